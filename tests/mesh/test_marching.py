"""Marching cubes: analytic sphere, outward winding, range-pruned run identical to the dense one."""

import math

import numpy as np
import pytest
import torch

from neural_bake.errors import NeuralBakeError
from neural_bake.mesh.marching import grid_points, march
from neural_bake.nets.siren import Siren
from neural_bake.types import Frame


def sphere_siren(a=1.5, r=0.5, width=12, bumps=0.02, seed=0):
    """A (width, 0) Siren whose level 0 is close to the sphere of radius r (no training):
    f(x) = Σ_i 2 (1 - cos(a x_i)) / a² - r² ≈ |x|² - r², plus a few small random sine bumps."""
    g = torch.Generator().manual_seed(seed)
    net = Siren(width, 0, omega_0=1.0, hidden_omega=1.0, generator=g)
    with torch.no_grad():
        w1, b1 = net.layers[0].weight, net.layers[0].bias
        w1.normal_(0, 3.0, generator=g)
        b1.uniform_(-math.pi, math.pi, generator=g)
        w1[:3] = a * torch.eye(3)
        b1[:3] = math.pi / 2  # sin(a x + π/2) = cos(a x)
        w2, b2 = net.layers[1].weight, net.layers[1].bias
        w2.uniform_(-bumps, bumps, generator=g)
        w2[0, :3] = -2.0 / a**2
        b2.fill_(6.0 / a**2 - r**2)
    return net


def test_sphere_sdf_vertices_on_radius_and_outward():
    r = 0.55
    mesh, stats = march(lambda x: x.norm(dim=1) - r, 24, frame=Frame((1.0, 0.0, 0.0), 2.0))
    h = 2.0 / 24
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert np.abs(radius - r).max() < 0.1 * h  # linear interpolation of an SDF: error << one cell
    c = mesh.triangles.mean(axis=1)
    assert (np.sum(mesh.face_normals * c, axis=1) > 0).all()  # every face normal points outward
    assert (np.sum(mesh.vertex_normals * mesh.vertices, axis=1) > 0.95 * radius).all()
    assert mesh.watertight and not mesh.degenerate.any()
    assert mesh.frame == Frame((1.0, 0.0, 0.0), 2.0)
    assert stats["evaluations"] == 25**3 and stats["faces"] == mesh.n_faces
    # volume of the closed mesh ~ 4/3 π r³ (positive: outward winding)
    t = mesh.triangles
    vol = np.einsum("fi,fi->f", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6
    assert vol == pytest.approx(4 / 3 * math.pi * r**3, rel=0.02)


def test_level_and_bound():
    mesh, _ = march(lambda x: x.norm(dim=1), 20, level=0.3, bound=0.5)
    assert np.abs(np.linalg.norm(mesh.vertices, axis=1) - 0.3).max() < 0.1 * (1.0 / 20)
    assert np.abs(mesh.vertices).max() <= 0.5


def test_siren_inside_negative_normals_point_to_positive():
    net = sphere_siren(bumps=0.0)
    mesh, _ = march(net, 16)
    x = torch.as_tensor(mesh.vertices + 0.05 * mesh.vertex_normals, dtype=torch.float32)
    with torch.no_grad():
        assert (net(x)[:, 0] > 0).all()


@pytest.mark.parametrize("method", ["affine-fixed", "interval"])
@pytest.mark.parametrize("resolution", [32, 37])
def test_pruned_gives_identical_triangles_with_fewer_evaluations(method, resolution):
    net = sphere_siren()
    dense, sd = march(net, resolution)
    pruned, sp = march(net, resolution, pruned=True, method=method)
    np.testing.assert_array_equal(pruned.faces, dense.faces)
    np.testing.assert_array_equal(pruned.vertices, dense.vertices)
    assert sp["evaluations"] < 0.5 * sd["evaluations"]
    assert sp["boxes_pruned"] > 0 and sp["bound_evaluations"] > 0


def test_pruned_on_a_random_siren_at_its_median_level():
    g = torch.Generator().manual_seed(3)
    net = Siren(16, 1, omega_0=2.0, hidden_omega=2.0, generator=g).double()
    with torch.no_grad():
        level = float(net(torch.rand(4000, 3, dtype=torch.float64, generator=g) * 2 - 1).median())
    dense, sd = march(net, 24, level=level)
    pruned, sp = march(net, 24, level=level, pruned=True, leaf_cells=2)
    np.testing.assert_array_equal(pruned.faces, dense.faces)
    np.testing.assert_array_equal(pruned.vertices, dense.vertices)
    assert sp["evaluations"] <= sd["evaluations"]


@pytest.mark.parametrize("method", ["affine-fixed", "interval"])
def test_pruned_tiled_sdf_gives_the_dense_triangles(method):
    from neural_bake.nets.tiles import TiledSdf, TileGrid, TiledSiren

    g = torch.Generator().manual_seed(5)
    tiles = TiledSiren(TileGrid([-1.0, -1.0, -1.0], 0.5, 4, 0.1, torch.arange(64)[::2]), 8, 1, omega_0=4.0,
                       hidden_omega=4.0, zero_output=False, generator=g)
    with torch.no_grad():  # a residual that moves the sphere's surface by a few hundredths
        tiles.weights[-1].mul_(0.3)
        tiles.biases[-1].mul_(0.3)
    net = TiledSdf(sphere_siren(), tiles).double()
    dense, sd = march(net, 32)
    pruned, sp = march(net, 32, pruned=True, method=method)
    np.testing.assert_array_equal(pruned.faces, dense.faces)
    np.testing.assert_array_equal(pruned.vertices, dense.vertices)
    assert sp["evaluations"] < sd["evaluations"] and sp["boxes_pruned"] > 0
    plain, _ = march(sphere_siren().double(), 32)
    assert plain.n_faces != dense.n_faces or not np.array_equal(plain.vertices, dense.vertices)  # tiles count


def test_grid_points():
    np.testing.assert_allclose(grid_points(4, 1.0), [-1, -0.5, 0, 0.5, 1])


def test_errors():
    f = lambda x: x.norm(dim=1) - 0.5  # noqa: E731
    with pytest.raises(NeuralBakeError, match="resolution must be an integer >= 2"):
        march(f, 1)
    with pytest.raises(NeuralBakeError, match="bound must be a positive number"):
        march(f, 8, bound=0)
    with pytest.raises(NeuralBakeError, match="chunk_size must be a positive integer"):
        march(f, 8, chunk_size=0)
    with pytest.raises(NeuralBakeError, match="leaf_cells must be a positive integer"):
        march(f, 8, leaf_cells=0)
    with pytest.raises(NeuralBakeError, match="level must be finite"):
        march(f, 8, level=float("nan"))
    with pytest.raises(NeuralBakeError, match="pruned=True needs a Siren"):
        march(f, 8, pruned=True)
    with pytest.raises(NeuralBakeError, match="does not cross the grid"):
        march(lambda x: x.norm(dim=1) + 1.0, 8)
    with pytest.raises(NeuralBakeError, match="non-finite values"):
        march(lambda x: x.norm(dim=1) / 0.0 - x.norm(dim=1) / 0.0, 8)
    with pytest.raises(NeuralBakeError, match="must map \\(N, 3\\) points to \\(N,\\) values"):
        march(lambda x: x, 8)
    with pytest.raises(NeuralBakeError, match="scalar SDF of 3-D points"):
        march(Siren(8, 0, out_dim=2), 8)
    with pytest.raises(NeuralBakeError, match="must be a Siren or a callable"):
        march(42, 8)


# -- cost-aware pruning (pruned="auto") --------------------------------------------------------------------


def _same(a, b):
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.vertices, b.vertices)


