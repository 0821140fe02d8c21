"""Residual fine-level SDF construction: band-only supervision on a sphere, sums of SIRENs and their normals."""

import numpy as np
import pytest
import torch
import trimesh

import neural_bake.fit.sdf as sdf_module
from neural_bake.errors import FitError
from neural_bake.fit.residual import CONSTRUCTIONS, ResidualSdfFit, fit_sdf_construction, level_keys
from neural_bake.fit.sdf import SdfFit, fit_sdf, load_sdf
from neural_bake.fit.sdf_pools import band_pools
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.nets.gemm import gemm_gradient
from neural_bake.nets.siren import Siren
from neural_bake.nets.siren_sum import siren_sum

R = 0.7
TINY = dict(width=32, depth=1, omega_0=15.0, lr=1e-3, batch=512, batch_near=512, batch_uniform=128, pool_surface=4000,
            pool_near=4000, pool_uniform=1000, progress=False, log_every=10)


def sphere(r=R, sub=3):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=r)
    return mesh_from_arrays(np.asarray(m.vertices), np.asarray(m.faces), normalise=False)


def random_siren(width, depth, omega_0, seed, dtype=torch.float32):
    return Siren(width, depth, omega_0=omega_0, generator=torch.Generator().manual_seed(seed)).to(dtype)


def test_residual_level_trains_only_inside_the_coarse_band(fit_sphere_siren, monkeypatch):
    h = fit_sphere_siren(r=R, steps=300)
    band = 0.05
    seen = []
    real = sdf_module.sdf_step_backward

    def spy(loss_fn, model, sp, sn, vp, vd, cfg, **kwargs):
        seen.append((sp, vp, kwargs["base"]))
        return real(loss_fn, model, sp, sn, vp, vd, cfg, **kwargs)

    monkeypatch.setattr(sdf_module, "sdf_step_backward", spy)
    fit = fit_sdf(sphere(), steps=40, seed=0, base=h, band=band, hard_fraction=0.0, **TINY)
    assert len(seen) == 40 and fit.distance_error is None
    for sp, vp, (sv, sg, vv, vg) in seen:
        for pts, values, grads in ((sp, sv, sg), (vp, vv, vg)):
            assert pts.shape[0] > 0
            hv, hg = gemm_gradient(h, pts)
            assert float(hv.abs().max()) < band  # every training point inside |h| < δ
            torch.testing.assert_close(values, hv[:, 0])  # the coarse level's values and gradients beside them
            torch.testing.assert_close(grads, hg)
        # the sphere's oracle: the band around h's zero set is the shell | |x| − R | ≲ δ
        assert float((vp.norm(dim=1) - R).abs().max()) < band + 0.02
    # the sum still fits the sphere: |h + r| on the sphere stays within the band, and h + r vanishes there
    x = torch.nn.functional.normalize(torch.randn(2000, 3, generator=torch.Generator().manual_seed(3)), dim=1) * R
    with torch.no_grad():
        total = h(x)[:, 0] + fit.model(x)[:, 0]
    assert float(total.abs().max()) < band
    assert float(total.abs().mean()) < 0.01


def test_residual_level_mines_the_sign_errors_of_the_sum(fit_sphere_siren, monkeypatch):
    # the sign-error mining of a residual level ranks h + r, not r alone: its pools carry h's values
    h = fit_sphere_siren(r=R, steps=300)
    calls = []
    real = sdf_module._sign_errors

    def spy(model, pools, *args):
        calls.append(pools)
        return real(model, pools, *args)

    monkeypatch.setattr(sdf_module, "_sign_errors", spy)
    fit = fit_sdf(sphere(), steps=30, seed=0, base=h, band=0.05, hard_fraction=0.0, sign_fraction=0.5, hard_every=10,
                  **TINY)
    assert len(calls) == 3 and fit.config.sign_fraction == 0.5
    for pools in calls:
        assert "vol_base" in pools
        torch.testing.assert_close(pools["vol_base"], h(pools["vol_p"])[:, 0].detach())


