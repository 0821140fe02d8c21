"""Detail sampling of SDF fitting: curvature-aware surface sampling and error-driven resampling."""

from dataclasses import replace

import numpy as np
import pytest
import torch
import trimesh

from neural_bake.errors import FitError
from neural_bake.fit.sampling import curvature_face_weights, hard_edge_sides, sample_near, sample_surface
from neural_bake.fit.sdf import SdfFitConfig, fit_sdf
from neural_bake.fit.sdf_pools import _draw, _error_cdf, _importance_draw
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.types import Mesh

TINY = dict(width=32, depth=1, omega_0=15.0, lr=1e-3, batch=512, batch_near=512, batch_uniform=128, pool_surface=4000,
            pool_near=4000, pool_uniform=1000, progress=False, log_every=20)


def _mesh(tm: trimesh.Trimesh) -> Mesh:
    return Mesh(np.asarray(tm.vertices, dtype=np.float64), np.asarray(tm.faces, dtype=np.int64))


def _box(size=0.8, max_edge=0.1) -> Mesh:
    """A cube subdivided into small triangles: its curvature lies on its 12 edges only."""
    box = trimesh.creation.box(extents=(size, size, size))
    v, f = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=max_edge)
    return _mesh(trimesh.Trimesh(v, f, process=False))


def _crease_faces(mesh: Mesh, half: float) -> np.ndarray:
    """Faces with a vertex on one of the cube's edges (two coordinates at ±half)."""
    on_edge = (np.isclose(np.abs(mesh.vertices), half).sum(axis=1) >= 2)
    return on_edge[mesh.faces].any(axis=1)


@pytest.mark.parametrize("u", [0.0, 0.3, 0.7])
def test_curvature_weights_put_the_curved_share_on_a_cubes_creases(u):
    mesh = _box()
    crease = _crease_faces(mesh, 0.4)
    area_share = mesh.face_areas[crease].sum() / mesh.face_areas.sum()
    assert 0.05 < area_share < 0.4
    w = curvature_face_weights(mesh, uniform_share=u)
    assert w.sum() == pytest.approx(1.0) and (w >= 0).all()
    # all curvature lies on the crease faces: they get the curved share plus their part of the uniform one
    expected = u * area_share + (1.0 - u)
    assert w[crease].sum() == pytest.approx(expected, abs=1e-9)
    s = sample_surface(mesh, 40_000, seed=3, face_weights=w)
    share = crease[s.face_index].mean()
    assert share == pytest.approx(expected, abs=4 * np.sqrt(expected * (1 - expected) / 40_000) + 1e-9)
    if u <= 0.3:  # the stated factor: at least twice the area share on the creases
        assert share > 2.0 * area_share


def test_sphere_curvature_sampling_is_uniform_by_area():
    mesh = _mesh(trimesh.creation.icosphere(subdivisions=4, radius=0.9))
    area_p = mesh.face_areas / mesh.face_areas.sum()
    w = curvature_face_weights(mesh, uniform_share=0.0)
    ratio = w / area_p
    assert ratio.min() > 0.75 and ratio.max() < 1.3  # constant curvature: density within the mesh's irregularity
    n = 200_000
    s = sample_surface(mesh, n, seed=1, face_weights=w)
    # the share of points in each octant is the octant's area share (1/8) within a statistical tolerance
    octant = (s.points > 0) @ np.array([1, 2, 4])
    counts = np.bincount(octant, minlength=8) / n
    assert np.abs(counts - 0.125).max() < 4 * np.sqrt(0.125 * 0.875 / n) + 0.005


def test_plane_and_uniform_share_one_give_area_weights():
    mesh = _mesh(trimesh.creation.box(extents=(1.0, 1.0, 0.5)).subdivide())
    area_p = mesh.face_areas / mesh.face_areas.sum()
    np.testing.assert_allclose(curvature_face_weights(mesh, 1.0), area_p)
    plane = Mesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    np.testing.assert_allclose(curvature_face_weights(plane, 0.0), [0.5, 0.5])


def test_uv_seam_split_vertices_are_welded():
    mesh = _box()
    # split every vertex per face (as a UV layout of separate islands would): the creases must stay creases
    split = Mesh(mesh.vertices[mesh.faces.reshape(-1)], np.arange(3 * mesh.n_faces).reshape(-1, 3))
    np.testing.assert_allclose(curvature_face_weights(split, 0.2), curvature_face_weights(mesh, 0.2), atol=1e-12)