def _median_level_siren(seed, omega_0):
    g = torch.Generator().manual_seed(seed)
    net = Siren(16, 1, omega_0=omega_0, hidden_omega=2.0, generator=g).double()
    with torch.no_grad():
        level = float(net(torch.rand(4000, 3, dtype=torch.float64, generator=g) * 2 - 1).median())
    return net, level


def test_auto_bounds_levels_that_pay_and_gives_identical_triangles():
    net = sphere_siren()
    dense, sd = march(net, 64)
    auto, sa = march(net, 64, pruned="auto", bound_cost={"interval": 10, "affine-fixed": 30})
    _same(auto, dense)
    assert sa["mode"] == "auto" and sa["reason"] == ""
    # with these costs both levels pay: 8-cell boxes (512 cells) and 4-cell ones (64 cells, q ~ 0.45)
    assert [e["decision"] for e in sa["levels"]] == ["bound", "bound"] and sa["levels_bounded"] == 2
    assert sa["evaluations"] < 0.15 * sd["evaluations"]
    assert sa["evaluation_ratio"] == pytest.approx(sa["grid_points"] / sa["evaluations"])
    top = sa["levels"][0]
    assert top["side"] == 8 and top["boxes"] == 512 and top["bounded"] == 512
    assert set(top["probe"]) == {"interval", "affine-fixed"}
    for m, p in top["probe"].items():
        assert 0 < p["pruned_fraction"] <= 1 and p["eval_cost"] == 1.0
    assert top["probe"]["interval"]["bound_cost"] == 10 and top["probe"]["affine-fixed"]["bound_cost"] == 30
    # the method with the larger gain q·cells·c_e - PAYBACK·c_b bounds the level
    gain = {m: p["pruned_fraction"] * 512 - 1.5 * p["bound_cost"] for m, p in top["probe"].items()}
    assert top["method"] == max(gain, key=gain.get)
    assert sa["boxes_pruned"] == sum(e["pruned"] for e in sa["levels"])
    assert sa["boxes_unknown"] == sum(e["dense"] for e in sa["levels"])