def test_band_pools_keep_the_band_and_refuse_an_empty_one(fit_sphere_siren):
    h = fit_sphere_siren(r=R, steps=300)
    gen = torch.Generator().manual_seed(0)
    cube = torch.rand(20000, 3, generator=gen) * 2 - 1
    surf = torch.nn.functional.normalize(torch.randn(500, 3, generator=gen), dim=1)
    data = {"surf_p": surf * R, "surf_n": surf, "vol_p": cube, "vol_d": cube.norm(dim=1) - R, "n_near": 5000}
    kept = band_pools(h, 0.05)(data)
    assert kept["surf_p"].shape[0] == 500
    assert 0 < kept["vol_p"].shape[0] < 0.2 * cube.shape[0]  # a thin shell of the cube
    inside = (h(cube)[:, 0].abs() < 0.05)
    assert kept["n_near"] == int(inside[:5000].sum()) and kept["vol_p"].shape[0] == int(inside.sum())
    with pytest.raises(FitError, match="no surface sample lies in the band"):
        band_pools(h, 0.05)(dict(data, surf_p=surf * 0.1))


def test_band_pools_keep_the_near_points_gradient_targets_beside_them(fit_sphere_siren):
    # the targets ("vol_n") are kept with their points, and the band audit's points, appended, get none
    h = fit_sphere_siren(r=R, steps=300)
    gen = torch.Generator().manual_seed(1)
    cube = torch.rand(20000, 3, generator=gen) * 2 - 1
    surf = torch.nn.functional.normalize(torch.randn(500, 3, generator=gen), dim=1)
    radial = torch.nn.functional.normalize(cube, dim=1)
    vol_n = torch.where((torch.arange(20000) < 5000)[:, None], radial, torch.zeros(()))
    data = {"surf_p": surf * R, "surf_n": surf, "vol_p": cube, "vol_d": cube.norm(dim=1) - R, "n_near": 5000,
            "vol_n": vol_n}
    audit = (torch.tensor([[0.0, 0.0, R + 0.01]]), torch.tensor([0.01]))
    kept = band_pools(h, 0.05, audit=audit)(data)
    assert kept["vol_n"].shape == kept["vol_p"].shape
    near = kept["n_near"]
    torch.testing.assert_close(kept["vol_n"][:near], torch.nn.functional.normalize(kept["vol_p"][:near], dim=1))
    assert (kept["vol_n"][near:] == 0).all()  # the uniform points and the audit's point (the last row)
    assert torch.equal(kept["vol_p"][-1], audit[0][0])
    assert "vol_n" not in band_pools(h, 0.05)({k: v for k, v in data.items() if k != "vol_n"})


_VALLEY = torch.tensor([0.0, 0.0, 0.35])  # 0.35 inside the sphere of radius R