def test_degenerate_and_zero_area_faces_get_no_weight_and_stay_finite():
    box = _box(max_edge=0.2)
    v = np.concatenate([box.vertices, [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0]]])
    k = box.n_vertices
    extra = np.array([[0, 0, 1], [k, k + 1, k + 2], [k, k, k]])  # a repeated vertex, a collinear face, a point
    mesh = Mesh(v, np.concatenate([box.faces, extra]))
    w = curvature_face_weights(mesh, 0.3)
    assert np.isfinite(w).all() and w.sum() == pytest.approx(1.0) and (w[-3:] == 0).all()
    s = sample_surface(mesh, 5000, seed=0, face_weights=w)
    assert (s.face_index < box.n_faces).all() and np.isfinite(s.points).all() and np.isfinite(s.normals).all()
    near = sample_near(mesh, 2000, sigma=0.01, seed=0, face_weights=w)
    assert np.isfinite(near.points).all() and np.isfinite(near.sdf).all()


def test_curvature_sampling_is_seeded():
    mesh = _box()
    w = curvature_face_weights(mesh, 0.5)
    a, b = (sample_surface(mesh, 3000, seed=7, face_weights=w) for _ in range(2))
    np.testing.assert_array_equal(a.points, b.points)
    c = sample_surface(mesh, 3000, seed=8, face_weights=w)
    assert not np.array_equal(a.points, c.points)


@pytest.mark.parametrize("kw, msg", [
    ({"face_weights": np.ones(3)}, "face_weights must be"),
    ({"face_weights": "neg"}, "face_weights must be"),
    ({"face_weights": "nan"}, "face_weights must be"),
])
def test_bad_face_weights(kw, msg):
    mesh = _box(max_edge=0.4)
    if isinstance(kw["face_weights"], str):
        w = np.ones(mesh.n_faces)
        w[0] = -1.0 if kw["face_weights"] == "neg" else np.nan
        kw = {"face_weights": w}
    with pytest.raises(ValueError, match=msg):
        sample_surface(mesh, 10, **kw)


@pytest.mark.parametrize("u", [-0.1, 1.5, float("nan")])
def test_bad_uniform_share(u):
    with pytest.raises(ValueError, match="uniform_share must be in"):
        curvature_face_weights(_box(max_edge=0.4), u)


# ----------------------------------------------------------------------------------------------- error-driven


def _sphere_points(n=6000, r=0.7, seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    p = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=1)
    return (p * r).to(dtype), p.to(dtype)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_error_resampling_moves_samples_to_an_injected_error(fit_sphere_siren, dtype):
    net = fit_sphere_siren(r=0.7, steps=300).to(dtype)
    p, n = _sphere_points(dtype=dtype)
    wrong = p[:, 0] > 0.5  # inject an error: the normals of a cap (~14% of the sphere) are flipped
    n = torch.where(wrong[:, None], -n, n)
    cdf = _error_cdf(net, p, n)
    assert cdf.dtype == torch.float64 and torch.isfinite(cdf).all() and (cdf.diff() >= 0).all()
    idx = _importance_draw(cdf, 20_000, torch.Generator().manual_seed(0))
    share = wrong[idx].double().mean().item()
    assert wrong.double().mean().item() < 0.2 and share > 0.9  # the sampled share goes to the wrong cap
    again = _importance_draw(cdf, 20_000, torch.Generator().manual_seed(0))
    assert torch.equal(idx, again)


def test_error_cdf_float32_matches_float64(fit_sphere_siren):
    net = fit_sphere_siren(r=0.7, steps=300)
    p, n = _sphere_points(n=3000, r=0.6, seed=2, dtype=torch.float64)  # off the zero set: real errors
    c64 = _error_cdf(net.double(), p, n)
    c32 = _error_cdf(net.float(), p.float(), n.float())
    torch.testing.assert_close(c32, c64, rtol=2e-4, atol=1e-6)


def test_error_cdf_is_none_without_error_and_finite_where_the_gradient_vanishes():
    from neural_bake.nets.siren import Siren

    net = Siren(16, 1, omega_0=10.0, generator=torch.Generator().manual_seed(0))
    for w in net.parameters():  # a constant field: ∇f = 0 everywhere, so every point counts the error 1
        torch.nn.init.zeros_(w)
    p, n = _sphere_points(n=100)
    cdf = _error_cdf(net, p, n)
    torch.testing.assert_close(cdf, torch.arange(1, 101, dtype=torch.float64))
    assert _error_cdf(net, p[:0], n[:0]) is None  # an empty pool: nothing to importance-sample


