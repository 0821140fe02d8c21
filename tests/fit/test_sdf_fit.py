"""fit_sdf: quality floor on a sphere, seeds, resume, divergence handling, model files, CLI."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
import trimesh

from neural_bake.cli.main import main
from neural_bake.errors import FitError, ModelFileError, NeuralBakeWarning
from neural_bake.fit.sdf import PRESETS, SdfFit, SdfFitConfig, fit_sdf, load_sdf
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.nets.gemm import gemm_gradient
from neural_bake.nets.compiled import compiler_available

R = 0.8
TINY = dict(width=32, depth=1, omega_0=15.0, lr=1e-3, batch=512, batch_near=512, batch_uniform=128, pool_surface=4000,
            pool_near=4000, pool_uniform=1000, progress=False, log_every=20)


def sphere(r=R, sub=3, center=(0.0, 0.0, 0.0)):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=r)
    return mesh_from_arrays(np.asarray(m.vertices) + np.asarray(center), np.asarray(m.faces), normalise=False)


def weights(model):
    return torch.cat([p.detach().flatten() for p in model.parameters()])


@pytest.fixture(scope="module")
def sphere_fit():
    return fit_sdf(sphere(), steps=200, seed=0, **TINY)


def test_sphere_zero_level_set_near_radius(sphere_fit):
    d = torch.randn(2000, 3, generator=torch.Generator().manual_seed(1))
    d = d / d.norm(dim=1, keepdim=True)
    with torch.no_grad():
        on = sphere_fit.model(d * R)[:, 0]
        inside = sphere_fit.model(d * 0.5)[:, 0]
        outside = sphere_fit.model(d * 0.95)[:, 0]
    assert on.abs().max() < 0.03 and on.abs().mean() < 0.008
    assert (inside < -0.1).all() and (outside > 0.05).all()  # the sign is right everywhere
    assert abs(inside.mean() + 0.3) < 0.05 and abs(outside.mean() - 0.15) < 0.03  # true SDF: -0.3, 0.15
    assert sphere_fit.steps == 200 and sphere_fit.stopped_reason == "steps"
    h = sphere_fit.history
    assert h[-1]["loss"] < 0.2 * h[0]["loss"] and {"surface", "normal", "eikonal", "sdf"} <= set(h[-1])


def test_save_load_round_trip(sphere_fit, tmp_path):
    path = sphere_fit.save(tmp_path / "sphere.sdf")
    back = load_sdf(path)
    assert isinstance(back, SdfFit) and back.frame == sphere_fit.frame and back.steps == 200
    assert back.config == sphere_fit.config
    x = torch.rand(100, 3) * 2 - 1
    with torch.no_grad():
        assert torch.equal(back.model(x), sphere_fit.model(x))
    assert SdfFit.load(path).config.width == 32


def test_load_refuses_non_sdf_model(tmp_path):
    from neural_bake.fields import save_model
    from neural_bake.nets.siren import Siren

    save_model(Siren(8, 0, out_dim=3), tmp_path / "tex.model", kind="texture")
    with pytest.raises(ModelFileError, match="not an SDF model file"):
        load_sdf(tmp_path / "tex.model")


def test_seed_reproduces():
    kw = dict(TINY, steps=15)
    a, b, c = fit_sdf(sphere(), seed=5, **kw), fit_sdf(sphere(), seed=5, **kw), fit_sdf(sphere(), seed=6, **kw)
    assert torch.equal(weights(a.model), weights(b.model))
    assert not torch.equal(weights(a.model), weights(c.model))


def test_resume_equals_uninterrupted(tmp_path):
    kw = dict(TINY, lr_schedule="constant", refresh_every=10, checkpoint_every=10)
    full = fit_sdf(sphere(), steps=30, **kw)
    ck = str(tmp_path / "run.ckpt")
    first = fit_sdf(sphere(), steps=20, checkpoint=ck, **kw)
    assert first.steps == 20
    resumed = fit_sdf(sphere(), steps=30, checkpoint=ck, resume=True, **kw)
    assert resumed.steps == 30
    assert torch.allclose(weights(resumed.model), weights(full.model), atol=1e-6)
    with pytest.raises(FitError, match="belongs to another run"):
        fit_sdf(sphere(r=0.7), steps=40, checkpoint=ck, resume=True, **kw)


def test_divergence_is_detected_and_reported():
    from neural_bake.errors import TrainingDivergedError

    with pytest.warns(NeuralBakeWarning, match="halved the learning rate"), \
            pytest.raises(TrainingDivergedError, match="diverged") as info:
        fit_sdf(sphere(), steps=100, **dict(TINY, lr=1e4))
    assert info.value.exit_code == 1  # failed work, not a bad command line


def test_cli_fit_that_diverges_exits_1_with_one_line(tmp_path, capsys):
    src = tmp_path / "ball.obj"
    trimesh.creation.icosphere(subdivisions=2, radius=1.0).export(src)
    out = tmp_path / "ball.sdf"
    code = main(["fit", "sdf", str(src), "-o", str(out), "--preset", "64x1", "--steps", "100", "--lr", "1e4",
                 "--batch", "512", "--polish-evals", "0", "--compile", "off", "--no-progress", "--no-metrics"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and err[-1].startswith("neural-bake: error:") and "diverged" in err[-1]
    assert not out.exists()


@pytest.mark.parametrize("radius, offset", [(5000.0, 1e6), (1e-4, 0.0), (1e-4, 3.0)])
def test_far_from_origin_huge_and_tiny_scales_fit_in_unit_frame(radius, offset):
    m = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    mesh = mesh_from_arrays(np.asarray(m.vertices) + offset, np.asarray(m.faces))  # normalised on build
    fit = fit_sdf(mesh, steps=30, **TINY)
    assert torch.isfinite(weights(fit.model)).all()
    assert fit.frame.scale == pytest.approx(1.8 / (2 * radius), rel=1e-3)
    # the unit-frame mesh is the same whatever the input scale: the fit sees a sphere of radius ~0.9
    assert np.linalg.norm(mesh.vertices, axis=1) == pytest.approx(0.9, rel=1e-3)


def test_open_mesh_fits_without_nan():
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.8)
    keep = m.triangles_center[:, 2] < 0.6  # cut a hole at the top
    with pytest.warns(NeuralBakeWarning):
        mesh = mesh_from_arrays(m.vertices, m.faces[keep], normalise=False)
    fit = fit_sdf(mesh, steps=30, **TINY)
    assert torch.isfinite(weights(fit.model)).all() and fit.steps == 30


def test_presets_and_config():
    assert set(PRESETS) == {"quick", "default", "high", "64x1", "128x2", "256x2", "256x3"}
    from neural_bake.fit.sdf import config_from

    assert config_from(preset="256x3").hard_pool == 0.05 and config_from(preset="64x1").hard_pool == 0.02
    assert config_from(preset="256x3").lr_min_factor == 0.01 and config_from(preset="64x1").lr_min_factor == 0.05
    assert config_from(preset="64x1").polish_evals == 400 and config_from(preset="256x3").polish_evals == 0
    assert config_from(preset="64x1").polish_share == 0.25 and config_from(preset="256x3").polish_share == 0.0
    assert config_from(preset="256x3").loop_config().lr_min_factor == 0.01
    c = config_from(preset="64x1", seed=3)
    assert (c.width, c.depth, c.seed, c.minutes) == (64, 1, 3, 2.0)
    assert config_from(SdfFitConfig(), steps=None).steps == SdfFitConfig().steps  # None keeps the default
    assert config_from(preset="64x1", minutes=None).minutes is None  # ... except where None means "none"
    # quick, default and high: the best networks found for 2, 5 and 10 minutes
    q, d, h = config_from(preset="quick"), config_from(preset="default"), config_from(preset="high")
    assert (q.width, q.depth, q.minutes) == (192, 3, 2.0) and q != config_from(preset="64x1")
    for c in (q, d):  # aimed at the map's shading
        assert (c.hard_fraction, c.w_normal, c.w_angle, c.omega_0, c.lr) == (0.0, 300.0, 300.0, 45.0, 3e-4)
    assert (h.hard_fraction, h.w_normal, h.w_angle, h.omega_0, h.lr) == (0.0, 300.0, 300.0, 30.0, 1.5e-4)
    for c in (q, d, h):  # ∇f where a bake reads it, off the surface
        assert (c.w_near_normal, c.near_normal_reach) == (1000.0, 0.03)
    assert (q.near_normal_gap_share, d.near_normal_gap_share, h.near_normal_gap_share) == (0.25, 0.25, 0.25)
    assert (q.curvature_sampling, d.curvature_sampling, h.curvature_sampling) == (0.0, 0.0, 0.25)
    assert (q.edge_sampling, d.edge_sampling, h.edge_sampling) == (0.0, 0.0, 0.0)
    assert config_from(preset="256x3").w_near_normal == 0.0
    assert (q.zero_fraction, d.zero_fraction, h.zero_fraction) == (0.0, 0.1, 0.0)  # default's stray pieces
    assert (d.width, d.depth, d.minutes) == (192, 3, 5.0) and d != config_from(preset="128x2")
    assert (h.width, h.depth, h.minutes) == (256, 4, 10.0) and h != config_from(preset="256x3")
    assert (q.coarse_share, d.coarse_share, h.coarse_share) == (0.25, 0.25, 0.1)  # high's fine level: 9 minutes


def test_slow_sdf_fit_warns_and_records(tmp_path, monkeypatch):
    """A fit whose clock says each Adam step's own work took 20 s makes 6 steps in its 2 minutes, far below
    what the preset makes here: one warning line, and both figures in the model file."""
    from neural_bake.fit import sdf
    from neural_bake.fit.sdf import load_sdf

    t = [0.0]
    backward = sdf.sdf_step_backward

    def slow_backward(*args, **kwargs):  # the clock moves by 20 s in each step's own work, nowhere else
        t[0] += 20.0
        return backward(*args, **kwargs)

    monkeypatch.setattr(sdf, "sdf_step_backward", slow_backward)

    def clock():
        return t[0]

    with pytest.warns(NeuralBakeWarning, match=r"^64x1: made 6 steps of the ~\d+ this machine makes in 120 s"):
        fit = fit_sdf(sphere(sub=2), preset="64x1", clock=clock, polish_evals=0, pool_surface=20000,
                      pool_near=20000, pool_uniform=5000, progress=False)
    b = fit.budget
    assert fit.steps == b["steps"] == 6 and b["expected_steps"] > 12 and b["budget_seconds"] == 120.0
    assert b["stopped"] == "time budget (120 s) used" and b["preset"] == "64x1"
    assert b["pool_refreshes"]["built"] == 1 and b["pool_refreshes"]["skipped"] == 0
    fit.save(tmp_path / "s.sdf")
    assert load_sdf(tmp_path / "s.sdf").budget == b
    # another batch is another step cost: no expectation, no warning
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", NeuralBakeWarning)
        t[0] = 0.0
        other = fit_sdf(sphere(sub=2), preset="64x1", clock=clock, polish_evals=0, minutes=0.5, **TINY)
    assert other.budget["expected_steps"] is None and other.budget["warning"] is None


@pytest.mark.parametrize("kw, msg", [
    ({"preset": "512x9"}, "unknown preset '512x9'; choose one of quick, default, high, 64x1, 128x2, 256x2, 256x3$"),
    ({"bogus": 1}, "unknown setting"),
    ({"batch": 0}, "batch must be a positive integer"),
    ({"w_eikonal": -1.0}, "w_eikonal must be a non-negative"),
    ({"sigmas": (0.0,)}, "sigmas must be positive"),
    ({"dtype": "float16"}, "dtype must be one of"),
    ({"omega_0": 0.0}, "omega_0 must be positive"),
    ({"batch_near": 8, "pool_near": 0}, "non-empty batch needs a non-empty pool"),
    ({"hard_fraction": 1.5}, "hard_fraction must be in"),
    ({"hard_pool": 0.0}, "hard_pool in"),
    ({"hard_every": 0}, "hard_every must be a positive integer"),
    ({"zero_fraction": -0.1}, "zero_fraction must be in"),
    ({"zero_fraction": 0.8, "hard_fraction": 0.25}, r"zero_fraction must be in \[0, 1 - hard_fraction\]"),
    ({"sign_fraction": 1.5}, r"sign_fraction must be in \[0, 1\], got 1.5"),
    ({"sign_fraction": -0.2}, "sign_fraction must be in"),
    ({"zero_candidates": 0}, "zero_candidates must be a positive integer"),
    ({"micro_batches": -1}, "micro_batches must be a non-negative integer"),
    ({"micro_batches": 1.5}, "micro_batches must be a non-negative integer"),
    ({"lr_min_factor": 0.0}, "lr_min_factor must be in"),
    ({"focus_tau": -0.01}, "focus_tau must be a non-negative number"),
    ({"focus_tau": math.inf}, "focus_tau must be a non-negative number"),
    ({"surface_normals": "smooth"}, "surface_normals must be 'face' or 'vertex'"),
    ({"w_angle": -1.0}, "w_angle must be a non-negative number"),
    ({"w_near_normal": math.nan}, "w_near_normal must be a non-negative number"),
    ({"near_normal_reach": 0.0}, "near_normal_reach must be a positive distance"),
    ({"near_normal_gap_share": 1.5}, "near_normal_gap_share must be in"),
    ({"near_normal_gap_share": math.nan}, "near_normal_gap_share must be in"),
])
def test_bad_settings(kw, msg):
    with pytest.raises(FitError, match=msg):
        fit_sdf(sphere(sub=1), **kw)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_surface_normals_target_the_faces_or_the_smooth_surface(dtype):
    """On a coarse icosphere the interpolated vertex normals are far closer to the sphere's own normals (the
    positions) than the faces' normals are; the pools carry the kind asked for, at the surface samples and as
    the near samples' gradient targets (of the closest points)."""
    from neural_bake.fit.sdf_config import config_from
    from neural_bake.fit.sdf_pools import _Pools

    mesh = sphere(sub=1)
    faces = torch.as_tensor(mesh.face_normals, dtype=dtype)
    err = {}
    for kind in ("face", "vertex"):
        pools = _Pools(mesh, config_from(surface_normals=kind, pool_surface=5000, pool_near=3000, batch_near=8,
                                         pool_uniform=0, batch_uniform=0, w_near_normal=1.0),
                       torch.device("cpu"), dtype)
        data = pools.get(0)
        p, n = data["surf_p"], data["surf_n"]
        assert p.dtype == n.dtype == dtype
        assert torch.allclose(n.norm(dim=1), torch.ones(len(n), dtype=dtype), atol=1e-5)
        cos = (n * torch.nn.functional.normalize(p, dim=1)).sum(1).clamp(-1, 1)
        err[kind] = float(torch.rad2deg(torch.acos(cos)).median())
        vn = data["vol_n"][(data["vol_n"] != 0).any(dim=1)]
        on_a_face = (vn @ faces.T).max(dim=1).values > 1 - 1e-5
        assert len(vn) > 1000 and (bool(on_a_face.all()) if kind == "face" else float(on_a_face.float().mean()) < 0.1)
    assert err["vertex"] < 0.5 * err["face"], err


