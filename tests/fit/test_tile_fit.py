"""Tile levels fitted on a coarse SDF: the sphere's oracle (its normals are its unit positions), the band, the
grid, the time budget on an injected clock, and the settings' errors."""

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from neural_bake.errors import FitError
from neural_bake.fit.sdf_config import SdfFitConfig
from neural_bake.fit.tiles import TileFitConfig, fit_tiles, tile_grid_for
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.nets.gemm import gemm_gradient

R = 0.7
POOLS = SdfFitConfig(pool_surface=6000, pool_near=6000, pool_uniform=1500, progress=False)
SMALL = dict(grid=3, width=16, depth=1, omega_0=10.0, hidden_omega=30.0, surface_points=64, volume_points=64,
             lr=1e-3)


def sphere(r=R, sub=3):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=r)
    return mesh_from_arrays(np.asarray(m.vertices), np.asarray(m.faces), normalise=False)


def sphere_points(n, seed):
    return torch.nn.functional.normalize(torch.randn(n, 3, generator=torch.Generator().manual_seed(seed)), dim=1) * R


def normal_error_deg(grads, points):
    cos = (torch.nn.functional.normalize(grads, dim=1) * torch.nn.functional.normalize(points, dim=1)).sum(1)
    return torch.rad2deg(torch.arccos(cos.clamp(-1, 1)))


def test_tiles_take_a_rough_coarse_level_closer_to_the_sphere(fit_sphere_siren):
    h = fit_sphere_siren(r=R, steps=60, width=16)  # a rough coarse level
    fit = fit_tiles(sphere(), h, 0.1, POOLS, TileFitConfig(steps=250, **SMALL))
    assert fit.steps == 250 and fit.history[0]["step"] == 1
    x = sphere_points(3000, 1)
    hv, hg = gemm_gradient(h, x)
    rv, rg = fit.model.value_and_gradient(x)
    before, after = normal_error_deg(hg, x), normal_error_deg(hg + rg, x)
    assert float(after.median()) < 0.5 * float(before.median())
    assert float((hv[:, 0] + rv).abs().mean()) < 0.5 * float(hv[:, 0].abs().mean())
    assert not any(p.requires_grad for p in fit.model.parameters())


def test_the_grid_covers_the_surface_and_only_its_cells_hold_networks():
    x = sphere_points(5000, 2)
    grid = tile_grid_for(x, 4, 0.1)
    tiles, w, _ = grid.covering(x)
    torch.testing.assert_close(w.sum(1), torch.ones(len(x)), rtol=0, atol=1e-6)  # every cell around a point active
    # counting cells by their own points alone would leave points in seams towards cells without a network
    sparse = tile_grid_for(x, 4, 0.1, 200)
    assert float(sparse.covering(x)[1].sum(1).min()) < 1.0
    inner = ((x - grid.origin.float()) / grid.cell)  # in cells: a seam clear of the grid's outer faces
    assert float(inner.min()) >= grid.margin and float(inner.max()) <= grid.grid - grid.margin
    assert grid.grid == 6 and 8 < grid.active.numel() < 64  # the sphere's shell, not the cube's centre
    assert int(grid.slot[(3 * 6 + 3) * 6 + 3]) == -1  # the centre of the sphere
    ring = torch.tensor([i in (0, 5) or j in (0, 5) or k in (0, 5) for i in range(6) for j in range(6)
                         for k in range(6)])
    assert not bool(ring[grid.active].any())  # no surface point reaches the ring of cells around the cube


def test_cells_holding_enough_sign_errors_get_a_network_in_the_ring_too():
    x = sphere_points(5000, 2)
    plain = tile_grid_for(x, 4, 0.1)
    errors = torch.tensor([[0.95, 0.0, 0.0]]) + 0.01 * torch.randn(5, 3, generator=torch.Generator().manual_seed(3))
    # (beyond the sphere's bounding cube: in the ring)
    assert plain.covering(errors)[1].sum() == 0
    assert torch.equal(tile_grid_for(x, 4, 0.1, errors=errors, min_errors=6).active, plain.active)
    grid = tile_grid_for(x, 4, 0.1, errors=errors, min_errors=5)
    assert grid.active.numel() > plain.active.numel()
    torch.testing.assert_close(grid.covering(errors)[1].sum(1), torch.ones(5), rtol=0, atol=1e-6)


