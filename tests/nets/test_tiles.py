"""neural_bake.nets.tiles: the tiles' partition of unity, its gradients, and the blended residual's value and
gradient against a slow reference (autograd of the blend written out tile by tile) in float32 and float64; the
tiled SDF h + r: its values, GEMM gradients and range bounds (checked against dense samples of each box)."""

import math

import pytest
import torch

from neural_bake.errors import NeuralBakeError
from neural_bake.nets.siren import Siren
from neural_bake.nets.gemm import gemm_gradient
from neural_bake.nets.range_analysis import range_bound
from neural_bake.nets.tiles import TiledSdf, TileGrid, TiledSiren, smoothstep


def full_grid(g=3, margin=0.2):
    return TileGrid([-1.0, -1.0, -1.0], 2.0 / g, g, margin, torch.arange(g ** 3))


def points_in(grid, n, seed=0, dtype=torch.float64, pad=0.0):
    gen = torch.Generator().manual_seed(seed)
    span = grid.cell * grid.grid
    return (grid.origin + pad + (span - 2 * pad) * torch.rand(n, 3, generator=gen, dtype=torch.float64)).to(dtype)


def test_smoothstep_ends_flat():
    s, d = smoothstep(torch.tensor([-1.0, 0.0, 0.5, 1.0, 2.0]))
    assert s.tolist() == [0.0, 0.0, 0.5, 1.0, 1.0]
    assert d.tolist() == [0.0, 0.0, 1.5, 0.0, 0.0]


def test_weights_are_a_partition_of_unity_inside_a_full_grid():
    grid = full_grid()
    p = points_in(grid, 4000, pad=grid.margin * grid.cell)  # away from the grid's outer faces
    tiles, w, dw = grid.covering(p)
    assert (w >= 0).all() and (w <= 1).all()
    torch.testing.assert_close(w.sum(1), torch.ones(len(p), dtype=p.dtype), rtol=0, atol=1e-12)
    torch.testing.assert_close(dw.sum(1), torch.zeros(len(p), 3, dtype=p.dtype), rtol=0, atol=1e-9)
    assert ((tiles >= 0) == (w > 0)).all()  # in a full grid every cell around a point has a network and a share
    # a cell's own centre is its alone
    c = grid.centres()
    tiles, w, _ = grid.covering(c)
    assert (tiles[:, 0] == torch.arange(grid.grid ** 3)).all() and (w[:, 0] == 1).all()


def test_weight_gradients_match_finite_differences():
    grid = TileGrid([-1.0, -0.5, -0.7], 0.5, 4, 0.25, torch.arange(64))
    p = points_in(grid, 3000, seed=1)
    tiles, w, dw = grid.covering(p)
    h = 1e-6
    for ax in range(3):
        step = torch.zeros(3, dtype=p.dtype)
        step[ax] = h
        t_plus, w_plus, _ = grid.covering(p + step)
        t_minus, w_minus, _ = grid.covering(p - step)
        same = (t_plus == tiles).all(1) & (t_minus == tiles).all(1)  # not across a cell face
        assert same.float().mean() > 0.99
        fd = (w_plus - w_minus) / (2 * h)
        torch.testing.assert_close(dw[same, :, ax], fd[same], rtol=0, atol=1e-5)


def test_weights_are_continuous_across_cell_faces():
    grid = full_grid(4, 0.1)
    face = grid.origin[0] + 2 * grid.cell
    p = torch.tensor([[face - 1e-12, 0.1, 0.2], [face + 1e-12, 0.1, 0.2]], dtype=torch.float64)
    tiles, w, _ = grid.covering(p)
    by_tile = [dict(zip(t.tolist(), x.tolist())) for t, x in zip(tiles, w)]
    for t in set(by_tile[0]) | set(by_tile[1]):
        if t >= 0:
            assert by_tile[0].get(t, 0.0) == pytest.approx(by_tile[1].get(t, 0.0), abs=1e-9)


def test_missing_tiles_fade_the_blend_to_zero():
    # two active cells side by side in x; beyond their seams the blend is exactly 0
    grid = TileGrid([0.0, 0.0, 0.0], 1.0, 3, 0.2, [1 * 9 + 1 * 3 + 1, 0 * 9 + 1 * 3 + 1])
    net = TiledSiren(grid, 16, 1, zero_output=False, generator=torch.Generator().manual_seed(0)).double()
    xs = torch.linspace(0.0, 3.0, 301, dtype=torch.float64)
    p = torch.stack([xs, torch.full_like(xs, 1.5), torch.full_like(xs, 1.5)], 1)
    _, w, _ = grid.covering(p)
    total = w.sum(1)
    assert (total[(xs > 0.2) & (xs < 1.8)] == 1).all()  # inside the two cells
    assert (total[xs > 2.2] == 0).all()  # past the seam into the inactive third cell
    r, g = net.value_and_gradient(p)
    assert (r[xs > 2.2] == 0).all() and (g[xs > 2.2] == 0).all()
    assert r[(xs > 0.5) & (xs < 1.5)].abs().max() > 0


