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
