"""sdf_metrics and mesh_distances against analytic cases (concentric spheres, a mesh against itself)."""

import numpy as np
import pytest
import torch
import trimesh

from neural_bake.errors import FitError
from neural_bake.fit.metrics import grid_values, mesh_distances, sdf_metrics, zero_level_mesh
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.nets.gemm import gemm_gradient
from neural_bake.nets.siren import Siren


def sphere(r, sub=4):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=r)
    return mesh_from_arrays(m.vertices, m.faces, normalise=False)


def test_mesh_against_itself_is_zero():
    s = sphere(0.8)
    d = mesh_distances(s.vertices, s.faces, s.vertices, s.faces, n=5000)
    assert d["chamfer_l1"] < 1e-6 and d["hausdorff"] < 1e-6


def test_concentric_spheres_distance_is_the_radius_gap():
    a, b = sphere(0.8), sphere(0.83)
    d = mesh_distances(a.vertices, a.faces, b.vertices, b.faces, n=5000)
    # both are inscribed polyhedra of subdivision 4: the gap is 0.03 up to the faceting (< 1e-3 here)
    assert d["chamfer_l1"] == pytest.approx(0.03, abs=1e-3)
    assert d["hausdorff"] == pytest.approx(0.03, abs=1.5e-3)
    assert d["a_to_b_mean"] == pytest.approx(d["b_to_a_mean"], abs=1e-3)


def _sphere_net(r):
    """An exact 'network' |x| - r (a module with parameters and forward only: for grid/marching-cubes tests)."""
    class Net(torch.nn.Module):
        in_dim, out_dim = 3, 1

        def __init__(self):
            super().__init__()
            self.dummy = torch.nn.Parameter(torch.zeros(1, dtype=torch.float64))

        def forward(self, x):
            return (x.norm(dim=1, keepdim=True) - r) + 0 * self.dummy

    return Net()


def test_grid_values_layout():
    net = _sphere_net(0.5)
    vol = grid_values(net, 9)
    axis = np.linspace(-1, 1, 9)
    i, j, k = 1, 4, 7
    assert vol[i, j, k] == pytest.approx(np.sqrt(axis[i] ** 2 + axis[j] ** 2 + axis[k] ** 2) - 0.5, abs=1e-6)


def test_zero_level_mesh_of_a_sphere():
    v, f = zero_level_mesh(_sphere_net(0.6), 48)
    r = np.linalg.norm(v, axis=1)
    assert np.abs(r - 0.6).max() < 2.0 / 47 * 0.1 and len(f) > 100


@pytest.fixture(scope="module")
def sphere_siren(fit_sphere_siren):
    """A tiny Siren fitted to |x| - 0.7 in a few hundred Adam steps."""
    return fit_sphere_siren(0.7, width=32, steps=300)


def test_sdf_metrics_of_trained_sphere_network(sphere_siren):
    # metrics must see a close, well-oriented surface
    net, gen = sphere_siren, torch.Generator().manual_seed(1)
    mesh = sphere(0.7)
    res = sdf_metrics(net, mesh, n=5000, resolution=64)
    x = torch.randn(4000, 3, generator=gen)
    x = 0.7 * x / x.norm(dim=1, keepdim=True)
    with torch.no_grad():
        sup_on_sphere = float(net(x).abs().max())
    assert res["chamfer_l1"] < 0.006 and res["hausdorff"] < 0.02
    # a lower bound of the mesh -> network distance: the mesh vertices lie on the sphere, where |f| is
    # about the distance to the zero set (|∇f| ≈ 1)
    assert res["mesh_to_net_max"] <= 1.5 * sup_on_sphere + 0.002
    assert res["chamfer_l1"] == pytest.approx(0.5 * (res["net_to_mesh_mean"] + res["mesh_to_net_mean"]))
    assert res["normal_median_deg"] < 3 and res["normal_p95_deg"] < 6
    assert res["normal_median_deg"] <= res["normal_p95_deg"]


def _radial(p):
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def test_sdf_metrics_against_the_smooth_surface(sphere_siren):
    # oracle: a sphere's normals are its positions. A coarse icosphere's faces are several degrees off them
    # (reference: trimesh's own samples of the same faces); the fitted network is smoother than that faceting
    mesh = sphere(0.7, sub=2)
    res = sdf_metrics(sphere_siren, mesh, n=20_000, resolution=48, truth_normal=_radial)
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    pts, idx = trimesh.sample.sample_surface(tm, 20_000, seed=3)
    cos = (tm.face_normals[idx] * _radial(pts)).sum(axis=1)
    faceting = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    assert res["mesh_normal_truth_median_deg"] == pytest.approx(np.median(faceting), rel=0.05)
    assert res["mesh_normal_truth_p95_deg"] == pytest.approx(np.percentile(faceting, 95), rel=0.05)
    assert res["normal_truth_median_deg"] < 0.5 * res["mesh_normal_truth_median_deg"]
    assert res["normal_truth_median_deg"] <= res["normal_truth_p95_deg"]
    # against the faces the same gradients read about the faceting: the floor the smooth truth removes
    assert res["normal_median_deg"] > res["normal_truth_median_deg"]
    # the truth's length does not matter; pointing it inwards turns every angle around
    scaled = sdf_metrics(sphere_siren, mesh, n=20_000, resolution=48, truth_normal=lambda q: 5 * _radial(q))
    assert scaled["normal_truth_median_deg"] == pytest.approx(res["normal_truth_median_deg"], abs=1e-9)
    flipped = sdf_metrics(sphere_siren, mesh, n=20_000, resolution=48, truth_normal=lambda q: -_radial(q))
    assert flipped["normal_truth_median_deg"] == pytest.approx(180 - res["normal_truth_median_deg"], abs=1e-6)
    assert "normal_truth_median_deg" not in sdf_metrics(sphere_siren, mesh, n=2_000, resolution=48)


