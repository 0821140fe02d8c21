"""Beyond the paper: empty-space skipping (range-analysis octree), LOD blending, guaranteed casting, hole map."""

import numpy as np
import pytest
import torch

from neural_bake.render.asset import RenderAsset, RenderError, analytic_level, as_render_asset
from neural_bake.render.camera import Camera
from neural_bake.render.guaranteed import cast_guaranteed
from neural_bake.render.renderer import render
from neural_bake.render.scene import Scene
from neural_bake.render.skip import build_occupancy, clear_cache, occupancy_for
from neural_bake.render.stats import EvalCounter
from neural_bake.render.trace import TraceSettings, continuous_lod, lod_weights

from render_cases import exact_sphere_hits, nested_sphere_asset, sphere_level

CAM = Camera(position=(0.3, 0.4, 2.6), fov_deg=40, width=40, height=36)


def test_occupancy_grid_holds_every_point_of_the_band_and_skipping_keeps_the_image():
    asset = nested_sphere_asset()
    grid = build_occupancy(asset.levels[0], EvalCounter(), depth=4)
    # every point of the band [|h1| ≤ δ1] lies in an occupied cell
    g = torch.Generator().manual_seed(0)
    d = torch.randn(20000, 3, generator=g)
    d = d / d.norm(dim=1, keepdim=True)
    r = 0.52 + (torch.rand(20000, generator=g) * 2 - 1) * 0.04
    p = d * r[:, None]
    ijk = ((p + 1) / (2 / grid.resolution)).floor().long()
    assert grid.occupied[ijk[:, 0], ijk[:, 1], ijk[:, 2]].all()
    assert grid.fraction() < 0.5
    on = render(asset, Scene(channels=("color", "depth", "hit"), skip=True, skip_depth=4), camera=CAM)
    off = render(asset, Scene(channels=("color", "depth", "hit"), skip=False), camera=CAM)
    np.testing.assert_array_equal(on["hit"], off["hit"])
    np.testing.assert_allclose(on["depth"][on["hit"]], off["depth"][off["hit"]], atol=2e-4)
    assert on.counter.total("trace") < off.counter.total("trace")
    assert on.stats["skip"][0]["rays_skipped_entirely"] > 0