def test_auto_stops_where_bounds_cost_more_than_they_save():
    net = sphere_siren()
    dense, sd = march(net, 64)
    # 4-cell boxes (64 cells) prune ~45%: ~29 evaluations saved per box, less than 1.5 × 40
    auto, sa = march(net, 64, pruned="auto", bound_cost=40.0, method="affine-fixed")
    _same(auto, dense)
    assert [e["decision"] for e in sa["levels"]] == ["bound", "dense"]
    second = sa["levels"][1]
    assert second["bounded"] == 64 and second["method"] is None  # only the probe was bounded
    assert second["dense"] + second["pruned"] == second["boxes"]
    assert sa["bound_evaluations"] == 512 + 64
    assert sa["evaluations"] < sd["evaluations"]


def test_auto_skips_a_level_whose_bounds_are_too_loose_and_bounds_the_next():
    net, level = _median_level_siren(seed=1, omega_0=8.0)
    dense, _ = march(net, 64, level=level)
    auto, sa = march(net, 64, level=level, pruned="auto", bound_cost=1.0)
    _same(auto, dense)
    assert [(e["side"], e["decision"]) for e in sa["levels"]] == [(8, "skip"), (4, "bound")]
    assert sa["levels"][0]["probe"]["affine-fixed"]["pruned_fraction"] == 0.0
    assert sa["levels"][1]["boxes"] == 4096 and sa["levels"][1]["pruned"] > 1000
    assert sa["levels_bounded"] == 1 and sa["evaluations"] < 0.7 * sa["grid_points"]


def test_auto_marches_densely_when_no_level_can_pay():
    net, level = _median_level_siren(seed=0, omega_0=16.0)
    dense, sd = march(net, 64, level=level)
    auto, sa = march(net, 64, level=level, pruned="auto", bound_cost=100.0)
    _same(auto, dense)
    # 8-cell boxes prune nothing and their 4-cell children (64 cells) could not pay 1.5 × 100 even if all pruned
    assert [e["decision"] for e in sa["levels"]] == ["dense"]
    assert sa["levels_bounded"] == 0 and sa["evaluations"] == sd["evaluations"]
    assert sa["bound_evaluations"] == 2 * 64  # the probes, one per method
    assert "prune too little" in sa["reason"]


def test_auto_with_measured_costs_keeps_the_lattice_values():
    net = sphere_siren()
    dense, sd = march(net, 48)
    auto, sa = march(net, 48, pruned="auto")
    _same(auto, dense)
    assert sa["evaluations"] <= sd["evaluations"]
    assert sa["seconds_per_evaluation"] > 0
    for p in sa["levels"][0]["probe"].values():
        assert p["bound_cost"] > 0 and p["eval_cost"] == sa["seconds_per_evaluation"]
    assert sa["seconds_bound"] > 0 and sa["seconds_eval"] > 0 and sa["seconds"] >= sa["seconds_bound"]


def test_auto_falls_back_to_dense_for_callables_and_small_grids():
    f = lambda x: x.norm(dim=1) - 0.5  # noqa: E731
    mesh, s = march(f, 16, pruned="auto")
    assert s["mode"] == "auto" and s["evaluations"] == 17**3 and "not a Siren" in s["reason"]
    _same(mesh, march(f, 16)[0])
    net = sphere_siren()
    mesh, s = march(net, 16, pruned="auto")
    assert s["evaluations"] == 17**3 and s["bound_evaluations"] == 0 and "grid too small" in s["reason"]


def test_forced_pruning_with_auto_method_probes_both_methods():
    net = sphere_siren()
    dense, sd = march(net, 32)
    pruned, sp = march(net, 32, pruned=True, method="auto", leaf_cells=2, bound_cost={"interval": 1, "affine-fixed": 2})
    _same(pruned, dense)
    assert sp["mode"] == "pruned" and all(e["decision"] == "bound" for e in sp["levels"])
    assert [e["side"] for e in sp["levels"]] == [4, 2]
    assert set(sp["levels"][0]["probe"]) == {"interval", "affine-fixed"}


def test_auto_errors():
    net = sphere_siren()
    with pytest.raises(NeuralBakeError, match="pruned must be False, True or 'auto'"):
        march(net, 8, pruned="yes")
    with pytest.raises(NeuralBakeError, match="pruned must be False, True or 'auto'"):
        march(net, 8, pruned=1)
    with pytest.raises(NeuralBakeError, match="unknown method 'bogus'"):
        march(net, 8, pruned=True, method="bogus")
    with pytest.raises(NeuralBakeError, match="bound_cost has no cost for method\\(s\\) affine-fixed"):
        march(net, 8, pruned="auto", bound_cost={"interval": 1.0})
    with pytest.raises(NeuralBakeError, match="bound_cost must be a non-negative number"):
        march(net, 8, pruned="auto", bound_cost=-1.0)
    with pytest.raises(NeuralBakeError, match="bound_cost must be a non-negative number"):
        march(net, 8, pruned="auto", bound_cost={"interval": 1.0, "affine-fixed": "x"})
