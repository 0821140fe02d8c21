"""Clean-up: welding, degenerate/duplicate faces, small components, edge report."""

import numpy as np
import pytest
import trimesh

from neural_bake.errors import NeuralBakeError
from neural_bake.mesh.cleanup import clean_mesh, edge_report
from neural_bake.types import Frame, Mesh


def sphere(sub=2, r=0.8, offset=(0, 0, 0)):
    s = trimesh.creation.icosphere(sub)
    return s.vertices * r + np.asarray(offset), s.faces.astype(np.int64)


def test_welds_split_vertices_and_removes_small_component():
    v, f = sphere()
    tv, tf = sphere(0, 0.05, (0.9, 0, 0))  # a 20-face blob
    nv = len(v)
    # split the first 30 faces' vertices (seam duplicates) and add the blob
    f2 = f.copy()
    f2[:30] += nv
    verts = np.concatenate([v, v, tv])
    faces = np.concatenate([f2, tf + 2 * nv])
    m = Mesh(vertices=verts, faces=faces, frame=Frame((0.0, 0.0, 1.0), 3.0))
    assert clean_mesh(m)[1]["components_removed"] == 0  # default: below 1% of the largest (320 faces)
    out, rep = clean_mesh(m, min_component_faces=50)
    assert rep["components"] == 2 and rep["components_removed"] == 1
    assert rep["small_component_faces_removed"] == 20
    assert out.n_faces == len(f) and out.n_vertices == nv
    assert out.watertight and rep["watertight"] and rep["non_manifold_edges"] == 0
    assert out.frame == m.frame
    # same surface: each output face equals the input face's positions (order and winding kept)
    np.testing.assert_array_equal(out.triangles, verts[faces[: len(f)]])
    assert rep["vertices_in"] == len(verts) and rep["faces_out"] == len(f)


def test_degenerate_duplicate_faces_and_unreferenced_vertices():
    v, f = sphere(1)
    extra_v = np.array([[5.0, 5, 5]])
    faces = np.concatenate([f, [[0, 0, 1]], f[:3][:, [1, 2, 0]]])  # a repeated-index face, 3 duplicates
    m = Mesh(vertices=np.concatenate([v, extra_v]), faces=faces, uv=np.zeros((len(faces), 3, 2)))
    out, rep = clean_mesh(m, min_component_faces=0)
    assert rep["degenerate_faces_removed"] == 1
    assert rep["duplicate_faces_removed"] == 3
    assert rep["unreferenced_vertices_removed"] == 1
    assert out.n_faces == len(f) and out.uv.shape == (len(f), 3, 2)
    assert out.watertight


def test_non_manifold_and_boundary_edges_are_reported_not_repaired():
    # three triangles on one edge (0, 1): non-manifold; all edges else boundary
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], dtype=np.float64)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]], dtype=np.int64)
    out, rep = clean_mesh(Mesh(vertices=v, faces=f))
    assert rep["non_manifold_edges"] == 1
    assert rep["boundary_edges"] == 6
    assert out.n_faces == 3 and not out.watertight


def test_edge_report_inconsistent_winding():
    v, f = sphere(1)
    f = f.copy()
    f[0] = f[0, ::-1]
    rep = edge_report(f)
    assert rep["inconsistent_edges"] == 3 and not rep["watertight"]
    assert edge_report(np.zeros((0, 3), np.int64))["edges"] == 0


def test_keep_largest_and_merge_tolerance():
    v, f = sphere(1)
    v2, f2 = sphere(1, 0.3, (0, 0, 0))
    m = Mesh(vertices=np.concatenate([v, v2]), faces=np.concatenate([f, f2 + len(v)]))
    out, rep = clean_mesh(m, keep_largest=True)
    assert rep["components_removed"] == 1 and out.n_faces == len(f)  # equal sizes: the first is kept
    # near-duplicates (1e-9 apart) are welded only with a tolerance
    vv = np.concatenate([v, v + 1e-9])
    ff = f.copy()
    ff[:10] += len(v)
    m2 = Mesh(vertices=vv, faces=ff)
    assert clean_mesh(m2)[1]["vertices_merged"] == 0
    out2, rep2 = clean_mesh(m2, merge_tolerance=1e-6)
    assert rep2["vertices_merged"] == len(v) and out2.watertight


def test_errors():
    v, f = sphere(0)
    m = Mesh(vertices=v, faces=f)
    with pytest.raises(NeuralBakeError, match="min_component_faces must be a non-negative integer"):
        clean_mesh(m, min_component_faces=-1)
    with pytest.raises(NeuralBakeError, match="min_component_fraction must be in \\[0, 1\\]"):
        clean_mesh(m, min_component_fraction=2.0)
    with pytest.raises(NeuralBakeError, match="merge_tolerance must be >= 0"):
        clean_mesh(m, merge_tolerance=-1.0)


def test_zero_area_sliver_is_kept_flagged_unless_asked():
    """A collinear sliver inside a closed surface: deleting it would open a 3-edge hole."""
    # a closed square pyramid whose base is a fan around vertex 5, placed on the base edge 1-2: the fan's
    # face [1, 5, 2] is a zero-area sliver sharing its three edges with neighbours
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1], [1.0, 0.5, 0]], dtype=np.float64)
    f = np.array([[0, 5, 1], [1, 5, 2], [2, 5, 3], [3, 5, 0],
                  [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]], dtype=np.int64)
    m = Mesh(vertices=v, faces=f)
    assert m.face_areas[1] < 1e-12
    out, rep = clean_mesh(m)
    assert rep["degenerate_faces_removed"] == 0 and out.n_faces == 8
    assert out.watertight and out.degenerate.sum() == 1
    out2, rep2 = clean_mesh(m, remove_zero_area=True)
    assert rep2["degenerate_faces_removed"] == 1 and not out2.watertight and rep2["boundary_edges"] == 3
