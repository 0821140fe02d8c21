"""Multiscale sphere tracing (Algorithm 1) against analytic truth, live-ray compaction, GEMM normals, hard cases."""

import math

import numpy as np
import pytest
import torch

from neural_bake.nets.siren import Siren
from neural_bake.render.asset import RenderAsset, RenderError, analytic_level, as_render_asset, siren_level
from neural_bake.render.camera import Camera
from neural_bake.render.renderer import render
from neural_bake.render.scene import Scene
from neural_bake.render.stats import EvalCounter
from neural_bake.render.trace import TraceSettings, box_interval, trace_rays

from render_cases import exact_sphere_hits, sample_level, sphere_level

CAM = Camera(position=(0.3, 0.4, 2.6), look_at=(0.0, 0.0, 0.0), fov_deg=40, width=48, height=40)


def _silhouette_band(hit: np.ndarray) -> np.ndarray:
    """Pixels within one pixel of the exact silhouette (where a pixel-centre ray grazes the surface)."""
    pad = np.pad(hit, 1, mode="edge")
    near = np.zeros_like(hit)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near |= pad[1 + dy:1 + dy + hit.shape[0], 1 + dx:1 + dx + hit.shape[1]] != hit
    return near


@pytest.mark.parametrize("mode", ["fixed", "threshold"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_nested_sphere_hits_depth_and_normals_match_the_exact_sphere(nested_sphere, mode, dtype):
    scene = Scene(channels=("color", "depth", "normal", "hit"), trace=TraceSettings(mode=mode), skip=False)
    r = render(nested_sphere, scene, camera=CAM, dtype=dtype)
    hit, t = exact_sphere_hits(CAM, 0.5)
    band = _silhouette_band(hit)
    assert np.array_equal(r["hit"][~band], hit[~band])
    assert r["hit"][hit & ~band].all()
    # depth: exact on rays that meet the sphere at an angle (away from the silhouette)
    err = np.abs(r["depth"][hit & ~band] - t[hit & ~band])
    assert err.max() < (5e-3 if mode == "fixed" else 2e-3)
    # normals of a sphere are its unit positions
    pts = np.asarray(CAM.position) + np.where(hit, t, 0.0)[..., None] * CAM.pixel_directions()
    want = pts / 0.5
    cos = (r["normal"] * want).sum(-1)[hit & ~band]
    assert cos.min() > 0.999
    assert np.isfinite(r["color"]).all() and np.isinf(r["depth"][~r["hit"]]).all()


def test_bundled_samples_render_against_their_analytic_surface(sample):
    """Hit points lie on the analytic surface, normals match the analytic normals, the mask matches a
    dense analytic ray march away from the silhouette."""
    asset = RenderAsset([sample_level(sample)])
    cam = Camera(position=(0.5, 0.8, 2.4), look_at=(0.0, 0.0, 0.0), fov_deg=50, width=40, height=40)
    r = render(asset, Scene(channels=("depth", "normal", "hit"), trace=TraceSettings(mode="threshold")), camera=cam)
    d = cam.pixel_directions().reshape(-1, 3)
    # reference mask: a fine fixed-step march of the analytic SDF along each ray (step 2e-3)
    ts = np.arange(0.5, 4.5, 2e-3)
    hit_ref = np.zeros(len(d), bool)
    for i0 in range(0, len(d), 200):
        p = np.asarray(cam.position) + ts[None, :, None] * d[i0:i0 + 200, None, :]
        inside = sample.sdf(p.reshape(-1, 3)).reshape(len(p), -1) <= 0
        hit_ref[i0:i0 + 200] = inside.any(axis=1)
    hit_ref = hit_ref.reshape(cam.height, cam.width)
    band = _silhouette_band(hit_ref)
    assert np.array_equal(r["hit"][~band], hit_ref[~band])
    h = r["hit"]
    pts = np.asarray(cam.position) + r["depth"][h][:, None] * d.reshape(cam.height, cam.width, 3)[h]
    assert np.abs(sample.sdf(pts)).max() < 2e-3
    cos = (r["normal"][h] * sample.normal(pts)).sum(-1)
    assert np.quantile(cos, 0.98) > 0.999 and cos.min() > 0.9  # creases of the jack: a few pixels


def test_compaction_changes_cost_not_the_image(nested_sphere):
    for mode in ("fixed", "threshold"):
        a = render(nested_sphere, Scene(channels=("color", "depth", "iterations"), skip=False,
                                        trace=TraceSettings(mode=mode, compact=True)), camera=CAM)
        b = render(nested_sphere, Scene(channels=("color", "depth", "iterations"), skip=False,
                                        trace=TraceSettings(mode=mode, compact=False)), camera=CAM)
        np.testing.assert_array_equal(a["color"], b["color"])
        np.testing.assert_array_equal(a["iterations"], b["iterations"])
        assert a.counter.total("trace") < b.counter.total("trace")
        # without compaction every ray of the chunk is evaluated at every step while any ray is live
        assert a.counter.total("trace") == int(a["iterations"].sum())


def test_fixed_mode_takes_exactly_the_iterations_per_level():
    # a plane far behind: no ray converges or leaves within the budget, so every ray takes every step
    far_plane = analytic_level(lambda p: p[:, 2] + 0.95, lambda p: torch.tensor([0.0, 0, 1]).to(p).expand_as(p),
                               name="plane")
    counter = EvalCounter()
    o = torch.tensor([[0.0, 0.0, 0.99]]).repeat(5, 1)
    d = torch.tensor([[0.0, 0.0, -1.0]]).repeat(5, 1)
    d[:, 0] = torch.linspace(-0.01, 0.01, 5)
    d = d / d.norm(dim=1, keepdim=True)
    shrunk = analytic_level(lambda p: 0.01 * (p[:, 2] + 0.95), name="slow")  # steps of 1 % of the distance
    res = trace_rays([shrunk, far_plane], o, d, TraceSettings(mode="fixed", iterations=(7, 3)), counter)
    assert counter.points["slow"]["trace"] == 5 * 7
    assert counter.points["plane"]["trace"] <= 5 * 3
    assert res.hit.all() and (res.iterations <= 10).all()


def test_levels_with_zero_iterations_are_never_evaluated(nested_sphere):
    r = render(nested_sphere, Scene(trace=TraceSettings(mode="fixed", iterations=(40, 0)), skip=False), camera=CAM)
    assert r.counter.total(network="f") == 0
    # the coarse level alone traces h1 − δ1 = 0: the sphere of radius 0.56
    hit, _ = exact_sphere_hits(CAM, 0.56)
    band = _silhouette_band(hit)
    assert np.array_equal(r["hit"][~band], hit[~band])


def test_gemm_normals_of_a_siren_match_autograd(fit_sphere_siren):
    net = fit_sphere_siren(r=0.5, width=32, steps=300)
    asset = as_render_asset(net)
    r = render(asset, Scene(channels=("depth", "normal", "hit")), camera=CAM, dtype=torch.float64)
    h = r["hit"]
    assert h.sum() > 100
    pts = np.asarray(CAM.position) + r["depth"][h][:, None] * CAM.pixel_directions()[h]
    x = torch.tensor(pts, requires_grad=True)
    (g,) = torch.autograd.grad(net.double()(x).sum(), x)
    want = (g / g.norm(dim=1, keepdim=True)).numpy()
    np.testing.assert_allclose(r["normal"][h], want, atol=1e-5)
    assert np.abs(net(torch.tensor(pts)).detach().numpy()).max() < 1e-3


def test_box_interval_handles_axis_parallel_rays_and_misses():
    o = torch.tensor([[0.0, 0.0, 3.0], [2.0, 0.0, 3.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    t_in, t_out = box_interval(o, d, 1.0)
    assert torch.isfinite(t_in).all() and torch.isfinite(t_out).all()
    np.testing.assert_allclose(t_in[[0, 2, 3]].numpy(), [2.0, 0.0, 0.0])
    assert t_out[0] == 4.0 and t_out[1] < t_in[1] and t_out[2] == 1.0 and t_out[3] == 2.0


# --------------------------------------------------------------------------------------------- hard cases
def test_camera_inside_the_object_fills_the_image_without_nan(nested_sphere):
    cam = Camera(position=(0.0, 0.0, 0.1), look_at=(0.0, 0.0, -1.0), width=16, height=16)
    r = render(nested_sphere, Scene(channels=("color", "depth", "normal", "hit")), camera=cam)
    assert r["hit"].all()
    np.testing.assert_allclose(r["depth"], 0.0, atol=1e-6)  # the hit is the ray's start
    for name in ("color", "depth", "normal"):
        assert np.isfinite(r[name]).all()


def test_rays_starting_on_the_bounding_cube_and_grazing_rays():
    level = sphere_level(0.5)
    # origins on the cube's faces, directions grazing the sphere (impact parameter 0.5 ± 1e-4)
    o = torch.tensor([[-1.0, 0.5 - 1e-4, 0.0], [-1.0, 0.5 + 1e-4, 0.0], [-1.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    d = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    res = trace_rays([level], o, d, TraceSettings(mode="threshold", iterations=(400,)), EvalCounter())
    assert res.hit.tolist() == [True, False, True, False]
    assert abs(float(res.t[2]) - 0.5) < 1e-3
    assert torch.isfinite(res.t[res.hit]).all()


def test_zero_gradient_surface_gives_masked_normals_not_nan():
    # f = (|p| - 0.5)^2 touches 0 with a zero gradient on the sphere
    lv = analytic_level(lambda p: (p.norm(dim=1) - 0.5) ** 2, name="square")
    r = render(RenderAsset([lv]), Scene(channels=("color", "normal", "hit", "depth"),
                                        trace=TraceSettings(hit_tolerance=1e-2), skip=False), camera=CAM)
    assert r["hit"].any()
    for name in ("color", "normal"):
        assert np.isfinite(r[name]).all()
    assert np.abs(r["normal"][r["hit"]]).max() < 1.0 + 1e-6


def test_large_omega_network_and_an_empty_scene_give_finite_images():
    net = Siren(32, 2, omega_0=300.0, hidden_omega=300.0, generator=torch.Generator().manual_seed(0))
    r = render(as_render_asset(net), Scene(channels=("color", "depth", "normal", "hit", "iterations"),
                                          trace=TraceSettings(iterations=(30,))), camera=CAM)
    assert np.isfinite(r["color"]).all() and np.isfinite(r["normal"]).all()
    empty = analytic_level(lambda p: p.norm(dim=1) + 10.0, name="nothing")
    r = render(RenderAsset([empty]), Scene(channels=("color", "hit"), skip=False), camera=CAM)
    assert not r["hit"].any()
    np.testing.assert_allclose(r["color"], 1.0)  # background
    assert r.counter.total("normals") == 0 and r.counter.total() == r.counter.total("trace")


def test_far_plane_cuts_hits(nested_sphere):
    near = render(nested_sphere, Scene(channels=("hit", "depth"), far=1.0), camera=CAM)
    assert not near["hit"].any()
    _, t = exact_sphere_hits(CAM, 0.5)
    far = render(nested_sphere, Scene(channels=("hit", "depth"), far=float(np.nanmin(t)) + 0.05), camera=CAM)
    assert far["hit"].any() and (far["depth"][far["hit"]] <= np.nanmin(t) + 0.05 + 1e-4).all()


def test_delta_too_small_leaves_holes_that_the_hole_map_finds():
    # h1 − δ1 is a sphere of radius 0.3 inside f's 0.5: the coarse stage steps over f everywhere
    bad = RenderAsset([sphere_level(0.3, 0.0, "h1"), sphere_level(0.5, 0.0, "f")])
    r = render(bad, Scene(effects=("shading", "hole_map"), channels=("hit", "holes"), skip=False,
                          trace=TraceSettings(mode="fixed", iterations=(30, 30))), camera=CAM)
    hit, _ = exact_sphere_hits(CAM, 0.5)
    inner, _ = exact_sphere_hits(CAM, 0.3)
    ring = hit & ~inner & ~_silhouette_band(hit) & ~_silhouette_band(inner)
    assert ring.sum() > 50
    assert not r["hit"][ring].any()  # the coarse stage passed f by and left the cube: holes
    assert r["holes"][ring].all() and not r["holes"][~hit].any()
    assert r.counter.total("hole_map") > 0


# --------------------------------------------------------------------------------------------- errors
@pytest.mark.parametrize("kwargs, match", [
    (dict(mode="sloppy"), "trace mode"),
    (dict(iterations=(0, 0)), "at least one level"),
    (dict(iterations=(3, -1)), "whole numbers"),
    (dict(epsilon=0.0), "epsilon"),
    (dict(hit_tolerance=float("nan")), "hit_tolerance"),
    (dict(chunk=0), "chunk"),
    (dict(lod=(0.1, 0.01)), "lod"),
])
def test_bad_trace_settings_are_refused(kwargs, match):
    with pytest.raises(RenderError, match=match):
        TraceSettings(**kwargs)


def test_iterations_must_match_the_levels(nested_sphere):
    with pytest.raises(RenderError, match="3 values for 2 levels"):
        render(nested_sphere, Scene(trace=TraceSettings(iterations=(1, 2, 3))), camera=CAM)


def test_trace_rays_refuses_mismatched_shapes():
    with pytest.raises(RenderError, match="origins and directions"):
        trace_rays([sphere_level()], torch.zeros(3, 3), torch.zeros(2, 3), TraceSettings(), EvalCounter())


def test_asset_errors():
    with pytest.raises(RenderError, match="at least one"):
        RenderAsset([])
    with pytest.raises(RenderError, match="names must differ"):
        RenderAsset([sphere_level(name="a"), sphere_level(name="a")])
    with pytest.raises(RenderError, match="δ"):
        sphere_level(delta=-1.0)
    with pytest.raises(RenderError, match="1 output"):
        siren_level(Siren(8, 0, out_dim=3))
    with pytest.raises(RenderError, match="cannot render"):
        as_render_asset("bunny.obj")
    with pytest.raises(RenderError, match="2 levels but 3"):
        as_render_asset([Siren(8, 0), Siren(8, 0)], deltas=[0.1, 0.2, 0.3])
    assert math.isfinite(sphere_level().delta)
