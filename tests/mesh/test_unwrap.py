"""xatlas unwrap: UVs in [0, 1], consistent vertex splitting, no overlapping charts; seam splitting."""

import numpy as np
import pytest
import trimesh

from neural_bake.errors import MeshError, NeuralBakeError
from neural_bake.mesh.texels import rasterize_texels
from neural_bake.mesh.unwrap import UnwrapConfig, split_uv_seams, unwrap, unwrap_with_mapping, vertex_uv
from neural_bake.types import Frame, Mesh


@pytest.fixture(scope="module")
def sphere():
    s = trimesh.creation.icosphere(2)
    return Mesh(vertices=s.vertices * 0.9, faces=s.faces.astype(np.int64), frame=Frame((1.0, 2.0, 3.0), 0.5))


@pytest.fixture(scope="module")
def unwrapped(sphere):
    return unwrap_with_mapping(sphere, resolution=128, padding=2)


def test_unwrap_splits_vertices_consistently(sphere, unwrapped):
    m, vmap = unwrapped
    assert vmap.dtype == np.int64 and vmap.shape == (m.n_vertices,)
    assert m.n_vertices > sphere.n_vertices  # seams were split
    np.testing.assert_array_equal(m.vertices, sphere.vertices[vmap])
    np.testing.assert_array_equal(vmap[m.faces], sphere.faces)  # same faces, same order and winding
    assert m.frame == sphere.frame
    assert m.uv.shape == (sphere.n_faces, 3, 2)
    assert (m.uv >= 0).all() and (m.uv <= 1).all()
    uvv = vertex_uv(m)  # one UV per vertex: does not raise
    np.testing.assert_array_equal(uvv[m.faces], m.uv)
    # split copies keep their source vertex's normal
    n = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    assert np.abs(m.vertex_normals - n[vmap]).max() < 0.05


def test_unwrap_charts_do_not_overlap(unwrapped):
    m, _ = unwrapped
    ts = rasterize_texels(m, 128, conservative=False)
    assert ts.overlaps == 0
    # every texel centre is claimed by at most one face: recount with a face-wise brute force on a subset
    assert len(np.unique(ts.texel)) == ts.n_samples
    # no UV triangle is folded over: within a chart (faces connected through split vertices) all UV
    # triangles have one orientation (xatlas may mirror a whole chart: its tangents get w = -1)
    d1, d2 = m.uv[:, 1] - m.uv[:, 0], m.uv[:, 2] - m.uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    assert (det != 0).all()
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = np.repeat(np.arange(m.n_faces), 3)
    inc = coo_matrix((np.ones(rows.size), (rows, m.faces.ravel())), shape=(m.n_faces, m.n_vertices)).tocsr()
    n_charts, chart = connected_components(inc @ inc.T, directed=False)
    assert n_charts > 1
    for c in range(n_charts):
        sg = np.sign(det[chart == c])
        assert (sg == sg[0]).all()
    assert 0.3 < ts.coverage.mean() < 0.95


def test_unwrap_attribute_mapping_and_options(sphere):
    m = unwrap(sphere, UnwrapConfig(resolution=64, padding=1))
    assert m.source_vertex.shape == (m.n_vertices,)
    small = unwrap(sphere, resolution=64, max_chart_area=0.05)
    # smaller charts: more seams, more split vertices
    assert small.n_vertices > m.n_vertices


def test_unwrap_errors(sphere):
    with pytest.raises(NeuralBakeError, match="unknown option 'charts'"):
        unwrap(sphere, charts=3)
    with pytest.raises(NeuralBakeError, match="resolution must be at least 8"):
        unwrap(sphere, resolution=2)
    with pytest.raises(NeuralBakeError, match="padding must be >= 0"):
        unwrap(sphere, padding=-1)
    empty = Mesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), np.int64))
    with pytest.raises(MeshError, match="no faces to unwrap"):
        unwrap(empty)


