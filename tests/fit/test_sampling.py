"""Sampling: area-uniform surface points, colours, signed distance and its sign, determinism, errors."""

import dataclasses
import math

import numpy as np
import pytest
import trimesh
from scipy import stats

from neural_bake.errors import MeshError
from neural_bake.fit import sampling as S
from neural_bake.fit.sampling import (
    SurfaceSamples,
    VolumeSamples,
    inside_mask,
    sample_near,
    sample_surface,
    sample_uniform,
    signed_distance,
    unsigned_distance,
)
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.mesh.winding import winding_number
from neural_bake.samples import SAMPLES
from neural_bake.types import Mesh

R = 0.9


def _icosphere(subdivisions=3, radius=R) -> Mesh:
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return Mesh(np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64))


@pytest.fixture(scope="module")
def sphere():
    return _icosphere(3)  # 1280 faces


@pytest.fixture(scope="module")
def textured_sphere():
    s = SAMPLES["sphere"]
    m = s.mesh(resolution=2048, texture_size=256)
    mesh = mesh_from_arrays(m.vertices, m.faces, m.uv, m.texture)
    return s, mesh


@pytest.fixture(scope="module")
def open_sphere(sphere):
    c = sphere.triangles.mean(1)
    keep = c[:, 2] < 0.8  # remove the cap above z = 0.8: a hole of radius ~0.4
    return Mesh(sphere.vertices, sphere.faces[keep], watertight=False)


def _gap(mesh: Mesh, radius=R) -> float:
    """Largest distance between the sphere and the inscribed polyhedron (the faces' planes)."""
    t = mesh.triangles
    n = mesh.face_normals
    return float(radius - np.abs((n * t[:, 0]).sum(1)).min())


# ------------------------------------------------------------------------------------------- surface


def test_surface_samples_lie_on_the_mesh_and_z_is_uniform_archimedes():
    mesh = _icosphere(5)  # 20480 faces: the polyhedron's z density is uniform to ~1e-3
    s = sample_surface(mesh, 20000, seed=3)
    assert isinstance(s, SurfaceSamples) and len(s) == 20000
    assert s.points.dtype == np.float32 and s.normals.dtype == np.float32 and s.face_index.dtype == np.int64
    # every point lies in the plane of its face, inside the face
    tri = mesh.triangles[s.face_index]
    n = mesh.face_normals[s.face_index]
    off = ((s.points.astype(np.float64) - tri[:, 0]) * n).sum(1)
    assert np.abs(off).max() < 1e-6
    r = np.linalg.norm(s.points, axis=1)
    assert r.max() <= R + 1e-6 and r.min() >= R - _gap(mesh) - 1e-6
    # Archimedes: the height of area-uniform points on a sphere is uniform
    ks = stats.kstest(s.points[:, 2] / R, stats.uniform(-1, 2).cdf)
    assert ks.pvalue > 1e-3
    # and the azimuth too
    ks = stats.kstest(np.arctan2(s.points[:, 1], s.points[:, 0]), stats.uniform(-math.pi, 2 * math.pi).cdf)
    assert ks.pvalue > 1e-3


def test_faces_are_drawn_by_area_and_points_uniform_inside():
    # three triangles of areas 1 : 4 : 0.25 (a scaled copy of one triangle)
    base = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64)
    verts = np.concatenate([base * 0.5, base + [2, 0, 0], base * 0.25 + [5, 0, 0]])
    faces = np.arange(9).reshape(3, 3)
    mesh = Mesh(verts, faces, watertight=False)
    n = 40000
    s = sample_surface(mesh, n, seed=1)
    counts = np.bincount(s.face_index, minlength=3)
    area = mesh.face_areas
    chi = stats.chisquare(counts, n * area / area.sum())
    assert chi.pvalue > 1e-3
    # inside one triangle: the 4 midpoint sub-triangles get a quarter each
    sel = s.face_index == 1
    p = s.points[sel].astype(np.float64) - [2, 0, 0]
    x, y = p[:, 0], p[:, 1]
    assert (x >= -1e-7).all() and (y >= -1e-7).all() and (x + y <= 1 + 1e-6).all()
    quad = np.where(x > 0.5, 0, np.where(y > 0.5, 1, np.where(x + y < 0.5, 2, 3)))
    chi = stats.chisquare(np.bincount(quad, minlength=4))
    assert chi.pvalue > 1e-3