def test_not_a_mesh():
    with pytest.raises(FitError, match="expected a neural_bake Mesh"):
        fit_sdf(np.zeros((3, 3)))


def test_cli_fit_sdf(tmp_path, capsys):
    m = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    src = tmp_path / "ball.obj"
    m.export(src)
    out = tmp_path / "ball.sdf"
    code = main(["fit", "sdf", str(src), "-o", str(out), "--preset", "64x1", "--steps", "5", "--no-progress",
                 "--no-metrics", "--seed", "2", "--hard-fraction", "0.5", "--zero-fraction", "0.25",
                 "--gemm-dtype", "float32", "--compile", "off", "--micro-batches", "2",
                 "--lr-min-factor", "0.01", "--focus-tau", "0.003", "--w-surface", "2000", "--w-normal", "50",
                 "--w-eikonal", "20", "--w-sdf", "300", "--polish-evals", "4", "--polish-share", "0.2"])
    assert code == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    assert "5 steps" in printed and "L-BFGS polish: " in printed
    fit = load_sdf(out)
    assert (fit.config.width, fit.config.depth, fit.steps, fit.config.seed) == (64, 1, 5, 2)
    assert fit.config.hard_fraction == 0.5 and fit.config.zero_fraction == 0.25 and fit.config.gemm_dtype == "float32" and fit.config.compile == "off"
    assert fit.config.micro_batches == 2 and fit.config.lr_min_factor == 0.01 and fit.config.focus_tau == 0.003
    assert (fit.config.w_surface, fit.config.w_normal, fit.config.w_eikonal, fit.config.w_sdf) == (2000, 50, 20, 300)
    assert fit.config.polish_evals == 4 and fit.polish["evals"] >= 2 and fit.config.polish_share == 0.2