def test_error_draw_takes_the_head_of_the_surface_batch():
    cfg = SdfFitConfig(batch=400, batch_near=100, batch_uniform=20, hard_fraction=0.25, error_sampling=0.5)
    pools = {"surf_p": torch.arange(3000.0).reshape(1000, 3), "surf_n": torch.zeros(1000, 3),
             "vol_p": torch.arange(1500.0).reshape(500, 3), "vol_d": torch.zeros(500), "n_near": 400}
    err = torch.zeros(1000, dtype=torch.float64)
    err[[3, 500]] = 1.0  # only two pool points have an error
    hard = {"surf": torch.tensor([7, 11]), "error": torch.cumsum(err, 0)}
    sp, *_ = _draw(pools, cfg, torch.Generator().manual_seed(0), hard)
    rows = (sp[:, 0] / 3).long()
    assert set(rows[:200].tolist()) == {3, 500}  # the head: error-driven draws
    assert len(set(rows[200:300].tolist())) > 50  # the floor: uniform over the pool
    assert set(rows[300:].tolist()) <= {7, 11}  # the tail: hard examples


def test_fit_with_detail_sampling_reproduces_and_stays_finite():
    m = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    v, f = trimesh.remesh.subdivide_to_size(m.vertices, m.faces, max_edge=0.15)
    mesh = mesh_from_arrays(v, f, normalise=False)
    kw = dict(TINY, steps=40, curvature_sampling=0.5, error_sampling=0.25, hard_every=10)
    a, b = fit_sdf(mesh, **kw), fit_sdf(mesh, **kw)
    wa = torch.cat([p.detach().flatten() for p in a.model.parameters()])
    wb = torch.cat([p.detach().flatten() for p in b.model.parameters()])
    assert torch.isfinite(wa).all() and torch.equal(wa, wb)
    assert a.sampling_seconds is not None and 0 < a.sampling_seconds < a.seconds
    c = fit_sdf(mesh, **dict(kw, curvature_sampling=0.0, error_sampling=0.0))
    assert not torch.equal(wa, torch.cat([p.detach().flatten() for p in c.model.parameters()]))


@pytest.mark.parametrize("kw, msg", [
    ({"curvature_sampling": -0.1}, "curvature_sampling must be in"),
    ({"curvature_sampling": 1.1}, "curvature_sampling must be in"),
    ({"error_sampling": 0.8, "hard_fraction": 0.25}, r"error_sampling must be in \[0, 1 - hard_fraction\]"),
    ({"error_sampling": -0.5}, "error_sampling must be in"),
    ({"texel_sampling": -0.1}, "texel_sampling must be in"),
    ({"texel_sampling": 1.5}, "texel_sampling must be in"),
    ({"edge_sampling": -0.1}, "edge_sampling must be in"),
    ({"edge_sampling": 1.5}, "edge_sampling must be in"),
    ({"edge_band": 0.0}, "edge_band must be positive"),
    ({"edge_band": float("nan")}, "edge_band must be positive"),
])
def test_bad_detail_sampling_settings(kw, msg):
    m = trimesh.creation.icosphere(subdivisions=1, radius=0.8)
    with pytest.raises(FitError, match=msg):
        fit_sdf(mesh_from_arrays(m.vertices, m.faces, normalise=False), **kw)


def test_curvature_pools_are_denser_on_creases():
    from neural_bake.fit.sdf_pools import _Pools

    mesh = _box()
    cfg = replace(SdfFitConfig(), pool_surface=20_000, pool_near=2000, pool_uniform=100)
    near_crease = {}
    for c in (0.0, 0.6):
        pools = _Pools(mesh, replace(cfg, curvature_sampling=c), torch.device("cpu"), torch.float32)
        p = pools.get(0)["surf_p"].numpy()
        # share of surface pool points within 0.05 of a crease (two coordinates near ±0.4)
        near_crease[c] = (np.isclose(np.abs(p), 0.4, atol=0.05).sum(axis=1) >= 2).mean()
    assert near_crease[0.6] > 2.0 * near_crease[0.0]