def _valley_siren(steps=800, seed=0):
    """A small Siren fitted to the sphere's SDF |x| − R plus a bump of 0.32 about :data:`_VALLEY`: h comes
    within 0.03 of zero there, 0.35 from the sphere, without crossing it (a coarse level whose small values
    mislead the band away from the mesh)."""
    net = Siren(64, 1, omega_0=10.0, generator=torch.Generator().manual_seed(seed))
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    gen = torch.Generator().manual_seed(seed + 1)
    for _ in range(steps):
        x = torch.cat([torch.rand(1024, 3, generator=gen) * 2 - 1, _VALLEY + 0.15 * torch.randn(256, 3, generator=gen)])
        want = x.norm(dim=1) - R + 0.32 * torch.exp(-((x - _VALLEY) ** 2).sum(dim=1) / 0.02)
        loss = ((net(x)[:, 0] - want) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net.eval()


def test_band_audit_finds_where_the_coarse_level_is_small_away_from_the_mesh():
    from neural_bake.fit.sampling import signed_distance
    from neural_bake.fit.sdf_pools import band_audit

    h, mesh, band, tol = _valley_siren(), sphere(), 0.1, 0.03
    with torch.no_grad():
        assert -0.06 < float(h(_VALLEY[None])[0, 0]) < 0  # the valley's floor: small, not crossing zero
    found = band_audit(h, mesh, band, tol, 40_000, seed=3)
    assert found is not None
    x, d = found
    with torch.no_grad():
        hv = h(x)[:, 0]
    assert float(hv.abs().max()) < band  # inside the fine level's band
    torch.testing.assert_close(d.double(), torch.as_tensor(signed_distance(mesh, x.double().numpy())), atol=1e-6,
                               rtol=0)
    assert bool((d.abs() >= hv.abs() + tol).all())  # where h understates the distance by more than its error
    near = (x - _VALLEY).norm(dim=1) < 0.25
    assert int(near.sum()) >= 50 and float(near.float().mean()) > 0.95  # the valley, not the sphere
    again = band_audit(h, mesh, band, tol, 40_000, seed=3)
    assert torch.equal(again[0], x)  # seeded
    # a coarse level that is small only at the mesh: nothing to audit
    assert band_audit(h, mesh, band, 0.5, 40_000, seed=3) is None
    assert band_audit(h, mesh, band, tol, 0, seed=3) is None


def test_residual_construction_splits_the_steps_and_saves_the_sum(tmp_path, monkeypatch):
    from neural_bake.fit.sdf_pools import _Pools

    draws = []
    real = _Pools._sample
    monkeypatch.setattr(_Pools, "_sample", lambda self, idx: draws.append(idx) or real(self, idx))
    fit = fit_sdf_construction(sphere(), "residual", steps=40, coarse_width=16, coarse_share=0.25,
                               **dict(TINY, width=48, omega_0=30.0))
    assert draws == [0]  # one pool drawn from the mesh, shared by both levels
    assert isinstance(fit, ResidualSdfFit) and fit.label == "16x1+32x1"
    # a smooth coarse level (ω0 15) under the fine one's ω0: the sum rescales its first layer
    assert (fit.coarse.model.omega_0, fit.fine.omega_0, fit.model.omega_0) == (15.0, 30.0, 30.0)
    assert (fit.config.width, fit.config.construction, fit.fine_config.width) == (48, "residual", 32)
    assert fit.coarse.steps == 10 and fit.steps == 30 and fit.band == pytest.approx(4.0 * fit.coarse.distance_error)
    x = torch.rand(500, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1
    with torch.no_grad():
        torch.testing.assert_close(fit.model(x), fit.coarse.model(x) + fit.fine(x), rtol=1e-5, atol=1e-5)
    back = load_sdf(fit.save(tmp_path / "sum.sdf"))  # the sum is an ordinary SDF file
    assert isinstance(back, SdfFit) and back.model.width == 48 and back.config.construction == "residual"
    with torch.no_grad():
        torch.testing.assert_close(back.model(x), fit.model(x))


def test_the_band_audit_joins_the_fine_levels_uniform_pool_and_its_sign_mining(monkeypatch):
    import neural_bake.fit.residual as residual_module

    # the audit's points (here three, with their distances) reach every pool of the fine level after its
    # uniform points, inside the band, where the sign mining of the sum sees them
    audit_p = torch.tensor([[0.0, 0.0, 0.05], [0.0, 0.05, 0.0], [0.05, 0.0, 0.0]])
    asked, seen = [], []
    def audit(h, mesh, band, tol, n, seed):
        asked.append((band, tol, n))
        return audit_p, audit_p.norm(dim=1) - R

    monkeypatch.setattr(residual_module, "band_audit", audit)
    real = sdf_module._sign_errors
    monkeypatch.setattr(sdf_module, "_sign_errors",
                        lambda model, pools, *a: seen.append(pools) or real(model, pools, *a))
    # a wide band (band_factor) keeps the centre of the sphere, where the audit's points are, in the pools
    fit = fit_sdf_construction(sphere(), "residual", steps=40, coarse_width=16, audit_candidates=5000,
                               sign_fraction=0.5, hard_every=10, band_factor=200.0, **dict(TINY, width=48))
    assert fit.audit["candidates"] == 5000 and fit.audit["kept"] == 3 and fit.audit["seconds"] >= 0
    (band, tol, n), = asked
    assert n == 5000 and band == pytest.approx(fit.band) and tol == pytest.approx(fit.coarse.distance_error)
    fine = [pools for pools in seen if "vol_base" in pools]  # the coarse level mines its own signs too
    assert len(fine) >= 3  # every 10 steps and at each pool refresh
    for pools in fine:
        torch.testing.assert_close(pools["vol_p"][-3:], audit_p)
        torch.testing.assert_close(pools["vol_d"][-3:], audit_p.norm(dim=1) - R)
        assert pools["vol_p"].shape[0] - pools["n_near"] > 3
    off = fit_sdf_construction(sphere(), "residual", steps=4, coarse_width=16, **dict(TINY, width=48))
    assert off.audit is None and len(asked) == 1  # audit_candidates 0: no audit


class _Killed(BaseException):
    """A run stopped from outside (the process killed) in the middle of the fine level."""


@pytest.mark.parametrize("construction", ["residual", "residual-warm"])
def test_a_construction_resumes_where_it_was_stopped(tmp_path, monkeypatch, construction):
    from neural_bake.fit.residual import coarse_checkpoint

    kw = dict(TINY, width=48, lr_schedule="constant", refresh_every=10, checkpoint_every=5, coarse_width=16,
              audit_candidates=2000, sign_fraction=0.5, hard_every=10)
    # checkpointed, uninterrupted (a checkpoint step re-ranks the mined sets: runs with checkpoints agree)
    full = fit_sdf_construction(sphere(), construction, steps=40, checkpoint=str(tmp_path / "full.ckpt"), **kw)
    ck = tmp_path / "run.ckpt"
    assert coarse_checkpoint(str(ck)) == str(tmp_path / "run.coarse.ckpt") and coarse_checkpoint(None) is None
    real, calls = sdf_module.sdf_step_backward, []

    def dies_in_the_fine_level(*args, **kwargs):
        calls.append(1)
        if len(calls) == 10 + 17:  # the coarse level's 10 steps, then 17 of the fine level's 30
            raise _Killed()
        return real(*args, **kwargs)

    monkeypatch.setattr(sdf_module, "sdf_step_backward", dies_in_the_fine_level)
    with pytest.raises(_Killed):
        fit_sdf_construction(sphere(), construction, steps=40, checkpoint=str(ck), **kw)
    assert ck.is_file() and (tmp_path / "run.coarse.ckpt").is_file()
    steps_run = []
    monkeypatch.setattr(sdf_module, "sdf_step_backward", lambda *a, **k: steps_run.append(1) or real(*a, **k))
    resumed = fit_sdf_construction(sphere(), construction, steps=40, checkpoint=str(ck), resume=True, **kw)
    assert resumed.coarse.stopped_reason == "resumed finished run" and resumed.steps == 30
    assert len(steps_run) == 15  # from the fine level's checkpoint at step 15, the coarse level not refitted
    x = torch.rand(500, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1
    with torch.no_grad():
        torch.testing.assert_close(resumed.model(x), full.model(x), atol=1e-5, rtol=1e-5)  # as if never stopped
    again = fit_sdf_construction(sphere(), construction, steps=40, checkpoint=str(ck), resume=True, **kw)
    assert again.stopped_reason == "resumed finished run" and len(steps_run) == 15
    # the fine level resumes only on the coarse level it was trained on
    other = tmp_path / "other.ckpt"
    fit_sdf_construction(sphere(), construction, steps=40, checkpoint=str(other), **kw)
    (tmp_path / "other.coarse.ckpt").unlink()
    with pytest.raises(FitError, match="belongs to another run"):
        fit_sdf_construction(sphere(), construction, steps=40, checkpoint=str(other), resume=True,
                             **dict(kw, coarse_omega_0=20.0))


def test_warm_start_begins_as_the_coarse_level():
    fit = fit_sdf_construction(sphere(), "residual-warm", steps=20, coarse_width=16, **TINY)
    assert fit.label == "16x1→32x1" and fit.band is None and fit.fine is None and fit.model.width == 32
    h = fit.coarse.model
    fresh = random_siren(16, 1, 15.0, 5)
    with torch.no_grad():
        fresh.layers[-1].weight.zero_()
        fresh.layers[-1].bias.zero_()
        x = torch.rand(200, 3) * 2 - 1
        torch.testing.assert_close(siren_sum(h, fresh)(x), h(x), rtol=1e-5, atol=1e-6)


def test_bad_constructions_and_residual_settings_are_refused(fit_sphere_siren):
    assert CONSTRUCTIONS == ("plain", "residual", "residual-warm", "tiles")
    with pytest.raises(FitError, match="unknown SDF construction 'nested'"):
        fit_sdf_construction(sphere(), "nested", steps=2, **TINY)
    with pytest.raises(FitError, match="coarse_share must be in"):
        fit_sdf_construction(sphere(), "residual", steps=2, coarse_share=1.0, coarse_width=8, **TINY)
    with pytest.raises(FitError, match=r"coarse_width must be an integer in \(0, width 32\)"):
        fit_sdf_construction(sphere(), "residual-warm", steps=2, coarse_width=32, **TINY)
    with pytest.raises(FitError, match="construction must be one of"):
        fit_sdf(sphere(), steps=2, construction="octree", **TINY)
    with pytest.raises(FitError, match="budget='steps' runs the reference steps of a preset's own construction"):
        fit_sdf(sphere(), construction="residual", coarse_width=8, budget="steps", **TINY)
    h = fit_sphere_siren(r=R, steps=300)
    with pytest.raises(FitError, match="needs a positive band"):
        fit_sdf(sphere(), steps=2, base=h, hard_fraction=0.0, **TINY)
    with pytest.raises(FitError, match="does not support hard_fraction"):
        fit_sdf(sphere(), steps=2, base=h, band=0.05, **dict(TINY, hard_fraction=0.25))
    with pytest.raises(FitError, match="band is the residual level's band"):
        fit_sdf(sphere(), steps=2, band=0.05, **TINY)
    with pytest.raises(FitError, match="init must be a Siren of width 32"):
        fit_sdf(sphere(), steps=2, init=random_siren(16, 1, 15.0, 0), **TINY)
    with pytest.raises(FitError, match="audit points belong to a residual level's band: they need base"):
        fit_sdf(sphere(), steps=2, audit=(torch.zeros(1, 3), torch.ones(1)), **TINY)
    with pytest.raises(FitError, match="audit_candidates must be"):
        fit_sdf_construction(sphere(), "residual", steps=2, coarse_width=8, audit_candidates=-1, **TINY)


def test_a_preset_of_the_residual_construction_accounts_both_levels_against_their_step_costs(monkeypatch):
    """The quick preset fits the residual construction; each level's time budget is accounted against its own
    step cost ("quick/coarse", "quick/fine") on a simulated clock, and the construction's account adds them
    up and carries a level's warning (a machine slowed in the fine level)."""
    import neural_bake.fit.budget as budget
    from neural_bake.fit.sdf_config import PRESETS, config_from

    cfg = config_from(preset="quick")
    assert (cfg.construction, cfg.width, cfg.coarse_width) == (PRESETS["quick"]["construction"], 192, 64)
    assert level_keys("quick", cfg) == ("quick/coarse", "quick/fine")
    assert level_keys("quick", config_from(preset="quick", coarse_width=32)) == (None, None)
    assert level_keys(None, cfg) == (None, None)
    monkeypatch.setattr(budget, "_full_rate", lambda: 100.0)  # reference steps a second, fixed
    t = {"now": 0.0}

    def clock():
        return t["now"]

    real_loss = sdf_module.sdf_step_backward

    def slow_step(*a, **k):  # the simulated clock: 0.01 s a coarse step, 0.4 s a fine (base given) one
        t["now"] += 0.4 if k.get("base") is not None else 0.01
        return real_loss(*a, **k)

    monkeypatch.setattr(sdf_module, "sdf_step_backward", slow_step)
    small = dict(pool_surface=4000, pool_near=4000, pool_uniform=1000, batch=256, batch_near=256, batch_uniform=64,
                 progress=False, compile="off", micro_batches=1)
    with pytest.warns(Warning, match="quick/fine: made"):
        fit = fit_sdf(sphere(), preset="quick", minutes=0.2, clock=clock, budget_key="quick", **small)
    b = fit.budget
    coarse, fine = b["levels"]["coarse"], b["levels"]["fine"]
    # a quarter of 12 s at 0.01 s a step, then the rest at 0.4 s a step
    assert coarse["preset"] == "quick/coarse" and fine["preset"] == "quick/fine"
    assert fit.coarse.steps == pytest.approx(300, abs=2) and fit.steps == pytest.approx(23, abs=2)
    assert b["steps"] == fit.coarse.steps + fit.steps
    assert b["expected_steps"] == coarse["expected_steps"] + fine["expected_steps"]
    assert coarse["expected_steps"] == budget.expected_steps("quick/coarse", coarse["budget_seconds"], 100.0,
                                                             coarse["asset_seconds_per_step"])
    assert coarse["warning"] is None and fine["warning"] and b["warning"] == fine["warning"]


def test_a_network_no_wider_than_the_presets_coarse_level_is_fitted_plainly():
    from neural_bake.fit.sdf_config import config_from

    assert config_from(preset="default").construction == "residual"
    assert config_from(preset="default", width=256).construction == "residual"
    assert config_from(preset="default", width=64).construction == "plain"  # one network of the width asked
    assert config_from(preset="default", width=32, coarse_width=16).construction == "residual"
    with pytest.raises(FitError, match=r"coarse_width must be an integer in \(0, width 32\).*construction 'plain'"):
        config_from(preset="default", width=32, construction="residual")