def test_cli_fit_sdf_errors(tmp_path, capsys):
    assert main(["fit", "sdf", str(tmp_path / "missing.obj"), "-o", str(tmp_path / "x.sdf")]) == 2
    assert "missing.obj" in capsys.readouterr().err
    m = trimesh.creation.icosphere(subdivisions=1)
    src = tmp_path / "ball.obj"
    m.export(src)
    assert main(["fit", "sdf", str(src), "-o", str(tmp_path / "nodir" / "x.sdf")]) == 2
    assert "does not exist" in capsys.readouterr().err
    for bad in (["--steps", "0"], ["--minutes", "nan"], ["--lr", "-1"]):  # refused before any work
        assert main(["fit", "sdf", str(src), "-o", str(tmp_path / "x.sdf"), *bad]) == 2
        err = capsys.readouterr().err
        assert err == f"neural-bake: error: {bad[0]} {float(bad[1]) if bad[0] != '--steps' else 0}: must be a positive number\n"
    assert not (tmp_path / "x.sdf").exists()
    assert main(["fit", "sdf", str(src), "-o", str(tmp_path / "x.sdf"), "--preset", "1x1"]) == 2
    capsys.readouterr()
    assert main(["fit", "sdf", str(src), "-o", str(tmp_path / "x.sdf"), "--hard-fraction", "2"]) == 2
    assert "hard_fraction must be in [0, 1]" in capsys.readouterr().err
    assert main(["fit", "sdf", str(src), "-o", str(tmp_path / "x.sdf"), "--lr-min-factor", "0"]) == 2
    assert "lr_min_factor must be in (0, 1]" in capsys.readouterr().err
    assert main(["fit", "sdf", str(src), "-o", str(tmp_path / "x.sdf"), "--focus-tau", "-1"]) == 2
    assert "focus_tau must be a non-negative number" in capsys.readouterr().err
    assert main(["fit", "sdf", str(src), "-o", str(tmp_path / "x.sdf"), "--w-sdf", "-3"]) == 2
    assert "w_sdf must be a non-negative number" in capsys.readouterr().err
    assert main(["fit", "sdf", str(src), "-o", str(tmp_path / "x.sdf"), "--polish-evals", "-1"]) == 2
    assert "polish_evals must be a non-negative integer" in capsys.readouterr().err
    assert not (tmp_path / "x.sdf").exists()


def test_bench_step_timing_parts():
    from neural_bake.bench.fit import step_timing

    roof = {"gflops_sgemm": 50.0, "gsin_per_s": 0.2, "gmul_per_s": 1.0}
    r = step_timing(16, 1, batch=64, batch_near=64, batch_uniform=16, roof=roof, repeat=1)
    assert r["network"] == "16x1" and r["points"] == 144
    assert r["ours_s"] > 0 and r["autograd_2x_backward_s"] > 0 and r["roofline_s"] > 0
    assert r["speedup_vs_autograd"] == pytest.approx(r["autograd_2x_backward_s"] / r["ours_s"])
    assert r["fraction_of_roofline"] == pytest.approx(r["roofline_s"] / r["ours_s"])
    # priced at the best of the given rates and the probes read in the step's own rounds
    assert r["sgemm_gflops"] >= 50.0
    if compiler_available("cpu"):
        assert r["compiled_s"] > 0 and r["compile_once_s"] > 0
        assert r["compiled_over_roofline"] == pytest.approx(r["compiled_s"] / r["roofline_s"])