def test_split_uv_seams():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    uv = np.array([[[0, 0], [0.5, 0], [0.5, 0.5]], [[0.6, 0.6], [1, 1], [0.6, 1]]])
    m = Mesh(vertices=v, faces=f, uv=uv)
    with pytest.raises(MeshError, match="different UVs"):
        vertex_uv(m)
    s, vmap = split_uv_seams(m)
    assert s.n_vertices == 6
    np.testing.assert_array_equal(vmap[s.faces], f)
    np.testing.assert_array_equal(vertex_uv(s)[s.faces], uv)
    # already split: identity (same count), and vertex_uv agrees
    s2, vmap2 = split_uv_seams(s)
    assert s2.n_vertices == s.n_vertices
    np.testing.assert_array_equal(s.vertices[vmap2][s2.faces], s.vertices[s.faces])
    m.uv = None
    with pytest.raises(MeshError, match="no UVs to split"):
        split_uv_seams(m)


def test_split_by_handedness_at_a_mirror_line():
    # two faces share an edge with equal UVs but mirrored layouts
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [1, 0]]], dtype=np.float64)
    m = Mesh(vertices=v, faces=f, uv=uv)
    assert split_uv_seams(m, by_handedness=False)[0].n_vertices == 4
    assert split_uv_seams(m)[0].n_vertices == 6


def test_unwrap_non_manifold_mesh():
    # three triangles on one edge: xatlas still gives a valid layout with the same faces
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], dtype=np.float64)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]], dtype=np.int64)
    m, vmap = unwrap_with_mapping(Mesh(vertices=v, faces=f), resolution=32, padding=1)
    np.testing.assert_array_equal(vmap[m.faces], f)
    assert (m.uv >= 0).all() and (m.uv <= 1).all()
    assert rasterize_texels(m, 32, conservative=False).overlaps == 0


def _chart_gap(m, size: int) -> int:
    """The smallest Chebyshev distance in texels of a ``size``² map between texels of two different charts."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = np.repeat(np.arange(m.n_faces), 3)
    inc = coo_matrix((np.ones(rows.size), (rows, m.faces.ravel())), shape=(m.n_faces, m.n_vertices)).tocsr()
    _, chart = connected_components(inc @ inc.T, directed=False)
    ts = rasterize_texels(m, size, conservative=False)
    ids = np.zeros((size + 32, size + 32), dtype=np.int64)  # a margin, so shifted views stay in range
    ids[ts.pixel[:, 0] + 16, ts.pixel[:, 1] + 16] = chart[ts.face] + 1
    for r in range(1, 16):
        for dr in range(-r, r + 1):
            for dc in range(-r, r + 1):
                if max(abs(dr), abs(dc)) != r:
                    continue
                a = ids[16:-16, 16:-16]
                b = ids[16 + dr: 16 + dr + size, 16 + dc: 16 + dc + size]
                if ((a > 0) & (b > 0) & (a != b)).any():
                    return r
    return 16


def test_a_large_map_is_packed_on_the_pack_grid_keeping_its_gaps(sphere, monkeypatch):
    """Above UNWRAP_PACK_SIDE the charts are packed on that grid with the padding scaled up to whole grid texels:
    the same charts, and gaps between them of about the padding in texels of the map."""
    import neural_bake.mesh.unwrap as unwrap_mod

    _, po = unwrap_mod._options(UnwrapConfig(resolution=4096, padding=4))
    assert (po.resolution, po.padding) == (1024, 1)
    _, po = unwrap_mod._options(UnwrapConfig(resolution=1024, padding=4))
    assert (po.resolution, po.padding) == (1024, 4)
    _, po = unwrap_mod._options(UnwrapConfig(resolution=3000, padding=5))
    assert (po.resolution, po.padding) == (1024, 2)  # 5 · 1024 / 3000 = 1.7, rounded up
    native = _chart_gap(unwrap(sphere, resolution=256, padding=4), 256)
    monkeypatch.setattr(unwrap_mod, "UNWRAP_PACK_SIDE", 64)
    packed = unwrap(sphere, resolution=256, padding=4)
    assert (packed.uv >= 0).all() and (packed.uv <= 1).all()
    ts = rasterize_texels(packed, 256, conservative=False)
    assert ts.overlaps == 0 and 0.3 < ts.coverage.mean() < 0.95
    # 1 grid texel = 4 map texels: the gaps are those of a packing at 256 (xatlas' rescaling to the square aside);
    # unscaled (padding 4 on the 64 grid) they would be 16, without padding 4
    assert native - 1 <= _chart_gap(packed, 256) < 16
