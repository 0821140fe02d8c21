"""Texel rasterisation: plane oracle, supersampling, conservative borders, wrap/clamp, chunks, errors."""

import numpy as np
import pytest
import trimesh

from neural_bake.errors import MeshError, NeuralBakeError, NeuralBakeWarning
from neural_bake.mesh.texels import (TexelSet, iter_texels, rasterize_texels, texel_centres, texel_counts,
                                    texel_grid_points)
from neural_bake.types import Mesh


def plane(uv_shift=(0.0, 0.0), policy="wrap", flip_u=False):
    """Square [-1, 1]² at z = 0 (normal +z) mapped to [0, 1]² (u = (x+1)/2, v = (y+1)/2), two triangles."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    uv = (v[:, :2] + 1) / 2 + np.asarray(uv_shift)
    if flip_u:
        uv[:, 0] = 1 - uv[:, 0]
        f = f.copy()
    return Mesh(vertices=v, faces=f, uv=uv[f], uv_policy=policy)


def expected_points(h, w):
    r, c = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    x = 2 * (c + 0.5) / w - 1
    y = 2 * (1 - (r + 0.5) / h) - 1
    return x.ravel(), y.ravel()


@pytest.mark.parametrize("size", [(8, 8), (16, 12), (1, 1)])
def test_plane_every_texel_centre_maps_to_its_point(size):
    h, w = size
    ts = rasterize_texels(plane(), size)
    assert isinstance(ts, TexelSet) and ts.size == (h, w)
    assert ts.coverage.all() and ts.n_samples == h * w and not ts.border.any() and ts.overlaps == 0
    order = np.argsort(ts.texel)
    np.testing.assert_array_equal(ts.texel[order], np.arange(h * w))
    np.testing.assert_array_equal(ts.pixel[order], np.stack(np.divmod(np.arange(h * w), w), axis=1))
    x, y = expected_points(h, w)
    np.testing.assert_allclose(ts.points[order], np.stack([x, y, np.zeros_like(x)], 1), atol=1e-12)
    np.testing.assert_allclose(ts.normal, np.tile([0, 0, 1.0], (h * w, 1)))
    np.testing.assert_allclose(ts.tangent, np.tile([1.0, 0, 0], (h * w, 1)), atol=1e-12)
    np.testing.assert_allclose(ts.bitangent, np.tile([0, 1.0, 0], (h * w, 1)), atol=1e-12)
    np.testing.assert_allclose(ts.weight, 1.0)
    assert (ts.bary >= 0).all()
    np.testing.assert_allclose(ts.bary.sum(1), 1.0)
    # the barycentrics reproduce the points
    np.testing.assert_allclose(np.einsum("mk,mkd->md", ts.bary, plane().triangles[ts.face]), ts.points)


def test_texel_grid_points_agree_with_rasterised_uv():
    m = plane()
    ts = rasterize_texels(m, (6, 10))
    uv = np.einsum("mk,mkd->md", ts.bary, m.uv[ts.face])
    grid = texel_grid_points((6, 10))
    np.testing.assert_allclose(uv, grid[ts.pixel[:, 0], ts.pixel[:, 1]], atol=1e-12)


def test_flipped_u_flips_tangent_keeps_bitangent():
    ts = rasterize_texels(plane(flip_u=True), 8)
    np.testing.assert_allclose(ts.tangent, np.tile([-1.0, 0, 0], (64, 1)), atol=1e-12)
    np.testing.assert_allclose(ts.bitangent, np.tile([0, 1.0, 0], (64, 1)), atol=1e-12)


@pytest.mark.parametrize("s", [2, 3])
def test_supersampling_weights_and_mean_point(s):
    h, w = 5, 7
    ts = rasterize_texels(plane(), (h, w), supersample=s)
    assert ts.n_samples == h * w * s * s and ts.supersample == s
    np.testing.assert_allclose(np.bincount(ts.texel, weights=ts.weight, minlength=h * w), 1.0)
    mean = ts.resolve(ts.points).reshape(-1, 3)
    x, y = expected_points(h, w)
    np.testing.assert_allclose(mean, np.stack([x, y, np.zeros_like(x)], 1), atol=1e-12)
    # subsample positions are distinct, inside their texel
    uv = np.einsum("mk,mkd->md", ts.bary, plane().uv[ts.face])
    col = uv[:, 0] * w - 0.5
    row = (1 - uv[:, 1]) * h - 0.5
    assert np.abs(col - ts.pixel[:, 1]).max() < 0.5 and np.abs(row - ts.pixel[:, 0]).max() < 0.5


def one_triangle():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2]], dtype=np.int64)
    uv = np.array([[[0.13, 0.11], [0.87, 0.2], [0.3, 0.91]]])
    return Mesh(vertices=v, faces=f, uv=uv)


def _brute_overlap(uvtri, h, w, n=24):
    """(H, W) bool: texels whose square contains one of n×n interior sub-points inside the UV triangle."""
    out = np.zeros((h, w), bool)
    for r in range(h):
        for c in range(w):
            g = (np.arange(n) + 0.5) / n
            uu = (c + g[None, :]) / w + 0 * g[:, None]
            vv = 1 - (r + g[:, None]) / h + 0 * g[None, :]
            p = np.stack([uu.ravel(), vv.ravel()], 1)
            a, b, cc = uvtri
            m = np.array([b - a, cc - a]).T
            lam = np.linalg.solve(m, (p - a).T).T
            out[r, c] = ((lam >= 0).all(1) & (lam.sum(1) <= 1)).any()
    return out


def test_conservative_border_texels_cover_every_touched_texel():
    m = one_triangle()
    h = w = 16
    inner = rasterize_texels(m, 16, conservative=False)
    full = rasterize_texels(m, 16)
    assert not inner.border.any() and full.border.any()
    touched = _brute_overlap(m.uv[0], h, w)
    assert not (touched & ~full.coverage).any()  # every touched texel is covered
    assert not (inner.coverage & ~full.coverage).any()
    # border samples: clamped barycentrics, points on the triangle, one per texel
    b = full.border
    assert (full.bary[b] >= 0).all()
    np.testing.assert_allclose(full.bary[b].sum(1), 1.0)
    assert len(np.unique(full.texel)) == full.n_samples
    # a border texel's sample is the triangle's closest point to its centre: within half a texel diagonal
    uv = np.einsum("mk,mkd->md", full.bary[b], m.uv[full.face[b]])
    centre = texel_grid_points(16)[full.pixel[b, 0], full.pixel[b, 1]]
    assert (np.linalg.norm(uv - centre, axis=1) <= np.sqrt(2) / 2 / 16 + 1e-12).all()


def _slow_centres(m, h, w):
    """Texel centres inside any UV triangle (per-texel loop reference)."""
    cov = np.zeros((h, w), bool)
    for r in range(h):
        for c in range(w):
            p = np.array([(c + 0.5) / w, 1 - (r + 0.5) / h])
            for tri in m.uv:
                a, b, cc = tri
                mat = np.array([b - a, cc - a]).T
                if abs(np.linalg.det(mat)) < 1e-14:
                    continue
                lam = np.linalg.solve(mat, p - a)
                if lam.min() >= -1e-9 and lam.sum() <= 1 + 1e-9:
                    cov[r, c] = True
                    break
    return cov


def test_centres_match_slow_reference_on_random_triangles(rng):
    uv = rng.uniform(0.02, 0.98, size=(12, 3, 2))
    v = rng.normal(size=(36, 3))
    m = Mesh(vertices=v, faces=np.arange(36).reshape(12, 3), uv=uv)
    ts = rasterize_texels(m, (13, 17), conservative=False, tangents=np.tile([1.0, 0, 0, 1], (36, 1)))
    np.testing.assert_array_equal(ts.coverage, _slow_centres(m, 13, 17))
    assert np.isfinite(ts.points).all() and np.isfinite(ts.normal).all() and np.isfinite(ts.tangent).all()


def test_degenerate_face_gives_finite_output():
    m = plane()
    # add a face with zero 3-D area and zero UV area, and one with zero 3-D area but a real UV triangle
    m.vertices = np.concatenate([m.vertices, [[0.5, 0.5, 0.5]] * 3])
    m.faces = np.concatenate([m.faces, [[4, 5, 6], [4, 4, 5]]])
    m.uv = np.concatenate([m.uv, [[[0.5, 0.5]] * 3, [[0.1, 0.1], [0.4, 0.1], [0.1, 0.4]]]])
    tang = np.tile([1.0, 0, 0, 1], (7, 1))
    ts = rasterize_texels(m, 16, tangents=tang)
    for name in ("points", "normal", "tangent", "bitangent", "bary", "weight"):
        assert np.isfinite(getattr(ts, name)).all(), name
    np.testing.assert_allclose(np.linalg.norm(ts.normal, axis=1), 1.0)
    np.testing.assert_allclose(np.linalg.norm(ts.tangent, axis=1), 1.0)
    assert ts.overlaps > 0  # the degenerate-in-3-D face overlaps the plane's UV triangles


def test_uvs_outside_unit_square_wrap():
    with pytest.warns(NeuralBakeWarning, match="outside \\[0, 1\\]; wrapped"):
        ts = rasterize_texels(plane(uv_shift=(0.25, 0.0)), 8)
    assert ts.coverage.all() and ts.n_samples == 64
    # u = (x + 1)/2 + 0.25 (mod 1): texel column c has u = (c + .5)/8
    u = (ts.pixel[:, 1] + 0.5) / 8
    x = ((u - 0.25) % 1.0) * 2 - 1
    np.testing.assert_allclose(ts.points[:, 0], x, atol=1e-12)


@pytest.mark.parametrize("shift,policy", [((0.0, 0.0), "wrap"), ((0.25, 0.0), "wrap"), ((0.25, 0.0), "clamp")])
def test_texel_centres_are_the_rasteriser_s_own_samples(shift, policy):
    """The texel centres on faces: the rasteriser's non-border samples at one per texel (faces, texels and
    barycentrics), on a plane whose UVs are inside, wrapped and clamped, and on a random-triangle layout."""
    import warnings

    rng = np.random.default_rng(3)
    tris = rng.uniform(0, 1, size=(40, 3, 2))
    random_layout = Mesh(vertices=rng.normal(size=(120, 3)), faces=np.arange(120).reshape(40, 3), uv=tris)
    for mesh in (plane(uv_shift=shift, policy=policy), random_layout):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NeuralBakeWarning)
            ts = rasterize_texels(mesh, (16, 12))
            face, rows, cols, bary = texel_centres(mesh, (16, 12))
        keep = ~ts.border
        order = np.argsort(rows * 12 + cols, kind="stable")
        np.testing.assert_array_equal(face[order], ts.face[keep])
        np.testing.assert_array_equal(np.stack([rows, cols], 1)[order], ts.pixel[keep])
        np.testing.assert_allclose(bary[order], ts.bary[keep], atol=1e-12)
    with pytest.raises(MeshError, match="no UVs"):
        texel_centres(Mesh(vertices=np.eye(3), faces=np.array([[0, 1, 2]])), 8)


def test_texel_counts_are_the_centres_each_face_holds_and_count_overlaps():
    """Per face, the texel centres :func:`texel_centres` gives it; strict overlaps counted; no warning for
    UVs outside [0, 1]; no UVs refused."""
    import warnings

    rng = np.random.default_rng(5)
    tris = rng.uniform(-0.5, 1.5, size=(30, 3, 2))
    mesh = Mesh(vertices=rng.normal(size=(90, 3)), faces=np.arange(90).reshape(30, 3), uv=tris)
    with warnings.catch_warnings():
        warnings.simplefilter("error", NeuralBakeWarning)
        counts, overlaps = texel_counts(mesh, (20, 24))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NeuralBakeWarning)
        face, _, _, _ = texel_centres(mesh, (20, 24))
    np.testing.assert_array_equal(counts, np.bincount(face, minlength=30))
    assert overlaps > 0  # random triangles over the square overlap
    # two copies of one triangle: every centre strictly inside is an overlap, held by the first face
    one = np.array([[[0.1, 0.1], [0.93, 0.1], [0.1, 0.93]]])  # no centre on its edges
    twice = Mesh(vertices=rng.normal(size=(6, 3)), faces=np.arange(6).reshape(2, 3), uv=np.concatenate([one, one]))
    counts, overlaps = texel_counts(twice, 16)
    assert counts[1] == 0 and counts[0] > 0 and overlaps > 0.9 * counts[0]
    with pytest.raises(MeshError, match="no UVs"):
        texel_counts(Mesh(vertices=np.eye(3), faces=np.array([[0, 1, 2]])), 8)


def test_uvs_outside_unit_square_clamp_reports_and_skips():
    with pytest.warns(NeuralBakeWarning, match="cover no texel"):
        ts = rasterize_texels(plane(uv_shift=(0.25, 0.0), policy="clamp"), 8)
    np.testing.assert_array_equal(ts.coverage[:, :2], False)
    assert ts.coverage[:, 2:].all()


def test_iter_texels_bands_concatenate_to_the_whole():
    s = trimesh.creation.icosphere(2)
    from neural_bake.mesh.unwrap import unwrap

    m = unwrap(Mesh(vertices=s.vertices * 0.8, faces=s.faces.astype(np.int64)), resolution=64, padding=2)
    whole = rasterize_texels(m, 64, supersample=2)
    parts = list(iter_texels(m, 64, supersample=2, max_samples=2000))
    assert len(parts) > 4
    cat = {k: np.concatenate([getattr(p, k) for p in parts]) for k in ("texel", "points", "face", "border", "weight")}
    for k, v in cat.items():
        np.testing.assert_array_equal(v, getattr(whole, k), err_msg=k)
    cov = np.zeros((64, 64), bool)
    for p in parts:
        assert not (cov & p.coverage).any()
        cov |= p.coverage
    np.testing.assert_array_equal(cov, whole.coverage)
    # points lie on the sphere (radius 0.8, chordal error of an icosphere(2) is small)
    r = np.linalg.norm(whole.points, axis=1)
    assert r.max() <= 0.8 + 1e-9 and r.min() > 0.75
    assert np.abs(np.sum(whole.normal * whole.tangent, axis=1)).max() < 0.1


def test_errors():
    m = plane()
    with pytest.raises(NeuralBakeError, match="size: texel grid must be at least 1x1"):
        rasterize_texels(m, 0)
    with pytest.raises(NeuralBakeError, match="size: expected an int or"):
        rasterize_texels(m, "big")
    with pytest.raises(NeuralBakeError, match="supersample: must be a positive integer"):
        rasterize_texels(m, 8, supersample=0)
    with pytest.raises(NeuralBakeError, match="tangents: expected shape \\(4, 4\\) or \\(2, 3, 4\\)"):
        rasterize_texels(m, 8, tangents=np.zeros((3, 4)))
    m.uv = None
    with pytest.raises(MeshError, match="no UVs"):
        rasterize_texels(m, 8)


def test_unsplit_uvs_use_per_corner_tangents():
    # a seam: the same vertex with different UVs on its two faces; tangents come from a split copy
    m = plane()
    m.uv = m.uv.copy()
    m.uv[0, :, 0] = 0.5 * m.uv[0, :, 0]  # face 0 in the left half
    m.uv[1, :, 0] = 1 - 0.5 * m.uv[1, :, 0]  # face 1 mirrored into the right half
    ts = rasterize_texels(m, 8)
    assert np.isfinite(ts.tangent).all() and ts.overlaps == 0
    w = np.sign(np.einsum("md,md->m", np.cross(ts.normal, ts.tangent), ts.bitangent))
    np.testing.assert_array_equal(w, np.where(ts.face == 0, 1.0, -1.0))
    np.testing.assert_allclose(ts.tangent, np.where(ts.face[:, None] == 0, [1.0, 0, 0], [-1.0, 0, 0]), atol=1e-12)


def test_tiny_chart_smaller_than_a_texel_still_gets_a_sample():
    # a UV triangle 0.3 texel across that contains no texel centre
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64)
    uv = (np.array([[[3.6, 4.1], [3.9, 4.1], [3.6, 4.4]]]) / 8.0)  # texel-space corners / size
    m = Mesh(vertices=v, faces=np.array([[0, 1, 2]]), uv=uv)
    assert rasterize_texels(m, 8, conservative=False).n_samples == 0
    ts = rasterize_texels(m, 8)
    assert ts.n_samples >= 1 and ts.border.all()
    assert ts.coverage.sum() == ts.n_samples
    np.testing.assert_allclose(ts.points[:, 2], 0.0)
    assert (ts.bary >= 0).all() and np.isfinite(ts.normal).all()


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    h=st.integers(1, 11),
    w=st.integers(1, 11),
    n=st.integers(1, 6),
    f32=st.booleans(),
)
def test_property_centres_match_slow_reference_and_frames_finite(seed, h, w, n, f32):
    rng = np.random.default_rng(seed)
    uv = rng.uniform(0.0, 1.0, size=(n, 3, 2)).astype(np.float32 if f32 else np.float64)
    m = Mesh(vertices=rng.normal(size=(3 * n, 3)), faces=np.arange(3 * n).reshape(n, 3), uv=uv)
    ts = rasterize_texels(m, (h, w), conservative=False)
    m64 = Mesh(vertices=m.vertices, faces=m.faces, uv=uv.astype(np.float64))
    np.testing.assert_array_equal(ts.coverage, _slow_centres(m64, h, w))
    full = rasterize_texels(m, (h, w))
    assert not (ts.coverage & ~full.coverage).any()
    for name in ("points", "normal", "tangent", "bitangent", "bary", "weight"):
        assert np.isfinite(getattr(full, name)).all()
    sums = np.bincount(full.texel, weights=full.weight, minlength=h * w)
    np.testing.assert_allclose(sums[full.coverage.ravel()], 1.0)
    np.testing.assert_array_equal(sums[~full.coverage.ravel()], 0.0)


# ---- the C kernel (texels.c) against the numpy rasteriser it replaces

from neural_bake.mesh import texels as texels_module  # noqa: E402

_EXACT = ("pixel", "points", "face", "bary", "weight", "texel", "coverage", "border")
_FRAME = ("normal", "tangent", "bitangent")


def _both(monkeypatch, mesh, size, **kw):
    """(C kernel, numpy) rasterisations of ``mesh``; skips where the kernel does not build."""
    if texels_module._kernel() is None:
        pytest.skip(f"no C kernel here: {texels_module.kernel_status()}")
    fast = rasterize_texels(mesh, size, **kw)
    with monkeypatch.context() as mp:
        mp.setattr(texels_module.KERNEL, "_state", {"lib": None, "status": "off (test)"})
        assert texels_module.kernel_status() == "numpy (off (test))"
        slow = rasterize_texels(mesh, size, **kw)
    return fast, slow


def _assert_same(fast, slow):
    for name in _EXACT:
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)
    assert fast.overlaps == slow.overlaps
    for name in _FRAME:  # torch divides by a broadcast length as a product with its reciprocal: ≤ 1 ulp apart
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=0, atol=4.5e-16, err_msg=name)


@pytest.mark.parametrize("size,supersample", [(37, 1), (128, 2), (300, 1)])
def test_kernel_equals_numpy_on_an_unwrapped_sphere(monkeypatch, size, supersample):
    from neural_bake.mesh.unwrap import unwrap

    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
    m = unwrap(Mesh(vertices=np.asarray(ico.vertices, dtype=np.float64), faces=np.asarray(ico.faces)),
               resolution=128)
    _assert_same(*_both(monkeypatch, m, size, supersample=supersample))


def test_kernel_equals_numpy_on_degenerate_overlapping_and_wrapped_uvs(monkeypatch):
    m = plane(uv_shift=(0.25, 0.0))
    m.vertices = np.concatenate([m.vertices, [[0.5, 0.5, 0.5]] * 3])
    m.faces = np.concatenate([m.faces, [[4, 5, 6], [4, 4, 5]]])
    m.uv = np.concatenate([m.uv, [[[0.5, 0.5]] * 3, [[0.1, 0.1], [0.4, 0.1], [0.1, 0.4]]]])
    with pytest.warns(NeuralBakeWarning):
        fast, slow = _both(monkeypatch, m, 16, tangents=np.tile([1.0, 0, 0, 1], (7, 1)))
    _assert_same(fast, slow)
    assert fast.overlaps > 0


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(1, 40), w=st.integers(1, 40), n=st.integers(1, 12),
       s=st.integers(1, 3), tiny=st.booleans())
def test_property_kernel_equals_numpy_on_random_triangles(seed, h, w, n, s, tiny):
    rng = np.random.default_rng(seed)
    uv = rng.uniform(0.0, 1.0, size=(n, 3, 2))
    if tiny:  # sub-texel triangles: only the conservative border pass gives them texels
        uv = uv[:, :1] + 0.01 * (uv - uv[:, :1])
    m = Mesh(vertices=rng.normal(size=(3 * n, 3)), faces=np.arange(3 * n).reshape(n, 3), uv=uv)
    with pytest.MonkeyPatch.context() as mp:
        fast, slow = _both(mp, m, (h, w), supersample=s)
    _assert_same(fast, slow)
    assert not tiny or fast.border.any() or not fast.coverage.any()


def test_bitangent_kernel_matches_numpy_bit_for_bit(rng):
    # sign · cross(n, t): the C kernel's operations are numpy's, in the same order
    from neural_bake.nets.native import compiler

    if compiler() is None:
        pytest.skip("no C compiler: the numpy path is the only one")
    assert texels_module.KERNEL.lib() is not None, texels_module.KERNEL.status()  # a compiler that cannot build the kernel is a failure
    n, t = rng.normal(size=(2, 500, 3))
    sign = np.where(rng.random(500) < 0.5, -1.0, 1.0)
    out = texels_module._signed_cross(sign, n, t)
    np.testing.assert_array_equal(out, sign[:, None] * np.cross(n, t))
    assert texels_module._signed_cross(sign[:0], n[:0], t[:0]).shape == (0, 3)