def slow_blend(net: TiledSiren, p: torch.Tensor):
    """The blend by autograd, tile by tile: each tile a Siren rebuilt from the stacked weights, its weight
    recomputed from the per-axis smoothstep formula."""
    grid = net.grid
    p = p.clone().requires_grad_(True)
    total = torch.zeros(len(p), dtype=p.dtype)
    centres = grid.centres(dtype=p.dtype)
    for t in range(net.tiles):
        siren = Siren(net.width, net.depth, omega_0=net.omega_0, hidden_omega=net.hidden_omega).to(p.dtype)
        with torch.no_grad():
            for i, layer in enumerate(siren.layers):
                layer.weight.copy_(net.weights[i][t])
                layer.bias.copy_(net.biases[i][t])
        lo = centres[t] - grid.cell / 2
        hi = centres[t] + grid.cell / 2
        m = grid.margin * grid.cell
        w = torch.ones(len(p), dtype=p.dtype)
        for ax in range(3):
            x = p[:, ax]
            rise = smoothstep((x - (lo[ax] - m)) / (2 * m))[0]
            fall = 1 - smoothstep((x - (hi[ax] - m)) / (2 * m))[0]
            w = w * rise * fall
        total = total + w * siren((p - centres[t]) / grid.half)[:, 0] * grid.half
    (g,) = torch.autograd.grad(total.sum(), p)
    return total.detach(), g


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-10), (torch.float32, 2e-4)])
def test_blend_matches_the_slow_reference(dtype, tol):
    gen = torch.Generator().manual_seed(3)
    active = torch.randperm(27, generator=gen)[:20]
    grid = TileGrid([-0.9, -1.1, -1.0], 0.7, 3, 0.15, active)
    net = TiledSiren(grid, 24, 2, omega_0=20.0, zero_output=False, generator=gen).double()
    p = points_in(grid, 1500, seed=4)
    ref_v, ref_g = slow_blend(net, p)
    v, g = net.to(dtype).value_and_gradient(p.to(dtype))
    assert v.dtype == dtype and g.dtype == dtype
    scale = ref_v.abs().max()
    torch.testing.assert_close(v.double(), ref_v, rtol=0, atol=tol * float(scale))
    torch.testing.assert_close(g.double(), ref_g, rtol=0, atol=tol * float(ref_g.abs().max()))


def test_tile_batch_gradients_are_autograds():
    grid = full_grid(2, 0.25)
    net = TiledSiren(grid, 16, 2, zero_output=False, generator=torch.Generator().manual_seed(5)).double()
    local = (torch.rand(grid.active.numel(), 64, 3, generator=torch.Generator().manual_seed(6),
                        dtype=torch.float64) * 2 - 1).requires_grad_(True)
    v, g = net.tile_values_and_gradients(local)
    (auto,) = torch.autograd.grad(v.sum(), local, create_graph=True)
    # values are in the unit frame (× half), gradients too: d/dx = d/d(local) ÷ half
    torch.testing.assert_close(g, auto / grid.half, rtol=1e-10, atol=1e-12)
    # a loss on the gradients reaches the weights with one ordinary backward pass
    (g ** 2).sum().backward()
    assert all(w.grad is not None and bool(torch.isfinite(w.grad).all()) for w in net.weights)


def test_a_new_residual_level_is_zero():
    grid = full_grid(2, 0.2)
    net = TiledSiren(grid, 16, 1)
    r, g = net.value_and_gradient(points_in(grid, 100, dtype=torch.float32))
    assert (r == 0).all() and (g == 0).all()


def test_grid_round_trips_and_rejects_bad_settings():
    grid = TileGrid([0.0, 1.0, 2.0], 0.5, 4, 0.1, [3, 17, 60])
    again = TileGrid.from_dict(grid.to_dict())
    assert again.to_dict() == grid.to_dict()
    assert grid.half == pytest.approx(0.5 * 0.6)
    for args, word in [(([0, 0], 1.0, 2, 0.1, [0]), "origin"), (([0, 0, 0], 0.0, 2, 0.1, [0]), "cell"),
                       (([0, 0, 0], 1.0, 0, 0.1, [0]), "grid"), (([0, 0, 0], 1.0, 2, 0.3, [0]), "margin"),
                       (([0, 0, 0], 1.0, 2, 0.1, [8]), "active"), (([0, 0, 0], 1.0, 2, 0.1, [1, 1]), "active"),
                       (([0, 0, 0], 1.0, 2, 0.1, []), "active"), (([0, math.nan, 0], 1.0, 2, 0.1, [0]), "origin")]:
        with pytest.raises(NeuralBakeError, match=word):
            TileGrid(*args)
    with pytest.raises(NeuralBakeError, match="width"):
        TiledSiren(grid, 0)
    with pytest.raises(NeuralBakeError, match="shape"):
        TiledSiren(grid, 8).value_and_gradient(torch.zeros(5, 2))
    with pytest.raises(NeuralBakeError, match="local points"):
        TiledSiren(grid, 8).tile_values_and_gradients(torch.zeros(2, 5, 3))