#: Where each side of :func:`_uv_box`'s cube lies in its layout (lower-left corner), by (axis, +/−): +x at
#: three times the others' scale, so with nine times their texels, and no two sides overlapping.
_SIDES = {(0, 1): (0.02, 0.02), (0, 0): (0.66, 0.02), (1, 1): (0.66, 0.24), (1, 0): (0.66, 0.46),
          (2, 1): (0.02, 0.70), (2, 0): (0.26, 0.70)}


def _uv_box(mirror: bool = False) -> Mesh:
    """The subdivided cube with a UV layout in [0, 1]² that gives its faces on the +x side 9 times their
    area's texels (each side flattened along its own normal, 0.2 across, +x 0.6). ``mirror``: the −x side
    takes the +x side's place in the layout (as a mirrored part shares its texels)."""
    mesh = _box()
    c = mesh.vertices[mesh.faces]  # (F, 3, 3)
    axis = np.abs(mesh.face_normals).argmax(axis=1)
    plus = np.take_along_axis(mesh.face_normals, axis[:, None], axis=1)[:, 0] > 0
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    local = (np.take_along_axis(c, np.repeat(keep[:, None, :], 3, axis=1), axis=2) + 0.4) / 0.8  # [0, 1]²
    side = [(int(a), int(p)) for a, p in zip(axis, plus)]
    if mirror:
        side = [(0, 1) if s == (0, 0) else s for s in side]
    scale = np.array([0.6 if s == (0, 1) else 0.2 for s in side])
    corner = np.array([_SIDES[s] for s in side])
    return replace(mesh, uv=local * scale[:, None, None] + corner[:, None, :])


def _uv_areas(mesh: Mesh) -> np.ndarray:
    d1, d2 = mesh.uv[:, 1] - mesh.uv[:, 0], mesh.uv[:, 2] - mesh.uv[:, 0]
    return 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def test_texel_weights_follow_the_uv_area_and_mix_with_curvature():
    from neural_bake.fit.sdf_pools import _face_weights
    from neural_bake.fit.texture import texel_face_weights

    mesh = _uv_box()
    uv_area = _uv_areas(mesh)
    assert np.array_equal(_face_weights(mesh, 0.0, 1.0), uv_area / uv_area.sum())  # a clean layout: UV area
    assert np.allclose(_face_weights(mesh, 0.0, 0.4), texel_face_weights(mesh, 0.4))
    both = _face_weights(mesh, 0.5, 0.4)
    assert np.allclose(both, 0.6 * curvature_face_weights(mesh, 0.5) + 0.4 * uv_area / uv_area.sum())
    assert both.sum() == pytest.approx(1.0)
    # without UVs the texel share has nothing to follow: curvature's weights, or the area's (None)
    bare = replace(mesh, uv=None)
    assert _face_weights(bare, 0.0, 0.5) is None
    assert np.allclose(_face_weights(bare, 0.3, 0.5), curvature_face_weights(bare, 0.7))


def test_map_texel_weights_count_a_shared_or_repeated_texel_once():
    from neural_bake.fit.sampling import map_texel_weights

    # the mirrored side shares +x's texels: the bake writes them from one face each, so the two sides hold
    # +x's 9 parts between them (by UV area they would take 18 of 22)
    mesh = _uv_box(mirror=True)
    c = mesh.vertices[mesh.faces]
    px, mx = (c[:, :, 0] > 0.399).all(axis=1), (c[:, :, 0] < -0.399).all(axis=1)
    w = map_texel_weights(mesh)
    assert w.sum() == pytest.approx(1.0) and (w >= 0).all()
    assert w[px | mx].sum() == pytest.approx(9 / 13, abs=0.01)
    uv_area = _uv_areas(mesh)
    assert uv_area[px | mx].sum() / uv_area.sum() == pytest.approx(18 / 22, abs=1e-9)
    # a tile repeated twice across the map (u in [0, 2], wrapped) holds one map's worth of texels, not two
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]])
    uv = np.array([[[0, 0], [1, 0], [1, 0.5]], [[0, 0], [1, 0.5], [0, 0.5]],
                   [[0, 0.5], [2, 0.5], [2, 1]], [[0, 0.5], [2, 1], [0, 1]]], dtype=np.float64)
    tiled = Mesh(v, f, uv=uv)
    w = map_texel_weights(tiled, 64)
    assert w[:2].sum() == pytest.approx(0.5, abs=0.02) and w[2:].sum() == pytest.approx(0.5, abs=0.02)
    # clamped, the part outside the map holds no texel: the second quad's half inside, half the map's texels
    w = map_texel_weights(replace(tiled, uv_policy="clamp"), 64)
    assert w[2:].sum() == pytest.approx(0.5, abs=0.02)
    # below a texel a face keeps its UV area's expected texels (a 4² map: a twenty-fifth of a texel each);
    # wholly outside a clamped map, none
    small = Mesh(v, f, uv=np.concatenate([uv[:2] * 0.1, uv[2:] * 0.1 + 1.5]))
    w = map_texel_weights(replace(small, uv_policy="clamp"), 4)
    assert np.allclose(w, [0.5, 0.5, 0.0, 0.0])
    assert map_texel_weights(replace(mesh, uv=None)) is None
    assert map_texel_weights(replace(mesh, uv=np.zeros_like(mesh.uv))) is None