@pytest.mark.parametrize("focus_tau, w_angle", [(0.0, 0.0), (0.05, 0.0), (0.5, 0.0), (0.0, 300.0)])
def test_bench_baseline_loss_equals_ours(focus_tau, w_angle):
    # the benchmark's double-backward baseline computes exactly our loss (so the timing compares like with like)
    from neural_bake.bench.fit import _autograd_terms
    from neural_bake.fit.sdf import sdf_loss_terms
    from neural_bake.nets.siren import Siren

    g = torch.Generator().manual_seed(0)
    model = Siren(16, 1, generator=g).double()
    sp, vp = torch.rand(50, 3, generator=g, dtype=torch.float64), torch.rand(30, 3, generator=g, dtype=torch.float64)
    sn = torch.nn.functional.normalize(torch.randn(50, 3, generator=g, dtype=torch.float64), dim=1)
    vd = torch.rand(30, generator=g, dtype=torch.float64)
    cfg = SdfFitConfig(focus_tau=focus_tau, w_angle=w_angle)
    ours = sdf_loss_terms(model, sp, sn, vp, vd, cfg)["loss"]
    ref = _autograd_terms(model, sp, sn, vp, vd, cfg)["loss"]
    assert float(ours.detach()) == pytest.approx(float(ref.detach()), rel=1e-10)
    (g1,) = torch.autograd.grad(ours, model.layers[1].weight)
    (g2,) = torch.autograd.grad(ref, model.layers[1].weight)
    assert torch.allclose(g1, g2, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_focused_squares_weights_and_cap(dtype):
    from neural_bake.fit.sdf import FOCUS_CAP, focused_squares

    r = torch.tensor([0.0, 1e-4, 1e-3, 2e-3, 5e-3, 1e-2, 0.5, 3.0], dtype=dtype, requires_grad=True)
    tau = 2e-3
    out = focused_squares(r ** 2, tau)
    ref = [x * x * (1 + min((x / tau) ** 2, FOCUS_CAP)) for x in r.detach().double().tolist()]
    assert out.detach().double().tolist() == pytest.approx(ref, rel=1e-5 if dtype == torch.float32 else 1e-12)
    assert torch.isfinite(out).all()
    assert torch.equal(focused_squares(r ** 2, 0.0), r ** 2)  # tau 0: the focus is off
    # the weight is a constant of the step: d/dr = 2 r w, not the derivative of r^2 w(r)
    (grad,) = torch.autograd.grad(out.sum(), r)
    w = 1 + torch.clamp((r.detach() / tau) ** 2, max=FOCUS_CAP)
    assert torch.allclose(grad, 2 * r.detach() * w, rtol=1e-5)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_angle_term_is_the_angle_and_stays_finite_where_it_vanishes(dtype):
    """The angle term is the mean chord 2 sin(θ/2) ≈ θ of the angle between ∇f and the target (to ε), its
    gradient finite where ∇f meets the target exactly and where ∇f vanishes; it adds to the other terms,
    unchanged."""
    from neural_bake.constants import NORMAL_ANGLE_EPS
    from neural_bake.fit.sdf import sdf_loss_terms
    from neural_bake.nets.siren import Siren

    g = torch.Generator().manual_seed(5)
    model = Siren(16, 1, generator=g).to(dtype)
    sp = torch.rand(64, 3, generator=g, dtype=dtype)
    with torch.no_grad():
        _, grads = gemm_gradient(model, sp, "reverse")
    unit = torch.nn.functional.normalize(grads, dim=1)
    axis = torch.nn.functional.normalize(torch.linalg.cross(unit, torch.randn(64, 3, generator=g, dtype=dtype)), dim=1)
    theta = torch.linspace(0.0, 1.0, 64, dtype=dtype)  # radians, the first exactly 0
    sn = unit * torch.cos(theta)[:, None] + axis * torch.sin(theta)[:, None]
    vp, vd = sp[:0], sp.new_zeros(0)
    cosine = sdf_loss_terms(model, sp, sn, vp, vd, SdfFitConfig())
    angle = sdf_loss_terms(model, sp, sn, vp, vd, SdfFitConfig(w_angle=7.0))
    tol = 1e-3 if dtype == torch.float32 else 1e-9
    assert "angle" not in cosine
    assert float(cosine["normal"]) == pytest.approx(float((1 - torch.cos(theta)).mean()), abs=tol)
    chord = 2 * torch.sin(theta / 2)  # √(2(1 − cos θ)): θ to within θ³/24
    assert float(angle["angle"]) == pytest.approx(float(chord.mean()), abs=NORMAL_ANGLE_EPS + tol)
    for key in ("surface", "normal", "eikonal"):
        assert float(angle[key]) == float(cosine[key])
    assert float(angle["loss"]) == pytest.approx(float(cosine["loss"]) + 7.0 * float(angle["angle"]), rel=1e-5)
    model.zero_grad()
    angle["loss"].backward()
    assert all(torch.isfinite(p.grad).all() for p in model.parameters())
    with torch.no_grad():  # a network whose gradient vanishes everywhere
        for p in model.parameters():
            p.zero_()
    model.zero_grad()
    flat = sdf_loss_terms(model, sp, sn, vp, vd, SdfFitConfig(w_angle=7.0))
    flat["loss"].backward()
    assert torch.isfinite(flat["loss"]) and all(torch.isfinite(p.grad).all() for p in model.parameters())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_near_normal_term_is_the_angle_at_the_points_with_a_target(dtype):
    """The near-normal term is the sum of the chords 2 sin(θ/2) ≈ θ between ∇f and the targets at the
    off-surface points that have one (zero rows add nothing) over all the step's off-surface points; the other
    terms are unchanged, micro-batches add up to the whole step, and its gradient stays finite where ∇f
    meets the target exactly or vanishes."""
    from neural_bake.constants import NORMAL_ANGLE_EPS
    from neural_bake.fit.sdf import sdf_loss_terms, sdf_step_backward
    from neural_bake.nets.siren import Siren

    g = torch.Generator().manual_seed(6)
    model = Siren(16, 1, generator=g).to(dtype)
    sp, sn, vp, vd = _step_data(dtype, s=20, v=64)
    with torch.no_grad():
        _, grads = gemm_gradient(model, vp, "reverse")
    unit = torch.nn.functional.normalize(grads, dim=1)
    axis = torch.nn.functional.normalize(torch.linalg.cross(unit, torch.randn(64, 3, generator=g, dtype=dtype)), dim=1)
    theta = torch.linspace(0.0, 1.0, 64, dtype=dtype)
    vn = unit * torch.cos(theta)[:, None] + axis * torch.sin(theta)[:, None]
    has = torch.arange(64) % 3 != 0
    vn = torch.where(has[:, None], vn, torch.zeros((), dtype=dtype))
    cfg = SdfFitConfig(w_near_normal=5.0)
    plain = sdf_loss_terms(model, sp, sn, vp, vd, SdfFitConfig())
    ours = sdf_loss_terms(model, sp, sn, vp, vd, cfg, vol_n=vn)
    tol = 1e-3 if dtype == torch.float32 else 1e-9
    chord = 2 * torch.sin(theta / 2)
    assert float(ours["near_angle"]) == pytest.approx(float(chord[has].sum()) / 64, abs=NORMAL_ANGLE_EPS + tol)
    for key in ("surface", "normal", "eikonal", "sdf"):
        assert float(ours[key]) == float(plain[key])
    assert float(ours["loss"]) == pytest.approx(float(plain["loss"]) + 5.0 * float(ours["near_angle"]), rel=1e-5)
    assert "near_angle" not in sdf_loss_terms(model, sp, sn, vp, vd, SdfFitConfig(), vol_n=vn)  # weight 0: off
    assert "near_angle" not in sdf_loss_terms(model, sp, sn, vp, vd, cfg)  # no targets: off
    model.zero_grad()
    ours["loss"].backward()
    ref_grads = [p.grad.clone() for p in model.parameters()]
    assert all(torch.isfinite(r).all() for r in ref_grads)
    model.zero_grad(set_to_none=True)
    out = sdf_step_backward(sdf_loss_terms, model, sp, sn, vp, vd, cfg, micro_batches=5, vol_n=vn)
    rtol = 1e-4 if dtype == torch.float32 else 1e-11
    assert float(out["near_angle"]) == pytest.approx(float(ours["near_angle"]), rel=rtol)
    for p, r in zip(model.parameters(), ref_grads):
        assert torch.allclose(p.grad, r, rtol=rtol, atol=rtol * float(r.abs().max()))
    with torch.no_grad():  # a network whose gradient vanishes everywhere
        for p in model.parameters():
            p.zero_()
    model.zero_grad()
    flat = sdf_loss_terms(model, sp, sn, vp, vd, cfg, vol_n=vn)
    flat["loss"].backward()
    assert torch.isfinite(flat["loss"]) and all(torch.isfinite(p.grad).all() for p in model.parameters())


def test_fit_with_the_near_normal_term_draws_targets_beside_the_near_points():
    # the pools carry the targets only when the term is on; the term changes the trajectory and is in the
    # fingerprint only then; mined zero-set points (the head of the near batch) get no target
    from neural_bake.fit.sdf import _draw

    on = fit_sdf(sphere(), steps=20, seed=3, **dict(TINY, w_near_normal=50.0))
    off = fit_sdf(sphere(), steps=20, seed=3, **TINY)
    assert np.isfinite(on.history[-1]["near_angle"]) and "near_angle" not in off.history[-1]
    assert not torch.equal(weights(on.model), weights(off.model))
    assert "w_near_normal" in on.config.fingerprint_dict()
    assert "w_near_normal" not in off.config.fingerprint_dict()
    assert "near_normal_reach" not in off.config.fingerprint_dict()
    assert "near_normal_gap_share" not in on.config.fingerprint_dict()  # 0: no bound, fingerprints as before
    assert replace(on.config, near_normal_gap_share=0.25).fingerprint_dict()["near_normal_gap_share"] == 0.25
    cfg = SdfFitConfig(batch=40, batch_near=200, batch_uniform=40, hard_fraction=0.0, zero_fraction=0.25)
    pools = {"surf_p": torch.zeros(100, 3), "surf_n": torch.zeros(100, 3), "vol_p": torch.rand(500, 3),
             "vol_d": torch.zeros(500), "n_near": 400, "vol_n": torch.ones(500, 3)}
    zero = (torch.full((3, 3), -7.0), torch.tensor([0.1, 0.2, 0.3]))
    _, _, vp, _, vn = _draw(pools, cfg, torch.Generator().manual_seed(0), {"zero": zero}, extra=("vol_n",))
    assert (vp[:50] == -7.0).all() and (vn[:50] == 0).all() and (vn[50:] == 1).all()
    with pytest.raises(FitError, match="no pool arrays"):
        _draw(dict(pools, vol_base=torch.zeros(500)), cfg, torch.Generator().manual_seed(0), {"zero": zero},
              extra=("vol_base", "vol_n"))


def test_focus_weights_the_worst_residuals_and_micro_batches_still_add_up():
    from neural_bake.fit.sdf import sdf_loss_terms, sdf_step_backward
    from neural_bake.nets.siren import Siren

    g = torch.Generator().manual_seed(3)
    model = Siren(16, 1, generator=g).double()
    sp, vp = torch.rand(64, 3, generator=g, dtype=torch.float64), torch.rand(40, 3, generator=g, dtype=torch.float64)
    sn = torch.nn.functional.normalize(torch.randn(64, 3, generator=g, dtype=torch.float64), dim=1)
    vd = torch.rand(40, generator=g, dtype=torch.float64) - 0.5
    plain = sdf_loss_terms(model, sp, sn, vp, vd, SdfFitConfig())
    cfg = SdfFitConfig(focus_tau=0.05)
    focused = sdf_loss_terms(model, sp, sn, vp, vd, cfg)
    assert float(focused["surface"]) > float(plain["surface"]) and float(focused["sdf"]) > float(plain["sdf"])
    assert float(focused["normal"]) == pytest.approx(float(plain["normal"]), rel=1e-12)  # untouched terms
    grads = []
    for k in (1, 5):
        model.zero_grad()
        sdf_step_backward(sdf_loss_terms, model, sp, sn, vp, vd, cfg, micro_batches=k)
        grads.append(torch.cat([p.grad.flatten() for p in model.parameters()]))
    assert torch.allclose(grads[0], grads[1], rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_mixed_gradient_matches_gemm_gradient(dtype):
    from neural_bake.fit.sdf import mixed_gradient
    from neural_bake.nets.gemm import gemm_gradient
    from neural_bake.nets.siren import Siren

    g = torch.Generator().manual_seed(3)
    model = Siren(64, 2, generator=g).to(dtype)
    x = (torch.rand(500, 3, generator=g, dtype=torch.float64) * 2 - 1).to(dtype)
    v_ref, g_ref = gemm_gradient(model, x, differentiable=True)
    # with the GEMMs in the points' own dtype the mixed path IS the reference formula
    v_same, g_same = mixed_gradient(model, x, dtype)
    assert torch.allclose(v_same, v_ref, atol=1e-5 if dtype == torch.float32 else 1e-12)
    assert torch.allclose(g_same, g_ref, atol=1e-4 if dtype == torch.float32 else 1e-10)
    v_bf, g_bf = mixed_gradient(model, x, torch.bfloat16)
    assert v_bf.dtype == dtype and g_bf.dtype == dtype
    # bf16 operands: ~3 significant digits per product, errors average over the width
    assert (v_bf - v_ref).abs().max() < 0.01 * (v_ref.abs().max() + 0.1)
    rel = (g_bf - g_ref).norm(dim=1) / g_ref.norm(dim=1).clamp_min(1e-3)
    assert rel.median() < 0.02 and rel.max() < 0.2
    # and the graph reaches the weights with one backward
    (v_bf.sum() + g_bf.square().sum()).backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in model.parameters())


def test_bf16_fit_reaches_the_same_floor():
    fit = fit_sdf(sphere(), steps=200, seed=0, gemm_dtype="bfloat16", bf16_fraction=0.75, **TINY)
    d = torch.randn(2000, 3, generator=torch.Generator().manual_seed(1))
    d = d / d.norm(dim=1, keepdim=True)
    with torch.no_grad():
        on = fit.model(d * R)[:, 0]
    assert on.abs().max() < 0.03 and on.abs().mean() < 0.008
    with pytest.raises(FitError, match="gemm_dtype must be"):
        fit_sdf(sphere(sub=1), gemm_dtype="float16")
    with pytest.raises(FitError, match="bf16_fraction must be in"):
        fit_sdf(sphere(sub=1), bf16_fraction=1.5)


def test_inward_winding_and_degenerate_faces_fit_like_the_clean_mesh():
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.8)
    faces = np.asarray(m.faces)[:, ::-1]  # inward winding
    v = np.vstack([m.vertices, [[0.8, 0.0, 0.0]]])  # a duplicate of an existing point ...
    faces = np.vstack([faces, [[0, len(v) - 1, 0]]])  # ... and a zero-area face
    with pytest.warns(NeuralBakeWarning):
        mesh = mesh_from_arrays(v, faces, normalise=False)
    fit = fit_sdf(mesh, steps=60, **TINY)
    assert torch.isfinite(weights(fit.model)).all()
    with torch.no_grad():
        centre, far = fit.model(torch.zeros(1, 3))[0, 0], fit.model(torch.tensor([[0.0, 0.0, 0.98]]))[0, 0]
    assert centre < 0 < far  # negative inside: the winding was fixed, not learnt inside out


