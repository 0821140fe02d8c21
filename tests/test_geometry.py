"""Shared mesh geometry: vertex normals, the edge report and the cached ray-casting scene (neural_bake.geometry)."""

import numpy as np
import pytest
import trimesh

from neural_bake import geometry
from neural_bake.constants import RAYCAST_SCENE_CACHE
from neural_bake.types import Mesh
from neural_bake.geometry import area_weighted_normals, edge_report, raycasting_scene, welded_edges

TETRA_V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_sphere_normals_are_its_positions(dtype):
    s = trimesh.creation.icosphere(subdivisions=3)
    n = area_weighted_normals(s.vertices.astype(dtype), s.faces)
    assert n.dtype == np.float64
    cos = np.einsum("ij,ij->i", n, s.vertices / np.linalg.norm(s.vertices, axis=1, keepdims=True))
    assert cos.min() > np.cos(np.radians(1.0))  # the facets of a 642-vertex icosphere: 0.7° at most


def test_normals_match_a_slow_per_vertex_sum():
    rng = np.random.default_rng(3)
    v = rng.normal(size=(30, 3))
    f = rng.integers(0, 30, size=(60, 3))
    fast = area_weighted_normals(v, f)
    for i in range(30):
        acc = np.zeros(3)
        for tri in f:
            if i in tri:
                acc += np.cross(v[tri[1]] - v[tri[0]], v[tri[2]] - v[tri[0]]) * list(tri).count(i)
        norm = np.linalg.norm(acc)
        expect = acc / norm if norm > 0 else np.zeros(3)
        np.testing.assert_allclose(fast[i], expect, atol=1e-12)


def test_weld_gives_split_copies_one_normal_and_exclude_and_fallback():
    # a tetrahedron whose vertex 0 is split into two copies (as at a UV seam), plus an unused vertex
    v = np.vstack([TETRA_V, TETRA_V[:1], [[5.0, 5, 5]]])
    f = TETRA_F.copy()
    f[2] = [4, 3, 2]  # the third face uses the copy of vertex 0
    split = area_weighted_normals(v, f)
    welded = area_weighted_normals(v, f, weld=True, fallback=(0.0, 0.0, 1.0))
    assert np.degrees(np.arccos(np.clip(split[0] @ split[4], -1, 1))) > 30
    np.testing.assert_allclose(welded[0], welded[4], atol=1e-12)
    np.testing.assert_allclose(welded[0], -np.ones(3) / np.sqrt(3), atol=1e-12)
    assert (split[5] == 0).all() and (welded[5] == (0, 0, 1)).all()
    only = area_weighted_normals(TETRA_V, TETRA_F, exclude=np.array([True, True, True, False]))
    np.testing.assert_allclose(only[0], 0.0)  # vertex 0 lies only on excluded faces
    np.testing.assert_allclose(only[1], np.ones(3) / np.sqrt(3), atol=1e-12)
    assert np.isfinite(area_weighted_normals(np.zeros((3, 3)), np.array([[0, 1, 2]]))).all()


def test_edge_report_cases():
    closed = edge_report(TETRA_F)
    assert closed == {"edges": 6, "boundary_edges": 0, "non_manifold_edges": 0, "inconsistent_edges": 0,
                      "watertight": True}
    open_ = edge_report(TETRA_F[:3])
    assert open_["boundary_edges"] == 3 and not open_["watertight"]
    flipped = TETRA_F.copy()
    flipped[0] = flipped[0][::-1]
    rep = edge_report(flipped)
    assert rep["inconsistent_edges"] == 3 and not rep["watertight"]
    with_degenerate = edge_report(np.vstack([TETRA_F, [[0, 0, 1]]]))
    assert with_degenerate == closed  # a face with a repeated corner has no edges
    fan = edge_report(np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))
    assert fan["non_manifold_edges"] == 1
    assert edge_report(np.zeros((0, 3), np.int64))["watertight"] is False


def test_edge_report_agrees_with_counting_edges_one_by_one():
    from collections import Counter

    rng = np.random.default_rng(0)
    faces = rng.integers(0, 40, size=(300, 3))  # repeated, flipped, non-manifold and degenerate faces
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    count: Counter = Counter()
    forward: Counter = Counter()
    for f in faces.tolist():
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            count[(min(a, b), max(a, b))] += 1
            forward[(min(a, b), max(a, b))] += a < b
    rep = edge_report(faces)
    assert rep["edges"] == len(count)
    assert rep["boundary_edges"] == sum(c == 1 for c in count.values())
    assert rep["non_manifold_edges"] == sum(c > 2 for c in count.values())
    assert rep["inconsistent_edges"] == sum(c == 2 and forward[k] != 1 for k, c in count.items())