def test_texel_pools_are_denser_where_the_layout_gives_texels():
    from neural_bake.fit.sdf_pools import _Pools

    mesh = _uv_box()
    cfg = replace(SdfFitConfig(), pool_surface=20_000, pool_near=2000, pool_uniform=100)
    share = {}
    for t in (0.0, 1.0):
        p = _Pools(mesh, replace(cfg, texel_sampling=t), torch.device("cpu"), torch.float32).get(0)["surf_p"].numpy()
        share[t] = (p[:, 0] > 0.399).mean()
    # one side of six by area; by UV area 9 of 14 (the other five sides 1 each)
    assert share[0.0] == pytest.approx(1 / 6, abs=0.02) and share[1.0] == pytest.approx(9 / 14, abs=0.02)


def test_texel_sampling_off_keeps_the_fingerprint():
    cfg = SdfFitConfig()
    assert cfg.fingerprint_dict() == replace(cfg, texel_sampling=0.0).fingerprint_dict()
    assert "texel_sampling" not in cfg.fingerprint_dict()
    assert replace(cfg, texel_sampling=0.5).fingerprint_dict()["texel_sampling"] == 0.5


def _hard_box(size=0.8, max_edge=0.1, split=True) -> Mesh:
    """:func:`_box` with its file's own normals: every corner its face's (hard edges) or, ``split=False``, the
    welded vertices' averaged normals (a smooth file: one normal per vertex)."""
    mesh = _box(size, max_edge)
    if split:
        normals = np.repeat(mesh.face_normals[:, None], 3, axis=1)
    else:
        from neural_bake.geometry import vertex_normals

        normals = vertex_normals(mesh)[mesh.faces]
    return replace(mesh, corner_normals=np.asarray(normals, dtype=np.float64))


def _edge_distance(p: np.ndarray, half: float) -> np.ndarray:
    """Distance from points on the cube's sides to its nearest edge, across the side."""
    a = np.sort(np.abs(p), axis=1)  # the largest coordinate is the side's own (±half)
    return half - a[:, 1]


def test_hard_edges_are_where_the_files_normals_split():
    mesh = _hard_box()
    face, slot = hard_edge_sides(mesh)
    tri, rows = mesh.vertices[mesh.faces[face]], np.arange(len(face))
    ends = np.stack([tri[rows, slot], tri[rows, (slot + 1) % 3]], axis=1)
    # every side lies on one of the cube's 12 edges (two coordinates at ±0.4 at both ends), and the pieces the
    # subdivision cut them into are there twice (once per face): twice 12 edges of 0.8
    assert (np.isclose(np.abs(ends), 0.4).sum(axis=2) >= 2).all()
    assert np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1).sum() == pytest.approx(2 * 12 * 0.8)
    # a smooth file, a file without normals, a split of less than the threshold: none
    for other in (_hard_box(split=False), replace(mesh, corner_normals=None)):
        assert hard_edge_sides(other)[0].size == 0
    assert hard_edge_sides(mesh, min_deg=91.0)[0].size == 0