def test_face_normals_are_the_faces_and_vertex_normals_are_smoother(sphere):
    s = sample_surface(sphere, 5000, seed=2)
    np.testing.assert_allclose(s.normals, sphere.face_normals[s.face_index], atol=1e-6)
    sv = sample_surface(sphere, 5000, seed=2, normals="vertex")
    np.testing.assert_array_equal(sv.points, s.points)  # same points, other normals
    np.testing.assert_allclose(np.linalg.norm(sv.normals, axis=1), 1.0, atol=1e-6)
    exact = s.points / np.linalg.norm(s.points, axis=1, keepdims=True)
    err_face = 1 - (s.normals * exact).sum(1)
    err_vertex = 1 - (sv.normals * exact).sum(1)
    assert err_vertex.mean() < 0.2 * err_face.mean()
    assert err_vertex.max() < 2e-3


def test_vertex_normals_are_the_files_own_where_it_has_them():
    """A box whose file gives every corner its face's normal (hard edges): the "vertex" normals are the box's
    axis directions, where the welded vertices' averaged normals round every side by up to 54.7°; corner
    normals given inward are turned to the face's outward side."""
    box = trimesh.creation.box(extents=(1.0, 0.4, 0.7))
    welded = mesh_from_arrays(box.vertices, box.faces)
    exact = np.repeat(welded.face_normals[:, None], 3, axis=1)
    hard = dataclasses.replace(welded, corner_normals=exact)
    inward = dataclasses.replace(welded, corner_normals=-exact)
    rounded = sample_surface(welded, 4000, seed=3, normals="vertex")
    err = np.degrees(np.arccos(np.clip((rounded.normals * welded.face_normals[rounded.face_index]).sum(1), -1, 1)))
    assert err.max() > 30.0  # near the corners the averaged normal is far from the side's
    for mesh in (hard, inward):
        s = sample_surface(mesh, 4000, seed=3, normals="vertex")
        np.testing.assert_array_equal(s.points, rounded.points)
        np.testing.assert_allclose(s.normals, welded.face_normals[s.face_index], atol=1e-6)
    # the near samples' gradient targets read the same normals at their closest points: off a side near its
    # corner, straight out of that side
    p = np.array([[0.8, 0.3, 0.66], [0.85, 0.39, 0.5], [-0.85, -0.39, 0.5]])  # the box spans ±(0.9, 0.36, 0.63)
    d = signed_distance(hard, p)
    closest = S._closest_points(hard, p)
    got = S.distance_gradient_targets(hard, p, d, closest, reach=0.1)
    np.testing.assert_allclose(got, [[0, 0, 1], [0, 1, 0], [0, -1, 0]], atol=1e-9)
    assert (S.distance_gradient_targets(welded, p, d, S._closest_points(welded, p), reach=0.1)[:, :2] != 0).any()


def test_colours_and_uv_match_the_analytic_texture(textured_sphere):
    shape, mesh = textured_sphere
    s = sample_surface(mesh, 4000, seed=5)
    assert s.uv.dtype == np.float32 and s.colors.dtype == np.float32 and s.colors.shape == (4000, 3)
    # the colour is the painted field at the interpolated uv (bilinear error of a smooth field only)
    np.testing.assert_allclose(s.colors, shape.albedo_uv(s.uv, 256), atol=2e-3)
    # and the field at the point itself, up to the tessellation's uv distortion
    src = mesh.frame.to_source(s.points)
    np.testing.assert_allclose(s.colors, shape.albedo(src), atol=0.05)
    # the interpolated uv is the point's azimuth and polar angle (away from the seam and the poles)
    az = (np.arctan2(src[:, 1], src[:, 0]) / (2 * math.pi)) % 1.0
    ok = (np.abs(src[:, 2]) < 0.8 * R) & (az > 0.02) & (az < 0.98)
    np.testing.assert_allclose(s.uv[ok, 0], az[ok], atol=5e-3)
    theta = np.arccos(np.clip(src[:, 2] / np.linalg.norm(src, axis=1), -1, 1))
    v = (0.5 + (1 - theta / math.pi) * 127) / 128
    np.testing.assert_allclose(s.uv[:, 1], v, atol=5e-3)