def test_hard_indices_are_the_pools_largest_errors():
    from neural_bake.fit.sdf import _hard_indices
    from neural_bake.nets.siren import Siren

    model = Siren(16, 1, generator=torch.Generator().manual_seed(0))
    pts = torch.rand(1000, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1
    idx = _hard_indices(model, pts, SdfFitConfig(hard_pool=0.05))
    err = model(pts)[:, 0].detach().abs()
    assert len(idx) == 50 and len(set(idx.tolist())) == 50
    assert err[idx].min() >= torch.topk(err, 50).values.min()  # exactly the 50 largest |f|
    assert len(_hard_indices(model, pts, SdfFitConfig(hard_pool=1e-9))) == 1  # at least one


def test_hard_mining_draws_from_the_hard_set():
    from neural_bake.fit.sdf import _draw

    cfg = SdfFitConfig(batch=400, batch_near=200, batch_uniform=40, hard_fraction=0.25)
    pools = {"surf_p": torch.arange(3000.0).reshape(1000, 3), "surf_n": torch.zeros(1000, 3),
             "vol_p": torch.arange(1500.0).reshape(500, 3), "vol_d": torch.zeros(500), "n_near": 400}
    hard = {"surf": torch.tensor([7, 11, 13]), "near": torch.tensor([5, 9])}
    sp, _, vp, _ = _draw(pools, cfg, torch.Generator().manual_seed(0), hard)
    rows = (sp[:, 0] / 3).long()
    assert set(rows[300:].tolist()) <= {7, 11, 13}  # the last quarter: hard samples only
    assert len(set(rows[:300].tolist())) > 100  # the rest: uniform over the pool
    vrows = (vp[:, 0] / 3).long()
    assert set(vrows[150:200].tolist()) <= {5, 9}  # the near batch's last quarter: hard near samples
    assert len(set(vrows[:150].tolist())) > 50 and (vrows[:200] < 400).all()
    assert (vrows[200:] >= 400).all()  # uniform samples untouched
    sp0, *_ = _draw(pools, replace(cfg, hard_fraction=0.0), torch.Generator().manual_seed(0), hard)
    assert len(set((sp0[300:, 0] / 3).long().tolist())) > 50


def test_hard_indices_of_the_near_pool_rank_by_sdf_error():
    from neural_bake.fit.sdf import _hard_indices
    from neural_bake.nets.siren import Siren

    model = Siren(16, 1, generator=torch.Generator().manual_seed(0))
    pts = torch.rand(500, 3, generator=torch.Generator().manual_seed(2)) * 2 - 1
    d = model(pts)[:, 0].detach().clone()
    d[[3, 77]] += torch.tensor([5.0, -4.0])  # the two samples the net misses by far
    idx = _hard_indices(model, pts, SdfFitConfig(hard_pool=0.004), d)
    assert sorted(idx.tolist()) == [3, 77]


def test_gemm_dtype_auto_resolves_and_is_recorded():
    from neural_bake.fit.sdf import _bf16_pays

    fit = fit_sdf(sphere(sub=1), steps=3, **TINY)  # width 32: bf16 never pays
    assert fit.config.gemm_dtype == "float32"
    assert not _bf16_pays(SdfFitConfig(width=64, depth=1), torch.device("cpu"), torch.float32)
    assert not _bf16_pays(SdfFitConfig(width=256, depth=0), torch.device("cpu"), torch.float32)
    assert not _bf16_pays(SdfFitConfig(width=256, depth=3), torch.device("cpu"), torch.float64)
    assert isinstance(_bf16_pays(SdfFitConfig(width=256, depth=3), torch.device("cpu"), torch.float32), bool)


def test_hard_mining_off_and_on_differ_and_stay_finite():
    on = fit_sdf(sphere(), steps=40, seed=0, **TINY)
    off = fit_sdf(sphere(), steps=40, seed=0, **dict(TINY, hard_fraction=0.0))
    assert on.config.hard_fraction == 0.25 and off.config.hard_fraction == 0.0
    assert torch.isfinite(weights(on.model)).all()
    assert not torch.equal(weights(on.model), weights(off.model))


@pytest.mark.skipif(not compiler_available("cpu"), reason="no C++ compiler for TorchInductor")
def test_compiled_loss_trains_like_the_eager_one():
    # the same seed and steps, the loss through torch.compile or not: fused kernels round differently, so
    # the weights agree to float32 noise grown over a few Adam steps, not bit for bit
    on = fit_sdf(sphere(sub=2), steps=5, seed=0, **dict(TINY, compile="on"))
    off = fit_sdf(sphere(sub=2), steps=5, seed=0, **dict(TINY, compile="off"))
    assert on.config.compile == "on" and off.config.compile == "off"
    torch.testing.assert_close(weights(on.model), weights(off.model), rtol=1e-3, atol=1e-5)
    for a, b in zip(on.history, off.history):
        assert a["loss"] == pytest.approx(b["loss"], rel=1e-4)


def test_compile_auto_resolves_to_off_for_short_runs_and_bad_modes_are_refused():
    fit = fit_sdf(sphere(sub=1), steps=3, **TINY)
    assert fit.config.compile == "off"
    with pytest.raises(FitError, match="compile must be one of auto, on, off, got 'fast'"):
        fit_sdf(sphere(sub=1), steps=3, **dict(TINY, compile="fast"))


def test_zero_set_mining_finds_where_the_surface_is_furthest_from_the_mesh(sphere_fit):
    # sphere_fit learned the sphere of radius R; against a mesh of radius R + 0.02 its whole zero set is
    # 0.02 inside: every mined point lies on f ≈ 0 and carries its true distance, d ≈ -0.02
    from neural_bake.fit.sdf import _zero_set_samples

    model = sphere_fit.model
    bigger = sphere(R + 0.02, sub=5)  # facets within 2e-4 of the sphere
    near = torch.randn(4000, 3, generator=torch.Generator().manual_seed(3))
    near = near / near.norm(dim=1, keepdim=True) * (R + 0.03 * torch.rand(4000, 1) - 0.015)
    cfg = SdfFitConfig(zero_candidates=2000, hard_pool=0.05)
    pts, d = _zero_set_samples(model, bigger, near, cfg, seed=1)
    assert pts.shape == (100, 3) and d.shape == (100,)
    with torch.no_grad():
        assert model(pts)[:, 0].abs().max() <= 1e-3
    r = pts.norm(dim=1)
    # the true signed distance to the (finely faceted) bigger sphere: d ≈ r - (R + 0.02) on all of them
    assert (d < 0).all() and torch.allclose(d, r - (R + 0.02), atol=5e-4)
    again = _zero_set_samples(model, bigger, near, cfg, seed=1)
    assert torch.equal(again[0], pts) and torch.equal(again[1], d)  # deterministic in the seed


def test_zero_set_mining_gives_none_when_nothing_reaches_the_zero_set():
    from neural_bake.fit.sdf import _zero_set_samples
    from neural_bake.nets.siren import Siren

    model = Siren(8, 0)
    with torch.no_grad():
        for q in model.parameters():
            q.zero_()
        model.layers[-1].bias.fill_(1.0)  # f = 1 everywhere, ∇f = 0
    assert _zero_set_samples(model, sphere(sub=1), torch.rand(50, 3), SdfFitConfig(zero_candidates=50), 0) is None


def test_zero_set_samples_take_the_head_of_the_near_batch():
    from neural_bake.fit.sdf import _draw

    cfg = SdfFitConfig(batch=40, batch_near=200, batch_uniform=40, hard_fraction=0.25, zero_fraction=0.25)
    pools = {"surf_p": torch.zeros(100, 3), "surf_n": torch.zeros(100, 3),
             "vol_p": torch.arange(1500.0).reshape(500, 3), "vol_d": torch.zeros(500), "n_near": 400}
    zero = (torch.full((3, 3), -7.0), torch.tensor([0.1, 0.2, 0.3]))
    _, _, vp, vd = _draw(pools, cfg, torch.Generator().manual_seed(0), {"zero": zero})
    assert (vp[:50] == -7.0).all() and torch.isin(vd[:50], zero[1]).all()  # a quarter of the near batch
    assert (vp[50:, 0] >= 0).all() and (vd[50:] == 0).all()  # the rest from the pools
    _, _, vp0, _ = _draw(pools, replace(cfg, zero_fraction=0.0), torch.Generator().manual_seed(0), {"zero": zero})
    assert (vp0[:, 0] >= 0).all()


@pytest.mark.parametrize("hard_fraction", [0.25, 0.0])  # 0: the default preset's mining of the zero set alone
def test_fit_with_zero_set_mining_reproduces_and_stays_finite(hard_fraction):
    kw = dict(TINY, zero_fraction=0.25, zero_candidates=2000, hard_every=10, hard_fraction=hard_fraction)
    a = fit_sdf(sphere(), steps=30, seed=0, **kw)
    b = fit_sdf(sphere(), steps=30, seed=0, **kw)
    off = fit_sdf(sphere(), steps=30, seed=0, **dict(TINY, hard_fraction=hard_fraction))
    assert torch.isfinite(weights(a.model)).all() and torch.equal(weights(a.model), weights(b.model))
    assert not torch.equal(weights(a.model), weights(off.model))
    assert a.config.zero_fraction == 0.25


class _StraySphere(torch.nn.Module):
    """f = |x| − R − 0.005 (the sphere's SDF, its surface 0.005 too far out) but −0.05 inside a ball of radius
    0.15 about (0.8, 0.8, 0.8): a piece of stray solid far from the sphere (``offset`` is added to f)."""

    def __init__(self, offset=None):
        super().__init__()
        self.offset = offset

    def forward(self, x):
        f = x.norm(dim=1) - R - 0.005
        f = torch.where((x - 0.8).norm(dim=1) < 0.15, torch.full_like(f, -0.05), f)
        return (f if self.offset is None else f - self.offset(x))[:, None]


def _sign_pools(n_near=300, n_uniform=20_000):
    g = torch.Generator().manual_seed(4)
    near = torch.nn.functional.normalize(torch.randn(n_near, 3, generator=g), dim=1) * (R + 0.004)
    near[:20] = 0.8 + 0.05 * torch.randn(20, 3, generator=g)  # near points inside the stray ball: not candidates
    vp = torch.cat([near, torch.rand(n_uniform, 3, generator=g) * 2 - 1])
    return {"surf_p": torch.zeros(10, 3), "surf_n": torch.zeros(10, 3), "vol_p": vp, "vol_d": vp.norm(dim=1) - R,
            "n_near": n_near}


def test_sign_mining_finds_the_uniform_points_inside_a_stray_piece_of_solid():
    from neural_bake.constants import SIGN_MINING_TOL
    from neural_bake.fit.sdf_pools import _sign_errors

    pools = _sign_pools()
    vp, d = pools["vol_p"], pools["vol_d"]
    idx = _sign_errors(_StraySphere(), pools)
    in_ball = (vp - 0.8).norm(dim=1) < 0.15
    want = torch.nonzero(in_ball & (torch.arange(vp.shape[0]) >= 300)).flatten()
    assert want.numel() > 10 and torch.equal(idx, want)  # the uniform points in the ball, no near point
    # the surface 0.005 too far out gives every point with 0 < d < 0.005 the wrong sign: within the
    # tolerance, so none of them counts
    assert ((d > 0) & (d < 0.005) & ~in_ball).any() and SIGN_MINING_TOL > 0.005
    # a residual level's pool: f is the frozen base's values plus the model's
    base = _StraySphere()
    with torch.no_grad():
        pools_b = dict(pools, vol_base=base(vp)[:, 0] + 1.0)
    assert torch.equal(_sign_errors(_StraySphere(offset=lambda x: base(x)[:, 0] + 1.0), pools_b), want)
    right = {**pools, "vol_d": _StraySphere()(vp)[:, 0].detach()}  # f agrees with d everywhere
    assert _sign_errors(_StraySphere(), right) is None
    assert _sign_errors(_StraySphere(), dict(pools, n_near=vp.shape[0])) is None  # no uniform points


def test_sign_errors_take_the_tail_of_the_uniform_batch():
    from neural_bake.fit.sdf import _draw

    cfg = SdfFitConfig(batch=40, batch_near=200, batch_uniform=40, sign_fraction=0.25)
    pools = {"surf_p": torch.zeros(100, 3), "surf_n": torch.zeros(100, 3),
             "vol_p": torch.arange(1500.0).reshape(500, 3), "vol_d": torch.zeros(500), "n_near": 400}
    _, _, vp, _ = _draw(pools, cfg, torch.Generator().manual_seed(0), {"sign": torch.tensor([450, 460])})
    rows = (vp[:, 0] / 3).long()
    assert set(rows[230:].tolist()) <= {450, 460}  # the uniform batch's last quarter
    assert (rows[:200] < 400).all() and (rows[200:230] >= 400).all() and len(set(rows[200:230].tolist())) > 20
    _, _, vp0, _ = _draw(pools, replace(cfg, sign_fraction=0.0), torch.Generator().manual_seed(0),
                         {"sign": torch.tensor([450, 460])})
    assert len(set((vp0[230:, 0] / 3).long().tolist())) > 5


def _step_data(dtype, s=37, v=29, seed=5):
    g = torch.Generator().manual_seed(seed)
    sp = (torch.rand(s, 3, generator=g, dtype=torch.float64) * 2 - 1).to(dtype)
    sn = torch.nn.functional.normalize(torch.randn(s, 3, generator=g, dtype=torch.float64), dim=1).to(dtype)
    vp = (torch.rand(v, 3, generator=g, dtype=torch.float64) * 2 - 1).to(dtype)
    vd = (torch.rand(v, generator=g, dtype=torch.float64) - 0.5).to(dtype)
    return sp, sn, vp, vd


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("k", [1, 2, 3, 7, 50, 1000])
def test_micro_batches_add_up_to_the_whole_batch(dtype, k):
    # the reference: the plain mean losses of the whole batch, one backward; sizes that k does not divide,
    # and k beyond the surface batch (parts with no surface point) or beyond every point
    from neural_bake.fit.sdf import sdf_loss_terms, sdf_step_backward
    from neural_bake.nets.siren import Siren

    model = Siren(24, 2, generator=torch.Generator().manual_seed(0)).to(dtype)
    cfg = SdfFitConfig()
    sp, sn, vp, vd = _step_data(dtype)
    ref = sdf_loss_terms(model, sp, sn, vp, vd, cfg)
    ref["loss"].backward()
    ref_grads = [p.grad.clone() for p in model.parameters()]
    model.zero_grad(set_to_none=True)
    out = sdf_step_backward(sdf_loss_terms, model, sp, sn, vp, vd, cfg, micro_batches=k)
    rtol = 1e-4 if dtype == torch.float32 else 1e-11
    for key in ("loss", "surface", "normal", "eikonal", "sdf"):
        assert not out[key].requires_grad
        assert float(out[key]) == pytest.approx(float(ref[key].detach()), rel=rtol, abs=1e-12)
    for p, r in zip(model.parameters(), ref_grads):
        assert torch.allclose(p.grad, r, rtol=rtol, atol=rtol * float(r.abs().max()))


def test_micro_batches_without_volume_points():
    from neural_bake.fit.sdf import sdf_loss_terms, sdf_step_backward
    from neural_bake.nets.siren import Siren

    model = Siren(16, 1, generator=torch.Generator().manual_seed(1)).double()
    sp, sn, _, _ = _step_data(torch.float64)
    vp, vd = sp.new_zeros((0, 3)), sp.new_zeros((0,))
    ref = sdf_loss_terms(model, sp, sn, vp, vd, SdfFitConfig())
    out = sdf_step_backward(sdf_loss_terms, model, sp, sn, vp, vd, SdfFitConfig(), micro_batches=4)
    assert float(out["loss"]) == pytest.approx(float(ref["loss"].detach()), rel=1e-12)
    assert float(out["sdf"]) == 0.0


def test_micro_batch_count_auto_and_explicit():
    from neural_bake.fit.sdf import micro_batch_count

    cfg = SdfFitConfig()
    assert micro_batch_count(replace(cfg, width=256), 9216, "cpu") == 8  # 9 × 2^18 elements → nearest 2^k
    assert micro_batch_count(replace(cfg, width=64), 9216, "cpu") == 2
    assert micro_batch_count(replace(cfg, width=128), 9216, "cpu") == 4
    assert micro_batch_count(replace(cfg, width=32), 1152, "cpu") == 1
    assert micro_batch_count(replace(cfg, width=256), 9216, "cuda") == 1  # GPUs want one big batch
    assert micro_batch_count(replace(cfg, width=256, micro_batches=3), 9216, "cuda") == 3


def test_fit_with_micro_batches_equals_one_batch():
    # the same trajectory up to rounding (float64), so micro_batches is not in the fingerprint
    m = sphere(sub=2)
    kw = dict(TINY, steps=15, seed=4, dtype="float64", hard_fraction=0.0)
    one = fit_sdf(m, micro_batches=1, **kw)
    three = fit_sdf(m, micro_batches=3, **kw)
    assert torch.allclose(weights(one.model), weights(three.model), rtol=1e-7, atol=1e-9)
    assert replace(one.config, micro_batches=3).fingerprint_dict() == three.config.fingerprint_dict()


# ----------------------------------------------------------------------------------------------- L-BFGS polish
@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("lam", [0.0, 100.0])
def test_polish_lowers_the_loss_and_the_distance_error(dtype, lam):
    # analytic oracle: the sphere's signed distance is |x| - R. Without the worst-distance term the polish
    # lowers the mean error everywhere; with it, the largest error on the surface, the mean not rising
    mesh = sphere()
    plain = fit_sdf(mesh, steps=150, seed=0, dtype=dtype, **TINY)
    polished = fit_sdf(mesh, steps=150, seed=0, dtype=dtype, polish_evals=40, polish_points=4096,
                       polish_max_weight=lam, **TINY)
    assert plain.polish is None
    p = polished.polish
    assert p["kept"] and p["reason"] == "kept" and 2 < p["evals"] <= 40 + 25
    assert p["loss_after"] < 0.7 * p["loss_before"] and p["check_after"] < p["check_before"]
    assert polished.steps == plain.steps == 150 and polished.seconds > p["seconds"]
    d = torch.randn(4000, 3, generator=torch.Generator().manual_seed(3), dtype=weights(polished.model).dtype)
    d = d / d.norm(dim=1, keepdim=True)
    with torch.no_grad():
        err = [[(f.model(d * r)[:, 0] - (r - R)).abs() for r in (0.6, R, 0.95)] for f in (plain, polished)]
    mean = [sum(float(e.mean()) for e in errs) for errs in err]
    worst_on_surface = [float(errs[1].max()) for errs in err]
    if lam == 0:
        assert mean[1] < 0.8 * mean[0]
    else:
        assert worst_on_surface[1] < 0.85 * worst_on_surface[0] and mean[1] <= mean[0]
    assert all(torch.isfinite(t).all() for t in polished.model.parameters())


def test_polish_reproduces_and_its_record_survives_save_and_load(tmp_path):
    kw = dict(steps=60, seed=1, polish_evals=12, polish_points=2048, **TINY)
    a, b = fit_sdf(sphere(), **kw), fit_sdf(sphere(), **kw)
    assert torch.equal(weights(a.model), weights(b.model)) and a.polish["loss_after"] == b.polish["loss_after"]
    a.save(tmp_path / "p.sdf")
    back = load_sdf(tmp_path / "p.sdf")
    assert back.polish == a.polish and back.config.polish_evals == 12


def test_polish_settings_are_not_part_of_the_fingerprint_so_a_checkpoint_can_be_polished(tmp_path):
    ck = str(tmp_path / "run.ckpt")
    first = fit_sdf(sphere(), steps=40, seed=0, checkpoint=ck, checkpoint_every=20, **TINY)
    again = fit_sdf(sphere(), steps=40, seed=0, checkpoint=ck, checkpoint_every=20, resume=True,
                    polish_evals=10, polish_points=2048, **TINY)
    assert again.stopped_reason == "resumed finished run" and again.polish["kept"]
    assert not torch.equal(weights(first.model), weights(again.model))


def test_polish_time_comes_out_of_the_budget(ticker):
    # Adam stops early enough for the polish to run (without the time set aside it would find none left),
    # and the two together keep to the budget: 9 s of 0.05-s clock reads
    fit = fit_sdf(sphere(), steps=10**6, minutes=0.15, seed=0, polish_evals=30, polish_points=4096,
                  clock=ticker(0.05), **TINY)
    assert fit.stopped_reason == "time budget" and fit.polish["evals"] > 2
    assert fit.seconds <= 0.15 * 60 + 0.5
    # the reserve: 30 evaluations + checks, less Adam's last step (four clock reads: the loop's two and the
    # sampling's two)
    assert fit.seconds - fit.polish["seconds"] < 0.15 * 60 - 31 * 0.05 + 0.1


@pytest.mark.slow
def test_polish_share_sets_aside_part_of_the_budget_and_the_polish_runs_to_its_end(ticker):
    # 30 % of 6 s for the polish: Adam stops near 4.2 s and the polish, with far more evaluations allowed than
    # fit, runs until the budget's end instead of stopping at an estimate of its cost
    fit = fit_sdf(sphere(), steps=10**6, minutes=0.1, seed=0, polish_evals=100_000, polish_share=0.3,
                  polish_points=4096, clock=ticker(0.02), **TINY)
    adam = fit.seconds - fit.polish["seconds"]
    assert fit.stopped_reason == "time budget" and fit.polish["evals"] > 2
    assert 0.7 * 6 - 0.1 < adam <= 0.7 * 6 + 0.1
    assert 6 - 0.2 < fit.seconds <= 6 + 0.1
    assert fit.polish["seconds"] > 0.3 * 6 - 0.3


@pytest.mark.parametrize("kw, msg", [({"polish_evals": -1}, "polish_evals must be a non-negative integer"),
                                     ({"polish_evals": 2.5}, "polish_evals must be a non-negative integer"),
                                     ({"polish_points": 1}, "polish_points must be an integer of at least 2"),
                                     ({"polish_max_weight": -1.0}, "polish_max_weight must be a non-negative"),
                                     ({"polish_max_weight": math.inf}, "polish_max_weight must be a non-negative"),
                                     ({"polish_max_p": 0.5}, r"polish_max_p must be a number in \[1, 64\]"),
                                     ({"polish_max_p": math.nan}, r"polish_max_p must be a number in \[1, 64\]"),
                                     ({"polish_share": -0.1}, r"polish_share must be in \[0, 0.5\]"),
                                     ({"polish_share": 0.7}, r"polish_share must be in \[0, 0.5\]")])
def test_bad_polish_settings(kw, msg):
    with pytest.raises(FitError, match=msg):
        fit_sdf(sphere(), steps=1, **TINY, **kw)


def test_polish_batches_are_disjoint_where_the_pools_allow_and_keep_the_step_proportions():
    from neural_bake.fit.sdf import _polish_batches

    n_surf, n_near, n_uni = 1000, 800, 200
    g = torch.Generator().manual_seed(0)
    data = {"surf_p": torch.rand(n_surf, 3, generator=g), "surf_n": torch.rand(n_surf, 3, generator=g),
            "vol_p": torch.rand(n_near + n_uni, 3, generator=g), "vol_d": torch.arange(n_near + n_uni).float(),
            "n_near": n_near}
    cfg = SdfFitConfig(batch=400, batch_near=400, batch_uniform=100, polish_points=900)
    fit, check = _polish_batches(data, cfg)
    assert [t.shape[0] for t in fit] == [400, 400, 500, 500] and [t.shape[0] for t in check] == [400, 400, 500, 500]
    for a, b in ((fit[0], check[0]), (fit[2], check[2])):  # no row in both
        assert not (a[:, None, :] == b[None, :, :]).all(dim=2).any()
    ids = fit[3].long()  # vol_d holds each volume row's index: 400 near rows, then 100 uniform rows
    assert (ids[:400] < n_near).all() and (ids[400:] >= n_near).all() and len(set(ids.tolist())) == 500
    # pools smaller than two batches: the two overlap, but each is still drawn without repeats where it can
    small = replace(cfg, polish_points=3000)
    fit, check = _polish_batches(data, small)
    assert fit[0].shape[0] == check[0].shape[0] and len(set(map(tuple, fit[0].tolist()))) == n_surf
    assert torch.equal(_polish_batches(data, cfg)[0][0], _polish_batches(data, cfg)[0][0])  # seeded


def _autograd_polish_objective(model, sp, sn, vp, vd, cfg):
    """The polish objective with ∇f by double-backward autograd: an independent reference."""
    from neural_bake.fit.sdf import sdf_loss_terms

    x = sp.clone().requires_grad_(True)
    f = model(x)[:, 0]
    (g,) = torch.autograd.grad(f.sum(), x, create_graph=True)
    r = f / torch.linalg.vector_norm(g, dim=1).clamp_min(0.1)
    big_p = r.abs().pow(cfg.polish_max_p).mean().pow(1.0 / cfg.polish_max_p)
    return sdf_loss_terms(model, sp, sn, vp, vd, cfg)["loss"] + cfg.polish_max_weight * big_p, r


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("micro", [1, 3, 8])
@pytest.mark.parametrize("lam, p", [(100.0, 8.0), (7.0, 2.0), (0.0, 8.0)])
def test_polish_objective_and_its_gradient_match_autograd_in_micro_batches(dtype, micro, lam, p):
    from neural_bake.fit.sdf import _polish_loss, first_order_distance
    from neural_bake.nets.siren import Siren

    model = Siren(24, 2, generator=torch.Generator().manual_seed(0)).to(dtype)
    cfg = SdfFitConfig(polish_max_weight=lam, polish_max_p=p)
    batch = _step_data(dtype, s=53, v=31)
    ref, r = _autograd_polish_objective(model, *batch, cfg)
    ref.backward()
    ref_grads = [q.grad.clone() for q in model.parameters()]
    model.zero_grad(set_to_none=True)
    out = _polish_loss(batch, model=model, cfg=cfg, micro=micro)
    rtol = 2e-4 if dtype == torch.float32 else 1e-10
    assert float(out) == pytest.approx(float(ref), rel=rtol)
    for a, b in zip((q.grad for q in model.parameters()), ref_grads):
        torch.testing.assert_close(a, b, rtol=rtol, atol=rtol * float(b.abs().max()))
    # the GEMM first-order distance is autograd's, chunked or not
    for chunks in (1, 4):
        torch.testing.assert_close(first_order_distance(model, batch[0], chunks), r.detach(), rtol=rtol, atol=1e-7)


def test_polish_objective_is_finite_at_a_perfect_fit_and_where_the_slope_vanishes():
    from neural_bake.fit.sdf import _polish_loss, first_order_distance
    from neural_bake.nets.siren import Siren

    model = Siren(16, 1, generator=torch.Generator().manual_seed(0)).double()
    with torch.no_grad():  # f ≡ 0: every residual and every gradient is zero
        for q in model.parameters():
            q.zero_()
    sp, sn, vp, vd = _step_data(torch.float64)
    assert torch.equal(first_order_distance(model, sp), torch.zeros(sp.shape[0], dtype=torch.float64))
    out = _polish_loss((sp, sn, vp, torch.zeros_like(vd)), model=model, cfg=SdfFitConfig(), micro=2)
    assert math.isfinite(float(out))
    assert all(torch.isfinite(q.grad).all() for q in model.parameters() if q.grad is not None)


@pytest.mark.parametrize("case", ["open", "huge_far", "tiny"])
def test_polish_on_hard_inputs_keeps_finite_weights(case):
    m = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    if case == "open":
        keep = m.triangles_center[:, 2] < 0.6
        with pytest.warns(NeuralBakeWarning):
            mesh = mesh_from_arrays(m.vertices, m.faces[keep], normalise=False)
    else:
        scale, offset = (5000.0, 1e6) if case == "huge_far" else (1e-4, 0.0)
        mesh = mesh_from_arrays(m.vertices * scale + offset, m.faces)  # normalised on build, as loading does
    fit = fit_sdf(mesh, steps=40, polish_evals=15, polish_points=2048, **TINY)
    assert torch.isfinite(weights(fit.model)).all() and fit.polish["evals"] >= 2
    assert fit.polish["kept"] or fit.polish["reason"] == "held-out loss rose"


def test_micro_batch_tuner_keeps_the_fastest_count_and_retunes():
    from neural_bake.fit.sdf import MicroBatchTuner

    assert MicroBatchTuner(8).candidates == [1, 2, 4, 8]
    assert MicroBatchTuner(16).candidates == [2, 4, 8, 16]  # at most four
    one = MicroBatchTuner(1)
    assert one.next(0, "float32") == (1, False) and one.history == []  # nothing to choose: never timed
    speed = {1: 3.0, 2: 1.0, 4: 2.0, 8: 4.0}
    t = MicroBatchTuner(8, rounds=2, every=50)
    assert t.choice == 8  # the rule's count until a tuning has finished

    def run(step, key):
        k, timed = t.next(step, key)
        if timed:
            t.record(k, speed[k] + 0.01 * step)
        return k, timed

    first = [run(s, "float32") for s in range(12)]  # a warm-up round (untimed), then two timed rounds
    assert [k for k, _ in first] == [1, 2, 4, 8] * 3
    assert [timed for _, timed in first] == [False] * 4 + [True] * 8
    assert t.choice == 2 and t.history[-1]["choice"] == 2 and t.history[-1]["variant"] == "float32"
    assert t.history[-1]["seconds"] == {1: 3.04, 2: 1.05, 4: 2.06, 8: 4.07}  # the best of each count's rounds
    assert run(12, "float32") == (2, False) and run(40, "float32") == (2, False)
    speed.update({1: 0.5})  # the machine changed: the next tuning (every 50 steps) follows it
    again = [run(s, "float32") for s in range(50, 58)]  # a variant seen before: no warm-up round
    assert all(timed for _, timed in again) and t.choice == 1
    bf16 = [run(s, "bf16") for s in range(60, 72)]  # a new variant is tuned at once, with its warm-up round
    assert [timed for _, timed in bf16] == [False] * 4 + [True] * 8 and len(t.history) == 3


def test_time_budgeted_fit_tunes_its_micro_batches_and_a_step_count_fit_does_not(tmp_path):
    # 18,432 points × width 32 = 2.25 × 2^18: the rule says 2 parts, the tuner tries 1 and 2
    kw = dict(TINY, batch=8192, batch_near=8192, batch_uniform=2048, gemm_dtype="float32", seed=1)
    timed = fit_sdf(sphere(), minutes=0.05, steps=100_000, **kw)
    tuning = timed.micro_batch_tuning
    assert tuning and tuning[0]["step"] == 0 and set(tuning[0]["seconds"]) == {1, 2}
    assert tuning[0]["choice"] in (1, 2) and all(s > 0 for s in tuning[0]["seconds"].values())
    assert torch.isfinite(weights(timed.model)).all()
    back = load_sdf(timed.save(tmp_path / "timed.model"))
    assert back.micro_batch_tuning == json_roundtrip(tuning)
    assert fit_sdf(sphere(), steps=3, **kw).micro_batch_tuning is None  # a step count reproduces bit for bit
    assert fit_sdf(sphere(), minutes=0.02, micro_batches=2, **kw).micro_batch_tuning is None  # fixed by hand


def json_roundtrip(obj):
    import json

    return json.loads(json.dumps(obj))


def test_cli_fit_sdf_reports_the_micro_batch_tuning(tmp_path, capsys):
    src = tmp_path / "ball.obj"
    trimesh.creation.icosphere(subdivisions=2, radius=1.0).export(src)
    out = tmp_path / "ball.sdf"
    # a budget (the tuner runs only in budgeted runs) that the step cap ends first: 9 tuning steps + 3
    code = main(["fit", "sdf", str(src), "-o", str(out), "--preset", "64x1", "--minutes", "30", "--steps", "12",
                 "--batch", "8192", "--compile", "off", "--polish-evals", "0", "--gemm-dtype", "float32",
                 "--no-progress", "--no-metrics"])
    assert code == 0, capsys.readouterr().err
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("micro-batches: "))
    assert "1: " in line and "2: " in line and "4: " in line and " ms" in line  # 13,312 points × 64: rule 4
    assert load_sdf(out).micro_batch_tuning[0]["step"] == 0