def _stray_siren(steps: int = 400) -> torch.nn.Module:
    """A small SIREN fitted to a sphere of radius 0.5 and a stray ball of radius 0.16 at (0.72, 0, 0): the
    ball lies beyond the sphere's bounding cube, in the tile grid's ring."""
    from neural_bake.nets.siren import Siren

    net = Siren(32, 1, omega_0=10.0, generator=torch.Generator().manual_seed(3))
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    gen = torch.Generator().manual_seed(4)
    for _ in range(steps):
        x = torch.rand(1024, 3, generator=gen) * 2 - 1
        d = torch.minimum(x.norm(dim=1) - 0.5, (x - torch.tensor([0.72, 0.0, 0.0])).norm(dim=1) - 0.16)
        loss = ((net(x)[:, 0] - d) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net.eval()


@pytest.mark.parametrize("mined", [True, False])
def test_the_tile_level_removes_a_stray_solid_of_the_coarse_level_with_tiles_on_its_sign_errors(mined):
    h = _stray_siren()
    ball = torch.tensor([0.72, 0.0, 0.0]) + 0.08 * torch.nn.functional.normalize(
        torch.randn(400, 3, generator=torch.Generator().manual_seed(5)), dim=1) * torch.rand(400, 1)
    with torch.no_grad():
        assert float((h(ball)[:, 0] < 0).float().mean()) > 0.9  # the coarse level's stray solid
    pools = SdfFitConfig(pool_surface=6000, pool_near=6000, pool_uniform=16000, progress=False,
                         sign_fraction=0.5 if mined else 0.0, hard_every=25)
    fit = fit_tiles(sphere(0.5), h, 0.1, pools, TileFitConfig(**{**SMALL, "steps": 300, "min_errors": 8 if mined
                                                                 else 0}))
    ring = (fit.model.grid.centres(dtype=torch.float32)[:, 0] > 0.5 + 0.5 * fit.model.grid.cell)
    with torch.no_grad():
        f = h(ball)[:, 0] + fit.model.value(ball)
    if mined:
        assert bool(ring.any())  # the ball's cells hold networks
        assert float((f > 0).float().mean()) > 0.9  # and the ball is gone: f has the true distance's sign
    else:
        assert not bool(ring.any()) and float((f < 0).float().mean()) > 0.9


def test_a_time_budget_stops_on_the_injected_clock(fit_sphere_siren):
    h = fit_sphere_siren(r=R, steps=60, width=16)
    ticks = iter(range(10_000))
    fit = fit_tiles(sphere(), h, 0.1, POOLS, TileFitConfig(steps=1000, minutes=40 / 60, **SMALL),
                    clock=lambda: float(next(ticks)))
    # a clock that ticks a second a reading: two readings before the loop (the start, and what is left of the
    # budget after the pool and the grid), four a step (the loop's two, the sampling's two): the budget of
    # 40 s stops the loop after 10 steps, and the readings after it give the fit's seconds
    assert (fit.steps, fit.stopped_reason, fit.seconds) == (10, "time budget", pytest.approx(45.0))


@pytest.mark.parametrize("change,word", [({"grid": 0}, "grid"), ({"width": 1.5}, "width"), ({"depth": -1}, "depth"),
                                         ({"margin": 0.5}, "margin"), ({"lr": 0.0}, "lr"), ({"minutes": -1.0}, "minutes"),
                                         ({"steps": 0}, "steps"), ({"surface_points": 0}, "surface_points"),
                                         ({"grid": 63}, "grid must be at most 62"), ({"min_errors": -1}, "min_errors")])
def test_bad_settings_are_one_line_errors(fit_sphere_siren, change, word):
    h = fit_sphere_siren(r=R, steps=10, width=16)
    with pytest.raises(FitError, match=word):
        fit_tiles(sphere(), h, 0.1, POOLS, TileFitConfig(**{**SMALL, **change}))


def test_a_band_without_surface_points_or_of_no_width_is_refused(fit_sphere_siren):
    h = fit_sphere_siren(r=R, steps=10, width=16)
    with pytest.raises(FitError, match="band"):
        fit_tiles(sphere(), h, 0.0, POOLS, TileFitConfig(**SMALL))
    far = sphere(r=0.2)  # the coarse level's zero set (|x| = 0.7) is nowhere near this mesh's surface
    with pytest.raises(FitError, match="band"):
        fit_tiles(far, h, 0.01, POOLS, TileFitConfig(**SMALL))


# ---------------------------------------------------------------------------------- the "tiles" construction
TILES = dict(construction="tiles", width=32, coarse_width=16, depth=1, coarse_omega_0=10.0, tile_grid=3,
             tile_width=16, tile_depth=1, pool_surface=6000, pool_near=6000, pool_uniform=1500, progress=False,
             audit_candidates=2000, lr=1e-3)


def test_the_tiles_construction_fits_saves_loads_and_beats_its_coarse_level(tmp_path):
    from neural_bake.fit.sdf import fit_sdf, load_sdf
    from neural_bake.nets.tiles import TiledSdf

    fit = fit_sdf(sphere(), steps=320, **TILES)
    assert isinstance(fit.model, TiledSdf) and fit.construction == "tiles"
    assert fit.coarse.steps == 80 and fit.steps == 240  # coarse_share 0.25 of the steps, the tiles the rest
    # the sphere's cells of the 3³ over its cube, and any of the ring around it where the coarse level errs
    assert fit.label == f"16x1+{fit.model.tiles.tiles}x(16x1)" and 8 < fit.model.tiles.tiles <= 5 ** 3
    assert fit.band > 0 and fit.audit["candidates"] == 2000
    x = sphere_points(3000, 5)
    _, hg = gemm_gradient(fit.coarse.model, x)
    v, g = gemm_gradient(fit.model, x)
    # the sphere's oracle: its normals are its unit positions, its surface |x| = R
    assert float(normal_error_deg(g, x).median()) < 0.75 * float(normal_error_deg(hg, x).median())
    assert float(v.abs().max()) <= fit.distance_error * 1.5
    # the level stays a residual inside its band: no surface of its own past it (the sphere's sign, |x| − R)
    gen = torch.Generator().manual_seed(6)
    y = torch.rand(20_000, 3, generator=gen) * 2 - 1
    d = y.norm(dim=1) - R
    away = d.abs() > fit.band
    assert bool((torch.sign(fit.model(y)[:, 0]) == torch.sign(d))[away].all())
    path = fit.save(tmp_path / "t.sdf")
    again = load_sdf(path)
    assert isinstance(again.model, TiledSdf) and again.distance_error == pytest.approx(fit.distance_error)
    assert again.config.construction == "tiles" and again.config.tile_grid == 3
    assert torch.equal(again.model(x), fit.model(x))


@pytest.mark.parametrize("change,word", [({"tile_grid": 0}, "tile_grid"), ({"tile_width": 0}, "tile_width"),
                                         ({"tile_depth": -1}, "tile_depth"), ({"tile_margin": 0.3}, "tile_margin"),
                                         ({"budget": "steps"}, "reference steps"),
                                         ({"tile_grid": 63}, "tile_grid must be at most 62")])
def test_bad_tiles_settings_are_one_line_errors(change, word):
    from neural_bake.fit.sdf import fit_sdf

    with pytest.raises(FitError, match=word) as err:
        fit_sdf(sphere(), steps=10, **{**TILES, **change})
    assert "\n" not in str(err.value)


def test_a_time_budgeted_tile_level_is_accounted_and_warns_when_short(fit_sphere_siren, monkeypatch):
    from neural_bake.errors import NeuralBakeWarning
    from neural_bake.fit import budget
    from neural_bake.fit.budget import TILE_STEP, TILE_STEP_COST, tile_level_cost

    assert tile_level_cost(10, *TILE_STEP[:2], TILE_STEP[2]) == pytest.approx(10 * TILE_STEP_COST)
    assert TILE_STEP_COST > 0 and tile_level_cost(10, 16, 1, 128) is None
    h = fit_sphere_siren(r=R, steps=60, width=16)
    cfg = TileFitConfig(steps=1000, minutes=40 / 60, **{**SMALL, "width": 64, "depth": 2, "surface_points": 256,
                                                         "volume_points": 320})
    rates = []
    monkeypatch.setattr(budget, "_full_rate", lambda: rates[0])

    def run():
        ticks = iter(range(10_000))
        return fit_tiles(sphere(), h, 0.1, POOLS, cfg, clock=lambda: float(next(ticks)))

    k = fit_tiles(sphere(), h, 0.1, POOLS, replace_steps(cfg, 1)).model.tiles
    # the injected clock makes 10 steps in the 40 s (test above), each with 1 s of the asset's own work (its
    # sampling's two readings). A machine whose step takes 0.2 s quiet makes 40 / 1.2 = 33: 10 is short
    rates.append(k * TILE_STEP_COST / 0.2)
    with pytest.warns(NeuralBakeWarning, match=rf"tile level \({k} tiles\): made 10 steps of the ~33 this machine"):
        fit = run()
    assert fit.steps == 10 and fit.budget["expected_steps"] == 33
    assert fit.budget["asset_seconds_per_step"] == pytest.approx(1.0)
    assert fit.budget["stopped"] == "time budget (40 s) used"
    rates[0] = k * TILE_STEP_COST / 2.9  # one whose step takes 2.9 s makes 40 / 3.9 = 10: no warning
    fit = run()
    assert fit.budget["expected_steps"] == 10 and fit.budget["warning"] is None


def replace_steps(cfg, steps):
    from dataclasses import replace

    return replace(cfg, steps=steps, minutes=None)


def test_reference_work_sets_the_steps_by_the_number_of_tiles(fit_sphere_siren, monkeypatch):
    from neural_bake.fit import budget
    from neural_bake.fit.budget import TILE_STEP_COST

    monkeypatch.setattr(budget, "_full_rate", lambda: 100.0)
    h = fit_sphere_siren(r=R, steps=60, width=16)
    cfg = TileFitConfig(steps=1, **{**SMALL, "width": 64, "depth": 2, "surface_points": 256, "volume_points": 320})
    k = fit_tiles(sphere(), h, 0.1, POOLS, cfg).model.tiles
    fit = fit_tiles(sphere(), h, 0.1, POOLS, cfg, reference_work=3.5 * k * TILE_STEP_COST)
    assert fit.steps == 3 and fit.budget["reference_steps"] == 3 and fit.budget["budget"] == "steps"
    assert fit.budget["estimated_seconds"] == pytest.approx(3 * k * TILE_STEP_COST / 100.0)
    with pytest.raises(FitError, match="no reference step cost"):
        fit_tiles(sphere(), h, 0.1, POOLS, TileFitConfig(steps=1, **SMALL), reference_work=10.0)


def test_band_pools_keep_off_surface_points_out_to_the_shell(fit_sphere_siren):
    from neural_bake.fit.sdf_pools import band_pools

    h = fit_sphere_siren(r=R, steps=60, width=16)
    gen = torch.Generator().manual_seed(7)
    surf = sphere_points(500, 8)
    vol = torch.rand(4000, 3, generator=gen) * 2 - 1
    data = {"surf_p": surf, "surf_n": torch.nn.functional.normalize(surf, dim=1), "vol_p": vol,
            "vol_d": vol.norm(dim=1) - R, "n_near": 0}
    hv = h(vol)[:, 0].detach()
    one, two = band_pools(h, 0.1)(data), band_pools(h, 0.1, shell=2.0)(data)
    assert one["vol_p"].shape[0] == int((hv.abs() < 0.1).sum())
    assert two["vol_p"].shape[0] == int((hv.abs() < 0.2).sum()) > one["vol_p"].shape[0]
    assert torch.equal(one["surf_p"], two["surf_p"])  # surface points stay in the band
    with pytest.raises(FitError, match="shell"):
        fit_tiles(sphere(), h, 0.1, POOLS, TileFitConfig(**{**SMALL, "shell": 0.5}))


def test_the_tiles_construction_checkpoints_and_resumes_both_levels(tmp_path):
    from neural_bake.fit.residual import coarse_checkpoint
    from neural_bake.fit.sdf import fit_sdf

    ckpt = tmp_path / "run.ckpt"
    first = fit_sdf(sphere(), steps=40, checkpoint=str(ckpt), checkpoint_every=10, **TILES)
    assert ckpt.is_file() and Path(coarse_checkpoint(str(ckpt))).is_file()
    again = fit_sdf(sphere(), steps=40, checkpoint=str(ckpt), checkpoint_every=10, resume=True, **TILES)
    # both levels were finished: the resumed run takes their weights and makes no step
    assert again.stopped_reason == "resumed finished run" and again.steps == first.steps == 30
    x = sphere_points(500, 9)
    assert torch.equal(again.model(x), first.model(x))