def test_colours_can_be_skipped_and_the_places_stay_the_same(textured_sphere):
    _, mesh = textured_sphere
    full, bare = sample_surface(mesh, 500, seed=4), sample_surface(mesh, 500, seed=4, colors=False)
    assert bare.colors is None and full.colors is not None
    np.testing.assert_array_equal(bare.points, full.points)
    np.testing.assert_array_equal(bare.uv, full.uv)
    np.testing.assert_array_equal(bare.face_index, full.face_index)


def test_no_uv_gives_none(sphere):
    s = sample_surface(sphere, 10)
    assert s.uv is None and s.colors is None


def test_degenerate_faces_are_never_sampled(sphere):
    v = np.concatenate([sphere.vertices, [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]])
    nv = len(sphere.vertices)
    extra = np.array([[nv, nv, nv + 1], [nv, nv + 1, nv + 1], [0, 0, 0]])  # zero area
    faces = np.concatenate([extra, sphere.faces])
    flagged = np.zeros(len(faces), bool)
    flagged[3:13] = True  # flagged by the loader: excluded even though they have an area
    mesh = Mesh(v, faces, degenerate=flagged)
    s = sample_surface(mesh, 20000, seed=0)
    assert s.face_index.min() >= 13
    assert np.isfinite(s.normals).all() and np.abs(np.linalg.norm(s.normals, axis=1) - 1).max() < 1e-6


def test_a_mesh_without_non_degenerate_faces_is_an_error():
    v = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2.0]])
    mesh = Mesh(v, np.array([[0, 1, 2], [0, 0, 1]]), source="flat.obj")
    with pytest.raises(MeshError, match=r"flat.obj: no non-degenerate faces"):
        sample_surface(mesh, 10)
    with pytest.raises(MeshError, match="no non-degenerate faces"):
        signed_distance(mesh, np.zeros((3, 3)))
    with pytest.raises(MeshError, match="no non-degenerate faces"):
        sample_uniform(mesh, 3)


def test_bad_arguments(sphere):
    with pytest.raises(ValueError, match="n must be a non-negative integer"):
        sample_surface(sphere, -1)
    with pytest.raises(ValueError, match="n must be a non-negative integer"):
        sample_near(sphere, 2.5)
    with pytest.raises(ValueError, match="normals must be 'face' or 'vertex'"):
        sample_surface(sphere, 3, normals="smooth")
    with pytest.raises(ValueError, match="sigma must be positive"):
        sample_near(sphere, 3, sigma=0.0)
    with pytest.raises(ValueError, match="sigma must be positive"):
        sample_near(sphere, 3, sigma=[0.01, -1])
    with pytest.raises(ValueError, match="non-empty sequence"):
        sample_near(sphere, 3, sigma=[])
    with pytest.raises(ValueError, match="bound must be positive"):
        sample_uniform(sphere, 3, bound=0)
    with pytest.raises(ValueError, match="sign must be one of"):
        signed_distance(sphere, np.zeros((1, 3)), sign="parity")
    with pytest.raises(ValueError, match="method must be one of"):
        inside_mask(sphere, np.zeros((1, 3)), method="parity")
    with pytest.raises(ValueError, match=r"points must be \(N, 3\), got shape \(4,\)"):
        signed_distance(sphere, np.zeros(4))
    with pytest.raises(ValueError, match="NaN or infinite"):
        signed_distance(sphere, np.array([[0.0, np.nan, 0.0]]))


def test_zero_samples(sphere):
    assert len(sample_surface(sphere, 0)) == 0
    assert len(sample_near(sphere, 0)) == 0 and len(sample_uniform(sphere, 0)) == 0
    assert signed_distance(sphere, np.zeros((0, 3))).shape == (0,)


# ------------------------------------------------------------------------------------------- determinism


def test_same_seed_same_arrays_other_seed_other_arrays(textured_sphere):
    _, mesh = textured_sphere
    a, b, c = (sample_surface(mesh, 500, seed=s) for s in (7, 7, 8))
    for name in ("points", "normals", "uv", "colors", "face_index"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.points, c.points)
    n1, n2, n3 = (sample_near(mesh, 300, seed=s, sigma=(0.01, 0.05)) for s in (7, 7, 8))
    np.testing.assert_array_equal(n1.points, n2.points)
    np.testing.assert_array_equal(n1.sdf, n2.sdf)
    assert not np.array_equal(n1.points, n3.points)
    u1, u2, u3 = (sample_uniform(mesh, 300, seed=s) for s in (7, 7, 8))
    np.testing.assert_array_equal(u1.points, u2.points)
    np.testing.assert_array_equal(u1.sdf, u2.sdf)
    assert not np.array_equal(u1.points, u3.points)