def test_scene_is_built_once_per_triangle_set_and_answers_correctly():
    import open3d as o3d

    s = trimesh.creation.icosphere(subdivisions=3)
    a = raycasting_scene(s.vertices, s.faces)
    b = raycasting_scene(s.vertices.copy(), s.faces.astype(np.int32))  # same content, other arrays
    assert a is b
    moved = raycasting_scene(s.vertices * 2.0, s.faces)
    assert moved is not a
    d = moved.compute_distance(o3d.core.Tensor(np.zeros((1, 3), np.float32))).numpy()
    assert d[0] == pytest.approx(2.0, abs=0.02)


def test_scene_queries_run_on_torchs_threads_unless_told():
    """Every query of a cached scene takes the run's thread count (torch's), not open3d's every core; a caller's
    nthreads wins; the rest of the scene is open3d's own, and answers as it does unwrapped."""
    import open3d as o3d
    import torch

    class Recording:
        def __init__(self):
            self.asked = []

        def cast_rays(self, rays, nthreads=0):
            self.asked.append(nthreads)
            return rays

        def compute_signed_distance(self, points, nthreads=0, nsamples=1):
            self.asked.append(nthreads)
            return nsamples

    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert geometry.query_threads() == 1
        rec = Recording()
        scene = geometry.RaycastScene(rec)
        assert scene.cast_rays("r") == "r" and scene.cast_rays("r", nthreads=2) == "r"
        assert scene.compute_signed_distance("r", nsamples=3) == 3  # the query's other arguments pass through
        assert rec.asked == [1, 2, 1]
    finally:
        torch.set_num_threads(before)
    s = trimesh.creation.icosphere(subdivisions=2)
    wrapped = raycasting_scene(s.vertices, s.faces)
    assert isinstance(wrapped, geometry.RaycastScene) and isinstance(wrapped.scene, o3d.t.geometry.RaycastingScene)
    bare = o3d.t.geometry.RaycastingScene()
    bare.add_triangles(o3d.core.Tensor(s.vertices.astype(np.float32)), o3d.core.Tensor(s.faces.astype(np.uint32)))
    rays = o3d.core.Tensor(np.array([[0, 0, 0, 1, 0, 0], [3, 0, 0, -1, 0, 0]], np.float32))
    np.testing.assert_array_equal(wrapped.cast_rays(rays)["t_hit"].numpy(), bare.cast_rays(rays)["t_hit"].numpy())
    assert wrapped.INVALID_ID == bare.INVALID_ID


def test_scene_cache_is_bounded():
    geometry._SCENES.clear()
    s = trimesh.creation.icosphere(subdivisions=1)
    first = raycasting_scene(s.vertices, s.faces)
    for k in range(RAYCAST_SCENE_CACHE):
        raycasting_scene(s.vertices + k + 1.0, s.faces)
    assert len(geometry._SCENES) == RAYCAST_SCENE_CACHE
    assert raycasting_scene(s.vertices, s.faces) is not first  # evicted, built again


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_interpolate_corners_matches_a_per_point_sum(dtype):
    rng = np.random.default_rng(3)
    values = rng.normal(size=(50, 3, 4)).astype(dtype)
    face = rng.integers(0, 50, 1000)
    bary = rng.dirichlet(np.ones(3), 1000).astype(dtype)
    slow = np.array([sum(float(bary[m, k]) * values[face[m], k].astype(np.float64) for k in range(3))
                     for m in range(len(face))])
    fast = geometry.interpolate_corners(values, face, bary)
    assert fast.dtype == np.float64 and fast.shape == (1000, 4)
    np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=1e-12)
    # a corner's own weight gives its value back exactly
    corner = geometry.interpolate_corners(values, face, np.tile([0.0, 1.0, 0.0], (1000, 1)))
    np.testing.assert_array_equal(corner, values[face, 1].astype(np.float64))