def test_skipping_grid_of_a_siren_covers_its_band_and_is_cached(fit_sphere_siren):
    net = fit_sphere_siren(r=0.5, width=16, steps=200)
    asset = as_render_asset([net, net], deltas=[0.05, 0.0])
    clear_cache()
    c1, c2 = EvalCounter(), EvalCounter()
    grid, built = occupancy_for(asset.levels[0], c1, depth=4)
    again, built2 = occupancy_for(asset.levels[0], c2, depth=4)
    assert built and not built2 and again is grid
    assert c1.boxes[asset.levels[0].name]["skip_octree"] == grid.boxes > 0 and not c2.boxes
    pts = torch.rand(40000, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1
    with torch.no_grad():
        band = pts[net(pts)[:, 0].abs() <= 0.05]
    ijk = ((band + 1) / (2 / grid.resolution)).floor().long().clamp(0, grid.resolution - 1)
    assert len(band) > 100 and grid.occupied[ijk[:, 0], ijk[:, 1], ijk[:, 2]].all()


def test_skipping_grid_on_disk_is_reused(fit_sphere_siren, tmp_path):
    net = fit_sphere_siren(r=0.5, width=16, steps=50)
    level = as_render_asset(net).levels[0]
    clear_cache()
    grid, built = occupancy_for(level, EvalCounter(), depth=3, cache_dir=tmp_path)
    clear_cache()
    c = EvalCounter()
    again, built2 = occupancy_for(level, c, depth=3, cache_dir=tmp_path)
    assert built and not built2 and not c.boxes
    assert torch.equal(again.occupied, grid.occupied) and len(list(tmp_path.glob("skip-*.npz"))) == 1


def test_guaranteed_caster_finds_a_thin_shell_sphere_tracing_overshoots():
    # a shell 0.04 thick around r = 0.5 with |∇f| = 4: sphere steps of 4× the distance jump through it
    def shell(p):
        return 4.0 * ((p.norm(dim=1) - 0.5).abs() - 0.02)

    level = analytic_level(shell, name="shell", lipschitz=4.0)
    cam = Camera(position=(0.0, 0.0, 2.5), width=32, height=32)
    scene = Scene(channels=("hit", "depth", "holes"), effects=("hole_map",), skip=False,
                  trace=TraceSettings(mode="threshold", iterations=(200,)))
    traced = render(RenderAsset([level]), scene, camera=cam)
    exact = render(RenderAsset([level]), scene.with_(guaranteed=True), camera=cam)
    hit, t = exact_sphere_hits(cam, 0.52)
    assert np.array_equal(exact["hit"], hit)
    np.testing.assert_allclose(exact["depth"][hit], t[hit], atol=2e-3)
    assert (traced["hit"] != hit).sum() > 20  # sphere tracing lost parts of the shell…
    assert np.array_equal(traced["holes"], hit & ~traced["hit"])  # …and the hole map shows exactly those
    assert exact["holes"].sum() == 0


def test_guaranteed_caster_agrees_with_sphere_tracing_on_a_true_sdf():
    level = sphere_level(0.5)
    o, d = CAM.rays()
    hit, t, iters = cast_guaranteed(level, o, d, EvalCounter())
    exact, t_ex = exact_sphere_hits(CAM, 0.5)
    assert np.array_equal(hit.reshape(exact.shape).numpy(), exact)
    np.testing.assert_allclose(t.reshape(exact.shape).numpy()[exact], t_ex[exact], atol=1e-3)
    assert (iters > 0).all()
    with pytest.raises(RenderError, match="no range bound"):
        cast_guaranteed(analytic_level(lambda p: p.norm(dim=1) - 0.5, lipschitz=None), o, d, EvalCounter())


def test_lod_uses_the_coarse_level_far_away_the_fine_near_and_blends_between():
    asset = nested_sphere_asset()
    near_cam = Camera(position=(0.0, 0.0, 1.6), width=24, height=24)
    far_cam = Camera(position=(0.0, 0.0, 40.0), fov_deg=2.0, width=8, height=8)
    lod = (0.01, 0.1)  # pixel footprints: near camera 0.03 at the hits (L̃ ≈ 0.5), far camera 0.17 (L̃ = 0)
    base = Scene(channels=("hit", "depth", "lod"), skip=False, trace=TraceSettings(lod=lod))
    far = render(asset, base, camera=far_cam)
    assert far.counter.total(network="f") == 0 and np.allclose(far["lod"][far["hit"]], 0.0)
    hit, t = exact_sphere_hits(far_cam, 0.56)  # h1 − δ1
    assert np.array_equal(far["hit"][hit], hit[hit])
    mid = render(asset, base, camera=near_cam)
    l_mid = mid["lod"][mid["hit"]]
    assert (l_mid > 0).all() and (l_mid < 1).all()
    # the blended surface lies between h1 − δ1 (r 0.56) and f (r 0.5): on axis t ∈ [1.04, 1.1]
    c = mid["depth"][12, 12]
    assert 1.6 - 0.56 - 1e-3 <= c <= 1.6 - 0.5 + 1e-3
    expected = 1.6 - (0.56 * (1 - l_mid.mean()) + 0.5 * l_mid.mean())
    assert abs(c - expected) < 5e-3
    assert mid.counter.total(network="f") > 0


def test_lod_weights_are_a_partition_of_unity_between_adjacent_levels():
    lod = torch.tensor([0.0, 0.25, 1.0, 1.5, 2.0])
    w = lod_weights(lod, 3)
    torch.testing.assert_close(w.sum(1), torch.ones(5))
    assert ((w > 0).sum(1) <= 2).all()
    fp = torch.tensor([1e-5, 1e-4, 1e-3, 1e-2, 1.0])
    c = continuous_lod(fp, (1e-4, 1e-2), 3)
    torch.testing.assert_close(c, torch.tensor([2.0, 2.0, 1.0, 0.0, 0.0]))