def tiled_sdf(seed=7, dtype=torch.float64, g=4, n_active=40):
    gen = torch.Generator().manual_seed(seed)
    active = torch.randperm(g ** 3, generator=gen)[:n_active]
    grid = TileGrid([-1.0, -0.9, -1.1], 2.0 / g, g, 0.12, active)
    tiles = TiledSiren(grid, 16, 1, omega_0=15.0, zero_output=False, generator=gen)
    with torch.no_grad():  # a residual's size: small beside the coarse level
        tiles.weights[-1].mul_(0.2)
        tiles.biases[-1].mul_(0.2)
    return TiledSdf(Siren(24, 2, omega_0=10.0, generator=gen), tiles).to(dtype).eval()


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-10), (torch.float32, 2e-4)])
def test_tiled_sdf_is_the_coarse_level_plus_the_blend(dtype, tol):
    f = tiled_sdf()
    p = points_in(f.tiles.grid, 2000, seed=8)
    ref_r, ref_rg = slow_blend(f.tiles, p)
    q = p.clone().requires_grad_(True)
    h = f.coarse(q)[:, 0]
    (hg,) = torch.autograd.grad(h.sum(), q)
    ref_v, ref_g = h.detach() + ref_r, hg + ref_rg
    f = f.to(dtype)
    v, g = gemm_gradient(f, p.to(dtype))  # handed to TiledSdf.gemm_gradient
    assert v.shape == (2000, 1) and g.shape == (2000, 3) and v.dtype == dtype
    torch.testing.assert_close(v[:, 0].double(), ref_v, rtol=0, atol=tol * float(ref_v.abs().max()))
    torch.testing.assert_close(g.double(), ref_g, rtol=0, atol=tol * float(ref_g.abs().max()))
    torch.testing.assert_close(f(p.to(dtype))[:, 0], v[:, 0], rtol=0, atol=tol * float(ref_v.abs().max()))
    assert f.label == "24x2+40x(16x1)"
    with pytest.raises(NeuralBakeError, match="differentiable"):
        gemm_gradient(f, p.to(dtype), differentiable=True)


@pytest.mark.parametrize("half_side", [0.02, 0.15, 0.9])  # inside a cell, across seams, many cells wide
def test_tiled_sdf_range_bounds_hold_over_their_boxes(half_side):
    f = tiled_sdf(seed=9)
    gen = torch.Generator().manual_seed(10)
    b = 60
    centers = (torch.rand(b, 3, generator=gen, dtype=torch.float64) * 2 - 1) * 0.9
    axes = torch.diag_embed(torch.full((b, 3), half_side, dtype=torch.float64))
    lo, hi = range_bound(f, centers, axes)  # handed to TiledSdf.range_bound
    assert bool((lo <= hi).all())
    t = torch.rand(b, 400, 3, generator=gen, dtype=torch.float64) * 2 - 1
    corners = torch.tensor([[a, c, d] for a in (-1.0, 1.0) for c in (-1.0, 1.0) for d in (-1.0, 1.0)],
                           dtype=torch.float64).expand(b, 8, 3)
    t = torch.cat([t, corners], dim=1)
    pts = centers[:, None, :] + t * half_side
    v = f(pts.reshape(-1, 3))[:, 0].reshape(b, -1)
    assert bool((v >= lo[:, None]).all() and (v <= hi[:, None]).all())
    # a ray segment (one axis) too
    seg = torch.nn.functional.normalize(torch.randn(b, 1, 3, generator=gen, dtype=torch.float64), dim=2) * half_side
    lo, hi = range_bound(f, centers, seg)
    s = torch.linspace(-1, 1, 101, dtype=torch.float64)
    v = f((centers[:, None, :] + s[None, :, None] * seg).reshape(-1, 3))[:, 0].reshape(b, -1)
    assert bool((v >= lo[:, None]).all() and (v <= hi[:, None]).all())


def test_tiled_sdf_far_from_its_tiles_is_the_coarse_level():
    f = tiled_sdf(seed=11)
    far = torch.tensor([[5.0, 5.0, 5.0], [-4.0, 0.0, 0.0]], dtype=torch.float64)
    v, g = gemm_gradient(f, far)
    hv, hg = gemm_gradient(f.coarse, far)
    assert torch.equal(v, hv) and torch.equal(g, hg)
    axes = torch.diag_embed(torch.full((2, 3), 0.1, dtype=torch.float64))
    lo, hi = range_bound(f, far, axes)
    clo, chi = range_bound(f.coarse, far, axes)
    assert bool((lo <= clo).all() and (hi >= chi).all()) and float((hi - lo - (chi - clo)).abs().max()) < 1e-9


def test_a_tiled_sdf_has_no_reduced_precision_and_no_single_layer_list():
    from neural_bake.nets.precision import resolve_precision

    f = tiled_sdf(dtype=torch.float32)
    assert resolve_precision("auto", f)[0] == "fp32"
    with pytest.raises(NeuralBakeError, match="bf16"):
        resolve_precision("bf16", f)
    with pytest.raises(NeuralBakeError, match="not one SIREN"):
        f.affine_layers()
    with pytest.raises(NeuralBakeError, match="R\\^3 to R"):
        TiledSdf(Siren(8, 1, in_dim=4), f.tiles)