@pytest.mark.parametrize("bad, message", [
    (lambda q: q[:, :2], r"must return \(500, 3\) normals"),
    (lambda q: np.full_like(q, np.nan), "non-finite or zero normals"),
    (lambda q: np.zeros_like(q), "non-finite or zero normals"),
])
def test_sdf_metrics_rejects_a_bad_truth_normal(sphere_siren, bad, message):
    with pytest.raises(FitError, match=message):
        sdf_metrics(sphere_siren, sphere(0.7, sub=2), n=500, resolution=32, truth_normal=bad)


def test_sdf_metrics_errors():
    mesh = sphere(0.7, sub=2)
    net = Siren(8, 0)
    with pytest.raises(FitError, match="n must be a positive integer"):
        sdf_metrics(net, mesh, n=0)
    with pytest.raises(FitError, match="resolution must be an integer >= 8"):
        sdf_metrics(net, mesh, resolution=4)
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
        net.layers[-1].bias.fill_(1.0)  # f = 1 everywhere: no surface
    with pytest.raises(FitError, match="does not cross the grid"):
        sdf_metrics(net, mesh, n=100, resolution=16)


def _ray_zero(net, p):
    """Reference: the zero of f on the ray from the origin through each point (bisection in float64)."""
    d = torch.as_tensor(p / np.linalg.norm(p, axis=1, keepdims=True))
    lo, hi = torch.full((len(p), 1), 0.3, dtype=torch.float64), torch.full((len(p), 1), 0.95, dtype=torch.float64)
    net64 = Siren(**net.architecture).double()
    net64.load_state_dict(net.state_dict())
    with torch.no_grad():
        assert (net64(lo * d) < 0).all() and (net64(hi * d) > 0).all()
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            inside = net64(mid * d) < 0
            lo, hi = torch.where(inside, mid, lo), torch.where(inside, hi, mid)
    return (0.5 * (lo + hi) * d).numpy()


def test_mesh_to_network_distance_is_to_points_of_the_zero_set(sphere_siren):
    # at a coarse grid the marching-cubes mesh is off by its own error; the distances sdf_metrics reports go to
    # projected points with f ≈ 0: they agree with a ray-bisection reference, and never undercut a lower bound
    from neural_bake.fit.metrics import ZERO_SET_TOL, _closest, _distance_to_zero_set, _values

    net = sphere_siren
    mv, mf = zero_level_mesh(net, 12)
    rng = np.random.default_rng(0)
    p = rng.normal(size=(3000, 3))
    p = p / np.linalg.norm(p, axis=1, keepdims=True) * rng.uniform(0.66, 0.74, size=(3000, 1))
    d_mc, closest = _closest(mv, mf, p)
    d, fallback = _distance_to_zero_set(net, p, closest, d_mc, 3)
    assert fallback == 0
    ref = np.linalg.norm(p - _ray_zero(net, p), axis=1)  # an upper bound, ≈ the distance on a near-sphere
    assert (d <= ref + 1e-4).all()
    assert np.abs(d - ref).max() < 5e-4 < 5e-3 < np.abs(d_mc - ref).max()  # 5e-5 against 0.019 here
    _, g = gemm_gradient(net, torch.as_tensor(p, dtype=torch.float32))
    lipschitz = 1.2 * float(g.norm(dim=1).max())
    assert (d >= (np.abs(_values(net, p)) - ZERO_SET_TOL) / lipschitz - 1e-6).all()


def test_mesh_to_network_distance_falls_back_where_projection_fails():
    from neural_bake.fit.metrics import _distance_to_zero_set

    net = Siren(8, 0)
    with torch.no_grad():
        for q in net.parameters():
            q.zero_()
        net.layers[-1].bias.fill_(1.0)  # f = 1, ∇f = 0: nothing projects onto f = 0
    p = np.random.default_rng(0).normal(size=(50, 3))
    d_mc = np.arange(50.0)
    d, fallback = _distance_to_zero_set(net, p, p.copy(), d_mc, 2)
    assert fallback == 50 and np.array_equal(d, d_mc)