def _rotated(theta_deg: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
    """Unit rows a and rows b at exactly ``theta_deg`` from them (float64 construction: the reference)."""
    a = rng.normal(size=(len(theta_deg), 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    u = np.cross(a, rng.normal(size=a.shape))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t = np.radians(theta_deg)[:, None]
    return a, np.cos(t) * a + np.sin(t) * u


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_angular_error_against_a_float64_reference(dtype):
    rng = np.random.default_rng(5)
    theta = np.concatenate([[1e-6, 1e-4, 0.01, 0.1], rng.uniform(0, 180, 200), [179.99, 179.9999]])
    a, b = _rotated(theta, rng)
    scale = rng.uniform(0.1, 10, size=(len(theta), 1))  # not unit: the angle is of the directions
    got = geometry.angular_error((a * scale).astype(dtype), b.astype(dtype))
    assert got.dtype == np.float64 and got.shape == theta.shape
    # float64 rows: the construction's own rounding; float32 rows: rounding each component to 2^-24 relative
    tol = 1e-9 if dtype == np.float64 else 2e-5
    np.testing.assert_allclose(got, theta, rtol=0, atol=tol)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_angular_error_exact_at_0_and_180_and_90_without_direction(dtype):
    rng = np.random.default_rng(6)
    a = rng.normal(size=(500, 3)).astype(dtype)
    assert (geometry.angular_error(a, a) == 0.0).all()
    assert (geometry.angular_error(a, -a) == 180.0).all()
    assert (geometry.angular_error(a, 4 * a) == 0.0).all()
    zero = np.zeros((2, 3), dtype=dtype)
    assert (geometry.angular_error(zero, a[:2]) == 90.0).all() and (geometry.angular_error(a[:2], zero) == 90.0).all()
    assert geometry.angular_error(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_angle_measure_is_exact_near_zero(dtype, rng):
    a = rng.normal(size=(200, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    assert geometry.angular_error(a.astype(dtype), a.astype(dtype)).max() < 1e-5  # arccos of the dot would read ~0.02°
    theta = rng.uniform(1e-4, 3.0, 200)
    axis = np.cross(a, rng.normal(size=(200, 3)))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    b = a * np.cos(theta)[:, None] + np.cross(axis, a) * np.sin(theta)[:, None]  # a turned by theta about axis
    tol = 1e-9 if dtype == np.float64 else 1e-3
    np.testing.assert_allclose(geometry.angular_error(a.astype(dtype), b.astype(dtype)), np.degrees(theta), atol=tol)


def test_prefetch_loads_open3d_once_in_the_background_and_scenes_still_answer():
    import sys
    import threading

    geometry.prefetch_raycasting()
    geometry.prefetch_raycasting()  # once per process
    threads = [t for t in threading.enumerate() if t.name == "prefetch-open3d"]
    assert len(geometry._PREFETCH) == 1 and len(threads) <= 1
    geometry._PREFETCH[0].join(timeout=120)
    assert "open3d" in sys.modules
    tri = trimesh.creation.icosphere(subdivisions=1)
    scene = raycasting_scene(np.asarray(tri.vertices), np.asarray(tri.faces))
    assert scene is raycasting_scene(np.asarray(tri.vertices), np.asarray(tri.faces))


def _fresh_python(code: str) -> str:
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip()


def test_open3d_imports_without_its_web_visualiser_which_loads_on_first_call():
    # a fresh process: open3d works and its plotly/dash visualiser is not imported until one of its functions runs;
    # then the real module takes the stand-in's place and the call answers with a real plotly figure
    out = _fresh_python(
        "import sys\n"
        "from neural_bake.geometry import import_open3d\n"
        "o3d = import_open3d()\n"
        "print('dash' in sys.modules, 'plotly' in sys.modules)\n"
        "m = o3d.geometry.TriangleMesh.create_box()\n"
        "fig = o3d.visualization.get_plotly_fig([m])\n"
        "print(type(fig).__module__.startswith('plotly'), 'dash' in sys.modules,\n"
        "      hasattr(sys.modules['open3d.visualization.draw_plotly'], '__file__'))\n")
    assert out.splitlines() == ["False False", "True True True"]


def test_open3d_imported_earlier_is_left_as_it_is():
    out = _fresh_python(
        "import sys\n"
        "import open3d\n"
        "from neural_bake.geometry import import_open3d\n"
        "print(import_open3d() is open3d, 'dash' in sys.modules,\n"
        "      hasattr(sys.modules['open3d.visualization.draw_plotly'], '__file__'))\n")
    assert out == "True True True"


@pytest.mark.parametrize("source,ok", [
    ("from .draw_plotly import get_plotly_fig\nfrom .draw_plotly import draw_plotly\n", True),
    ("from .draw_plotly import get_plotly_fig, draw_plotly_server\n", True),
    ("from .draw_plotly import get_plotly_fig\nfrom .draw_plotly import PlotlyWidget\n", False),  # a name it does not know
    ("from . import draw_plotly\n", False),  # the module itself
    ("from .draw_plotly import *\n", False),
    ("from .other import thing\n", False),  # nothing of it: nothing to defer
])
def test_web_visualiser_is_deferred_only_for_the_imports_the_stand_in_knows(source, ok):
    assert geometry.web_visualiser_deferrable(source) is ok


def test_installed_open3d_is_one_the_stand_in_knows():
    # the installed open3d's package source passes the check, so bakes here do defer it
    import importlib.util
    from pathlib import Path

    spec = importlib.util.find_spec("open3d")
    init = Path(list(spec.submodule_search_locations)[0]) / "visualization" / "__init__.py"
    assert geometry.web_visualiser_deferrable(init.read_text(encoding="utf-8"))


def test_welded_edges_join_a_mesh_split_along_its_seams():
    box = trimesh.creation.box()
    whole = Mesh(np.asarray(box.vertices, float), np.asarray(box.faces, np.int64))
    split = Mesh(whole.triangles.reshape(-1, 3), np.arange(3 * whole.n_faces).reshape(-1, 3))  # every face its own
    for mesh in (whole, split):
        edge, count = welded_edges(mesh)
        assert edge.shape == (36,) and len(count) == 18 and (count == 2).all()
        assert np.bincount(edge).tolist() == count.tolist()
    # side k of face f is row k·F + f: face 0's three sides are three different edges
    assert len({int(welded_edges(whole)[0][k * 12]) for k in range(3)}) == 3