def test_budgeted_pools_skip_refreshes_that_would_eat_the_budget():
    """A refresh is skipped while the builds (the next one included) would pass the share of the run's time,
    by the injected clock: each build here costs 10 clock seconds."""
    from neural_bake.fit.sdf_config import config_from
    from neural_bake.fit.sdf_pools import _Pools

    now = {"t": 0.0}

    class Timed(_Pools):
        def _build(self, idx):
            super()._build(idx)
            now["t"] += 10.0

    cfg = config_from(pool_surface=500, pool_near=0, batch_near=0, pool_uniform=0, batch_uniform=0,
                      refresh_every=100)
    pools = Timed(sphere(sub=1), cfg, torch.device("cpu"), torch.float32, max_share=0.2, clock=lambda: now["t"])
    first = pools.get(0)
    now["t"] = 30.0  # 20 s of steps after a 10-s build: another build would make 20 of 40 s
    assert pools.get(100) is first and pools.skipped == {1}
    assert pools.record() == {"built": 1, "skipped": 1, "build_seconds": 10.0}
    now["t"] = 90.0  # 20 of 100 s: within the share
    assert pools.get(150) is not first and pools.index == 1 and pools.build_seconds == 20.0
    assert pools.record() == {"built": 2, "skipped": 1, "build_seconds": 20.0}
    # without a share (a run with a step count) every refresh index is built, as the seed reproduces
    plain = _Pools(sphere(sub=1), cfg, torch.device("cpu"), torch.float32)
    plain.get(0)
    assert plain.get(100) is not None and plain.index == 1 and not plain.skipped
