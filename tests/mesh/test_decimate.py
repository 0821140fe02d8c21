"""Decimation: face targets, preserved boundaries, UVs kept, welded seams, errors and warnings."""

import numpy as np
import pytest
import trimesh

from neural_bake.errors import MeshError, NeuralBakeError, NeuralBakeWarning
from neural_bake.mesh.decimate import decimate, merge_duplicate_vertices
from neural_bake.mesh.tangents import vertex_uv
from neural_bake.types import Frame, Mesh


def bumpy_grid(n=24):
    xs = np.linspace(-1, 1, n + 1)
    x, y = np.meshgrid(xs, xs)
    x, y = x.ravel(), y.ravel()
    v = np.stack([x, y, 0.15 * np.sin(2 * x) * np.cos(3 * y)], axis=1)
    faces = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            faces += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    f = np.array(faces, dtype=np.int64)
    uv = np.stack([(x + 1) / 2, (y + 1) / 2], 1)[f]
    return Mesh(vertices=v, faces=f, uv=uv, frame=Frame((0.0, 1.0, 0.0), 2.0))


def boundary_vertices(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    return np.unique(u[c == 1])


def test_open_mesh_keeps_its_boundary_and_hits_the_target():
    m = bumpy_grid()
    d = decimate(m, faces=300)
    assert abs(d.n_faces - 300) <= 4
    assert d.frame == m.frame
    b = boundary_vertices(d.faces)
    on_border = np.isclose(np.abs(d.vertices[b, :2]), 1.0).any(axis=1)
    assert on_border.all()  # boundary vertices stay on the square's border
    # the four corners survive and the border is still the whole square (perimeter 8 in x-y)
    for c in ([-1, -1], [1, -1], [1, 1], [-1, 1]):
        assert (np.abs(d.vertices[b, :2] - c).max(axis=1) < 1e-12).any()
    # the border stays closed and straight: its edges projected on x-y add up to the perimeter
    e = np.sort(np.concatenate([d.faces[:, [0, 1]], d.faces[:, [1, 2]], d.faces[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    be = u[c == 1]
    assert np.linalg.norm(d.vertices[be[:, 0], :2] - d.vertices[be[:, 1], :2], axis=1).sum() == pytest.approx(8.0)
    assert d.uv is None
    n = d.vertex_normals
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    assert (n[:, 2] > 0.5).all()


def test_closed_sphere_ratio_keeps_shape_and_winding():
    s = trimesh.creation.icosphere(3)
    m = Mesh(vertices=s.vertices * 0.8, faces=s.faces.astype(np.int64))
    d = decimate(m, ratio=0.25)
    assert abs(d.n_faces - m.n_faces // 4) <= 4
    t = trimesh.Trimesh(d.vertices, d.faces, process=False)
    assert t.is_watertight and t.volume > 0  # closed and outward
    r = np.linalg.norm(d.vertices, axis=1)
    assert np.abs(r - 0.8).max() < 0.02
    assert not d.degenerate.any()


def test_keep_uv_preserves_a_linear_parametrisation():
    m = bumpy_grid()
    d = decimate(m, faces=200, keep_uv=True)
    assert abs(d.n_faces - 200) <= 4
    uvv = vertex_uv(d)  # split at seams: one UV per vertex
    # the texture-aware quadric keeps UVs close to the linear map (not exactly: positions move off-grid)
    np.testing.assert_allclose(uvv, (d.vertices[:, :2] + 1) / 2, atol=1.5e-2)
    d1, d2 = d.uv[:, 1] - d.uv[:, 0], d.uv[:, 2] - d.uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    assert (det > 0).all()  # no folded UV triangle
    assert 0.5 * det.sum() == pytest.approx(1.0, abs=1e-9)  # the layout still tiles the unit square


def test_split_seams_are_welded_before_decimation():
    s = trimesh.creation.icosphere(2)
    f = s.faces.astype(np.int64)
    # split every vertex used by the first 40 faces: duplicate positions as a UV-seam loader makes
    v = np.concatenate([s.vertices, s.vertices])
    f = f.copy()
    f[:40] += len(s.vertices)
    m = Mesh(vertices=v, faces=f)
    welded, remap = merge_duplicate_vertices(m)
    assert welded.n_vertices == len(s.vertices)
    np.testing.assert_array_equal(welded.vertices[remap], v)
    d = decimate(m, faces=100)
    assert trimesh.Trimesh(d.vertices, d.faces, process=False).is_watertight


def test_errors_and_warnings():
    m = bumpy_grid(4)
    with pytest.raises(NeuralBakeError, match="exactly one of faces= or ratio="):
        decimate(m)
    with pytest.raises(NeuralBakeError, match="exactly one of faces= or ratio="):
        decimate(m, faces=10, ratio=0.5)
    with pytest.raises(NeuralBakeError, match="faces must be an integer >= 4"):
        decimate(m, faces=2)
    with pytest.raises(NeuralBakeError, match="ratio must be in \\(0, 1\\]"):
        decimate(m, ratio=0.0)
    with pytest.raises(NeuralBakeError, match="ratio must be in \\(0, 1\\]"):
        decimate(m, ratio=float("nan"))
    with pytest.warns(NeuralBakeWarning, match="not decimated"):
        d = decimate(m, faces=1000)
    assert d.n_faces == m.n_faces
    m2 = bumpy_grid(4)
    m2.uv = None
    with pytest.warns(NeuralBakeWarning, match="keep_uv asked but the mesh has no UVs"):
        decimate(m2, faces=10, keep_uv=True)
    empty = Mesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), np.int64))
    with pytest.raises(MeshError, match="no faces to decimate"):
        decimate(empty, faces=10)


def test_watertight_flag_is_recomputed():
    m = bumpy_grid(8)
    m.watertight = True  # wrong on purpose: an open grid
    assert not decimate(m, faces=40).watertight
    s = trimesh.creation.icosphere(2)
    closed = Mesh(vertices=s.vertices, faces=s.faces.astype(np.int64), watertight=False)
    assert decimate(closed, faces=100).watertight


def test_first_pass_rule():
    from neural_bake.mesh.decimate import FIRST_PASS_MIN, first_pass_faces

    assert first_pass_faces(20_088, 2000) is None  # not twice the first pass: pymeshlab alone
    assert first_pass_faces(124_008, 2000) == FIRST_PASS_MIN
    assert first_pass_faces(124_008, 5000) == 40_000
    assert first_pass_faces(79_999, 5000) is None


def test_large_open_mesh_through_the_first_pass_keeps_its_border():
    m = bumpy_grid(130)  # 33,800 faces: a first pass to 16,000 before pymeshlab
    assert m.n_faces >= 32_000
    d = decimate(m, faces=2000)  # (its 520 border edges are kept: fewer faces cannot be reached)
    plain = decimate(m, faces=2000, first_pass=False)
    assert not np.array_equal(d.vertices, plain.vertices)  # the first pass ran
    assert abs(d.n_faces - 2000) <= 4
    b = boundary_vertices(d.faces)
    assert np.isclose(np.abs(d.vertices[b, :2]), 1.0).any(axis=1).all()
    for c in ([-1, -1], [1, -1], [1, 1], [-1, 1]):
        assert (np.abs(d.vertices[b, :2] - c).max(axis=1) < 1e-12).any()
    # as close to the surface z = 0.15 sin 2x cos 3y as pymeshlab alone
    def off(mesh):
        x, y, z = mesh.vertices.T
        return np.abs(z - 0.15 * np.sin(2 * x) * np.cos(3 * y)).mean()

    assert off(d) <= 1.5 * off(plain) + 1e-4


@pytest.mark.parametrize("first_pass", [True, False])
def test_large_closed_sphere_stays_closed_round_and_outward(first_pass):
    s = trimesh.creation.icosphere(6)  # 81,920 faces
    m = Mesh(vertices=s.vertices * 0.8, faces=s.faces.astype(np.int64))
    d = decimate(m, faces=2000, first_pass=first_pass)
    assert abs(d.n_faces - 2000) <= 4
    t = trimesh.Trimesh(d.vertices, d.faces, process=False)
    assert t.is_watertight and t.volume > 0
    assert np.abs(np.linalg.norm(d.vertices, axis=1) - 0.8).max() < 0.01
    assert not d.degenerate.any()