def test_edge_band_points_lie_uniformly_in_the_strips_with_one_sided_normals():
    # two triangles of height 1 meeting at a right angle along the x axis, hard-shaded: the strip within
    # ``band`` of the edge on each face, uniform by area, has its distance d from the edge with density ∝ 1 − d
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, 0, 1]])
    book = Mesh(v, np.array([[0, 1, 2], [1, 0, 3]]))
    book = replace(book, corner_normals=np.repeat(book.face_normals[:, None], 3, axis=1).astype(np.float64))
    band = 0.2
    s = sample_surface(book, 40_000, seed=4, normals="vertex", colors=False, edge_share=1.0, edge_band=band)
    p = s.points.astype(np.float64)
    d = np.hypot(p[:, 1], p[:, 2])
    assert d.max() <= band + 1e-6 and (np.bincount(s.face_index, minlength=2) / len(d) == pytest.approx(0.5, abs=0.01))
    edges = np.linspace(0, band, 5)
    expected = np.diff(edges - edges**2 / 2) / (band - band**2 / 2)
    assert np.histogram(d, bins=edges)[0] / len(d) == pytest.approx(expected, abs=0.01)
    # along the edge, uniform over the strip's length at that distance: x - 0.5 d is uniform on [0, 1 - d]
    u = (p[:, 0] - 0.5 * d) / (1.0 - d)
    assert np.histogram(u, bins=4, range=(0, 1))[0] / len(u) == pytest.approx(0.25, abs=0.01)
    # each point keeps its own face's normal: one side of the edge, not the average across it
    np.testing.assert_allclose(s.normals, book.face_normals[s.face_index], atol=1e-6)
    # on a subdivided cube, every point lies within the band of one of its edges
    cube = _hard_box()
    c = sample_surface(cube, 5000, seed=4, normals="vertex", colors=False, edge_share=1.0, edge_band=0.02)
    assert _edge_distance(c.points.astype(np.float64), 0.4).max() <= 0.02 + 1e-6
    np.testing.assert_allclose(c.normals, cube.face_normals[c.face_index], atol=1e-6)


def test_edge_share_draws_its_part_along_the_hard_edges_and_nothing_else_changes():
    mesh, band, n = _hard_box(), 0.02, 40_000
    plain = sample_surface(mesh, n, seed=2, colors=False)
    in_band = lambda s: (_edge_distance(s.points.astype(np.float64), 0.4) <= band).mean()  # noqa: E731
    area_share = 4 * band * 0.8 * 6 / (6 * 0.8**2) - 4 * band**2 * 6 / (6 * 0.8**2)  # strips less corner overlaps
    assert in_band(plain) == pytest.approx(area_share, abs=0.01)
    edged = sample_surface(mesh, n, seed=2, colors=False, edge_share=0.25, edge_band=band)
    assert len(edged) == n and in_band(edged) == pytest.approx(0.25 + 0.75 * area_share, abs=0.01)
    # a mesh without hard edges keeps the same draws, points and normals alike
    smooth = _hard_box(split=False)
    a = sample_surface(smooth, 5000, seed=7, normals="vertex")
    b = sample_surface(smooth, 5000, seed=7, normals="vertex", edge_share=0.5)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.normals, b.normals)
    # the near points start from the same draws: every σ group has its share along the edges
    near = sample_near(mesh, 30_000, sigma=(1e-4, 2e-4, 3e-4), seed=3, edge_share=1.0, edge_band=band)
    closest = np.clip(near.points.astype(np.float64), -0.4, 0.4)
    assert (_edge_distance(closest, 0.4) <= band + 1e-3).all()
    with pytest.raises(ValueError, match="edge_share must be in"):
        sample_surface(mesh, 10, edge_share=1.5)
    with pytest.raises(ValueError, match="edge_band must be positive"):
        sample_surface(mesh, 10, edge_share=0.5, edge_band=-1.0)


def test_edge_pools_and_fingerprint():
    from neural_bake.fit.sdf_pools import _Pools

    mesh = _hard_box()
    cfg = replace(SdfFitConfig(), pool_surface=20_000, pool_near=2000, pool_uniform=100, edge_band=0.02)
    share = {}
    for e in (0.0, 0.5):
        p = _Pools(mesh, replace(cfg, edge_sampling=e), torch.device("cpu"), torch.float32).get(0)["surf_p"].numpy()
        share[e] = (_edge_distance(p.astype(np.float64), 0.4) <= 0.02).mean()
    assert share[0.5] == pytest.approx(0.5 + 0.5 * share[0.0], abs=0.015)
    assert "edge_sampling" not in cfg.fingerprint_dict() and "edge_band" not in cfg.fingerprint_dict()
    assert replace(cfg, edge_sampling=0.25).fingerprint_dict()["edge_band"] == 0.02