# ------------------------------------------------------------------------------------------- volume


def test_near_samples_mix_the_sigmas_in_equal_parts(sphere):
    n = 6001
    v = sample_near(sphere, n, sigma=(0.002, 0.05), seed=4)
    assert isinstance(v, VolumeSamples) and v.points.dtype == np.float32 and v.sdf.dtype == np.float32
    base = sample_surface(sphere, n, seed=4).points.astype(np.float64)
    noise = v.points.astype(np.float64) - base
    first, second = noise[:3001], noise[3001:]
    assert abs(first.std() / 0.002 - 1) < 0.06
    assert abs(second.std() / 0.05 - 1) < 0.06
    np.testing.assert_allclose(noise.mean(0), 0, atol=3 * 0.05 / math.sqrt(3000))
    # the signed distance is the mesh's, i.e. the sphere's within the tessellation gap
    np.testing.assert_allclose(v.sdf, np.linalg.norm(v.points, axis=1) - R, atol=_gap(sphere) + 1e-5)


def test_near_samples_gradient_targets_are_the_spheres_radial_direction(sphere, open_sphere):
    # analytic oracle: off a sphere the signed distance's gradient is x/|x|, inside and out; the interpolated
    # normals of the closest points are it within the tessellation's normal error. Beyond the reach, and
    # where the closest point is on the open sphere's rim (the offset leaves the normal), there is none.
    v = sample_near(sphere, 6000, sigma=(0.003, 0.05), seed=2, targets=0.02)
    assert v.normals.dtype == np.float32 and v.normals.shape == (6000, 3)
    has = np.linalg.norm(v.normals, axis=1) > 0
    np.testing.assert_array_equal(has, np.abs(v.sdf) <= 0.02)
    radial = v.points / np.linalg.norm(v.points, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", v.normals[has], radial[has])
    assert cos.min() > math.cos(math.radians(3.0)) and (v.sdf[has] < 0).any() and (v.sdf[has] > 0).any()
    np.testing.assert_allclose(np.linalg.norm(v.normals[has], axis=1), 1.0, atol=1e-5)
    assert sample_near(sphere, 100, seed=2).normals is None  # not asked for: not computed
    # the same points and distances with or without the targets
    plain = sample_near(sphere, 6000, sigma=(0.003, 0.05), seed=2)
    np.testing.assert_array_equal(plain.points, v.points)
    np.testing.assert_array_equal(plain.sdf, v.sdf)
    # over the open sphere's hole the closest points are on its rim, the offset far from the normal there
    from neural_bake.fit.sampling import _closest_points, distance_gradient_targets

    axis = np.stack([np.zeros(8), np.linspace(-0.05, 0.05, 8), np.linspace(0.7, 0.95, 8)], axis=1)
    d = signed_distance(open_sphere, axis)
    assert (distance_gradient_targets(open_sphere, axis, d, _closest_points(open_sphere, axis), 1.0) == 0).all()
    empty = sample_near(sphere, 0, targets=0.01)
    assert empty.normals.shape == (0, 3) and empty.sdf.shape == (0,)


def test_distance_gradient_targets_skip_points_on_the_surface_and_past_a_crease():
    # a unit cube with flat-shaded faces (each its own vertices): off a face the target is the face's normal;
    # off an edge (the offset between the two faces' normals, 45° from each) there is none; a point on the
    # surface (distance 0) has none
    from neural_bake.fit.sampling import _closest_points, distance_gradient_targets

    tri = trimesh.creation.box().triangles.reshape(-1, 3)
    mesh = Mesh(np.asarray(tri, dtype=np.float64), np.arange(len(tri), dtype=np.int64).reshape(-1, 3))
    pts = np.array([[0.0, 0.0, 0.51], [0.1, -0.2, 0.45], [0.55, 0.0, 0.55], [0.0, 0.0, 0.5]])
    sdf = np.array([0.01, -0.05, math.sqrt(2) * 0.05, 0.0])
    out = distance_gradient_targets(mesh, pts, sdf, _closest_points(mesh, pts), reach=1.0)
    np.testing.assert_allclose(out[0], [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(out[1], [0, 0, 1], atol=1e-6)  # inside: still the outward normal
    np.testing.assert_array_equal(out[2:], 0.0)
    assert (distance_gradient_targets(mesh, pts, sdf, _closest_points(mesh, pts), reach=0.005) == 0).all()
    # the cube with shared corners: its interpolated normals lean towards the corners, its faces' do not
    box = trimesh.creation.box()
    shared = Mesh(np.asarray(box.vertices, dtype=np.float64), np.asarray(box.faces, dtype=np.int64))
    closest = _closest_points(shared, pts[:2])
    face = distance_gradient_targets(shared, pts[:2], sdf[:2], closest, reach=1.0, normals="face")
    vertex = distance_gradient_targets(shared, pts[:2], sdf[:2], closest, reach=1.0)
    np.testing.assert_allclose(face, [[0, 0, 1], [0, 0, 1]], atol=1e-6)
    assert vertex[1, 2] < 0.95  # 0.1, -0.2: off the face's centre
    with pytest.raises(ValueError, match="normals must be 'face' or 'vertex'"):
        distance_gradient_targets(shared, pts[:2], sdf[:2], closest, reach=1.0, normals="smooth")


def test_distance_gradient_targets_stay_within_a_share_of_the_gap_across_a_thin_wall():
    # a flat-shaded slab 0.02 thick: inside, the exact gradient turns over at its mid-plane; with a gap share of
    # 0.25 a point keeps its face's normal only within 0.005 of that face. Outside, the gap runs to the other
    # slab 0.1 above (0.025 of it), or to nothing below (no bound).
    from neural_bake.fit.sampling import _closest_points, distance_gradient_targets

    def slab(z0, z1):
        b = trimesh.creation.box(extents=(1.0, 1.0, z1 - z0))
        b.apply_translation((0, 0, (z0 + z1) / 2))
        return b.triangles.reshape(-1, 3)

    tri = np.concatenate([slab(-0.01, 0.01), slab(0.11, 0.13)])
    mesh = Mesh(np.asarray(tri, dtype=np.float64), np.arange(len(tri), dtype=np.int64).reshape(-1, 3))
    z = np.array([0.008, 0.004, 0.002, -0.007, 0.012, 0.04, -0.012, -0.04])
    pts = np.stack([np.full(len(z), 0.05), np.full(len(z), -0.1), z], axis=1)
    sdf = signed_distance(mesh, pts, sign="raycast")
    np.testing.assert_allclose(sdf, [-0.002, -0.006, -0.008, -0.003, 0.002, 0.03, 0.002, 0.03], atol=1e-6)
    closest = _closest_points(mesh, pts)
    every = distance_gradient_targets(mesh, pts, sdf, closest, reach=0.05)
    want = np.array([1, 1, 1, -1, 1, 1, -1, -1])[:, None] * [0.0, 0.0, 1.0]
    np.testing.assert_allclose(every, want, atol=1e-6)  # no gap bound: every point its face's normal
    bounded = distance_gradient_targets(mesh, pts, sdf, closest, reach=0.05, gap_share=0.25)
    keep = np.array([True, False, False, True, True, False, True, True])  # 0.04: 0.03 > 0.25 × 0.1
    np.testing.assert_allclose(bounded, np.where(keep[:, None], want, 0.0), atol=1e-6)
    # the gap rays see the other slab: at a share of one the point 0.03 above keeps its target
    assert distance_gradient_targets(mesh, pts[5:6], sdf[5:6], _closest_points(mesh, pts[5:6]), reach=0.05,
                                     gap_share=1.0)[0, 2] == pytest.approx(1.0)
    for bad in (-0.1, 1.5, math.nan):
        with pytest.raises(ValueError, match="gap_share must be in"):
            distance_gradient_targets(mesh, pts, sdf, closest, reach=0.05, gap_share=bad)
    # sample_near passes it on: the bounded targets are a subset of the unbounded ones at the same points
    a = sample_near(mesh, 3000, sigma=0.01, seed=4, targets=0.05, sign="raycast")
    b = sample_near(mesh, 3000, sigma=0.01, seed=4, targets=0.05, sign="raycast", target_gap_share=0.25)
    has_a, has_b = np.linalg.norm(a.normals, axis=1) > 0, np.linalg.norm(b.normals, axis=1) > 0
    assert (has_b <= has_a).all() and has_b.sum() < has_a.sum() and has_b.sum() > 0.3 * has_a.sum()
    np.testing.assert_array_equal(a.normals[has_b], b.normals[has_b])


def test_uniform_samples_fill_the_cube(sphere):
    v = sample_uniform(sphere, 4000, seed=1, bound=1.5)
    assert np.abs(v.points).max() <= 1.5 and np.abs(v.points).max() > 1.45
    for axis in range(3):
        assert stats.kstest(v.points[:, axis], stats.uniform(-1.5, 3).cdf).pvalue > 1e-3
    np.testing.assert_allclose(v.sdf, np.linalg.norm(v.points, axis=1) - R, atol=_gap(sphere) + 1e-5)


# ------------------------------------------------------------------------------------------- distance


@pytest.mark.parametrize("sign", ["auto", "raycast", "winding", "winding_exact"])
def test_signed_distance_equals_the_distance_to_the_mesh_and_the_sphere(sphere, rng, sign):
    p = rng.uniform(-1.2, 1.2, (300, 3))
    d = signed_distance(sphere, p, sign=sign)
    assert d.dtype == np.float64
    # reference: brute-force point-triangle distance (trimesh), float64
    tri = sphere.triangles
    ref = np.full(len(p), np.inf)
    for i, q in enumerate(p):
        cp = trimesh.triangles.closest_point(tri, np.repeat(q[None], len(tri), 0))
        ref[i] = np.linalg.norm(cp - q, axis=1).min()
    np.testing.assert_allclose(np.abs(d), ref, atol=2e-6)
    analytic = np.linalg.norm(p, axis=1) - R
    clear = np.abs(analytic) > _gap(sphere)
    np.testing.assert_array_equal(np.sign(d[clear]), np.sign(analytic[clear]))
    # the mesh is the inscribed polyhedron: its distance differs from the sphere's by at most the gap
    np.testing.assert_allclose(d, analytic, atol=_gap(sphere) + 1e-6)


def test_signed_distance_to_a_fine_sphere_is_the_analytic_sdf_to_1e4(rng):
    mesh = _icosphere(6)  # 81920 faces: tessellation gap < 1e-4
    gap = _gap(mesh)
    assert gap < 1e-4
    p = rng.uniform(-1, 1, (2000, 3))
    np.testing.assert_allclose(signed_distance(mesh, p), np.linalg.norm(p, axis=1) - R, atol=1e-4)


def test_surface_points_have_zero_distance(sphere):
    s = sample_surface(sphere, 500, seed=9)
    assert np.abs(unsigned_distance(sphere, s.points)).max() < 1e-6


@pytest.mark.parametrize("sign", ["auto", "winding", "winding_exact"])
def test_signs_are_right_on_an_open_mesh(open_sphere, rng, sign):
    p = rng.uniform(-1.3, 1.3, (3000, 3))
    r = np.linalg.norm(p, axis=1)
    d = signed_distance(open_sphere, p, sign=sign)
    assert (d[r < 0.6] < 0).all()
    assert (d[r > 1.0] > 0).all()
    assert (r < 0.6).sum() > 100 and (r > 1.0).sum() > 1000


def test_raycast_is_what_auto_uses_on_closed_meshes(sphere, rng):
    p = rng.uniform(-1, 1, (1000, 3))
    np.testing.assert_array_equal(inside_mask(sphere, p), inside_mask(sphere, p, method="raycast"))
    np.testing.assert_array_equal(inside_mask(sphere, p), inside_mask(sphere, p, method="winding"))


def test_hybrid_sign_on_an_open_mesh_matches_the_winding_number(open_sphere, rng):
    p = np.concatenate([rng.uniform(-1.3, 1.3, (2000, 3)), sample_near(open_sphere, 500, sigma=0.02, seed=1).points])
    hybrid = inside_mask(open_sphere, p, method="hybrid")
    exact = winding_number(open_sphere, p, exact=True) > 0.5
    assert np.mean(hybrid == exact) > 0.995
    votes = S._ray_parities(open_sphere, p, S.HYBRID_RAYS)
    assert (votes.any(0) & ~votes.all(0)).sum() > 10  # the hole is seen: some points needed the winding number
    r = np.linalg.norm(p, axis=1)
    assert (hybrid[r < 0.6]).all() and not hybrid[r > 1.0].any()


def _open_sheet():
    """A flat square sheet 1.2 across in the plane z = 0, its normals +z, subdivided (an open mesh)."""
    sheet = trimesh.creation.box(extents=(1.2, 1.2, 0.1))
    top = sheet.triangles_center[:, 2] > 0.04
    sheet = trimesh.Trimesh(sheet.vertices, sheet.faces[top], process=True).subdivide().subdivide()
    v = np.asarray(sheet.vertices, dtype=np.float64)
    v[:, 2] = 0.0
    return Mesh(v, np.asarray(sheet.faces, dtype=np.int64), watertight=False)


def test_a_sign_is_sure_off_closed_parts_and_not_behind_an_open_sheet(sphere, open_sphere, rng):
    """Behind an open sheet (against its normals) the winding number reads about 1/2: the sign is not sure; in
    front (about −1/2) and far away (about 0) it is; every sign of a watertight mesh (ray parity) is sure, and
    the open sphere's points away from its hole (winding 0 or 1) are sure too."""
    from neural_bake.fit.sampling import signed_distance_sure

    sheet = _open_sheet()
    xy = rng.uniform(-0.3, 0.3, (200, 2))
    behind, front = np.c_[xy, np.full(200, -0.03)], np.c_[xy, np.full(200, 0.03)]
    far = rng.uniform(-1, 1, (200, 3)) * [1, 1, 0.1] + [0, 0, 0.9]
    d, sure = signed_distance_sure(sheet, np.concatenate([behind, front, far]))
    np.testing.assert_allclose(np.abs(d), np.abs(signed_distance(sheet, np.concatenate([behind, front, far]))))
    assert not sure[:200].any() and sure[200:].all()
    d, sure = signed_distance_sure(sphere, rng.uniform(-1, 1, (500, 3)))
    assert sure.all()
    p = rng.uniform(-1.3, 1.3, (2000, 3))
    r = np.linalg.norm(p, axis=1)
    _, sure = signed_distance_sure(open_sphere, p)
    away = (p[:, 2] < 0.3) & ((r < 0.6) | (r > 1.0))
    assert sure[away].all() and away.sum() > 500
    _, sure = signed_distance_sure(sheet, np.zeros((0, 3)))
    assert sure.shape == (0,)
    assert sample_uniform(sheet, 300, seed=0).sure.shape == (300,)


def test_sign_mining_leaves_out_the_points_whose_sign_is_not_sure():
    """A network positive everywhere is wrong at every inside point of the pool; the points whose sign is not
    sure are not among its mined sign errors (the near points never are)."""
    import torch

    from neural_bake.fit.sdf_pools import _sign_errors

    vol_d = torch.tensor([-0.5, -0.5, -0.5, -0.5, 0.5, -0.5])
    pools = {"n_near": 1, "vol_p": torch.zeros(6, 3), "vol_d": vol_d,
             "vol_sure": torch.tensor([True, True, False, True, True, False])}
    positive = lambda p: torch.ones(p.shape[0], 1)  # noqa: E731
    assert _sign_errors(positive, pools).tolist() == [1, 3]
    del pools["vol_sure"]
    assert _sign_errors(positive, pools).tolist() == [1, 2, 3, 5]


def test_ray_parities_are_exact_on_a_closed_mesh(sphere, rng):
    p = rng.uniform(-1, 1, (500, 3))
    p = p[np.abs(np.linalg.norm(p, axis=1) - R) > 0.02]
    votes = S._ray_parities(sphere, p, 5)
    expect = np.linalg.norm(p, axis=1) < R
    assert (votes == expect[None]).all()


def test_bench_sampling_runs_shrunken():
    from neural_bake.bench.sampling import run

    res = run(quick=True, n=100, n_sign=40)
    assert res["name"] == "sampling" and set(res["tables"]) == {"throughput", "sign"}
    sign = res["tables"]["sign"]
    ref = [r for r in sign if r["method"].startswith("exact")]
    assert ref and all(r["sign agreement"] == 1.0 for r in ref)
    for r in sign:
        if r["method"].startswith("ours winding") or r["method"].startswith("ours auto"):
            assert r["sign agreement"] == 1.0, r
    assert all(r["samples/s"] > 0 for r in res["tables"]["throughput"])
