"""Tangent frames: analytic planes and surfaces, handedness, degenerate UVs, slow reference."""

import numpy as np
import pytest
import trimesh

from neural_bake.errors import MeshError
from neural_bake.mesh.tangents import tangent_frames, vertex_normals, vertex_uv
from neural_bake.types import Mesh


def grid(n=6, z=None, uvf=None):
    """(n+1)² grid over [-1, 1]², CCW seen from +z; z(x, y) height; uvf(x, y) -> (u, v) per vertex."""
    xs = np.linspace(-1, 1, n + 1)
    x, y = np.meshgrid(xs, xs, indexing="xy")
    x, y = x.ravel(), y.ravel()
    zz = np.zeros_like(x) if z is None else z(x, y)
    v = np.stack([x, y, zz], axis=1)
    faces = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            faces += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    faces = np.array(faces, dtype=np.int64)
    uv = np.stack(uvf(x, y), axis=1) if uvf else np.stack([(x + 1) / 2, (y + 1) / 2], axis=1)
    return Mesh(vertices=v, faces=faces, uv=uv[faces])


def test_plane_uv_xy_gives_plus_x_and_w_plus_one():
    t = tangent_frames(grid())
    assert t.shape == (49, 4) and t.dtype == np.float64
    np.testing.assert_allclose(t[:, :3], np.tile([1.0, 0, 0], (49, 1)), atol=1e-12)
    np.testing.assert_array_equal(t[:, 3], 1.0)


def test_flipping_u_flips_handedness_and_tangent():
    m = grid(uvf=lambda x, y: ((1 - x) / 2, (y + 1) / 2))
    t = tangent_frames(m)
    np.testing.assert_allclose(t[:, :3], np.tile([-1.0, 0, 0], (49, 1)), atol=1e-12)
    np.testing.assert_array_equal(t[:, 3], -1.0)
    # the bitangent a renderer rebuilds still points along +y (increasing v)
    n = vertex_normals(m)
    b = t[:, 3:] * np.cross(n, t[:, :3])
    np.testing.assert_allclose(b, np.tile([0, 1.0, 0], (49, 1)), atol=1e-12)


def test_rotated_uv_gives_rotated_tangent():
    # u along +y, v along -x: tangent +y, bitangent = cross(z, y) = -x -> w = +1
    m = grid(uvf=lambda x, y: ((y + 1) / 2, (1 - x) / 2))
    t = tangent_frames(m)
    np.testing.assert_allclose(t[:, :3], np.tile([0, 1.0, 0], (49, 1)), atol=1e-12)
    np.testing.assert_array_equal(t[:, 3], 1.0)


def test_curved_patch_matches_analytic_dp_du():
    # z = 0.3 (x² + y²), uv = xy: dP/du ∝ (1, 0, 0.6 x), projected on the tangent plane
    m = grid(n=40, z=lambda x, y: 0.3 * (x**2 + y**2))
    t = tangent_frames(m)
    n = vertex_normals(m)
    x = m.vertices[:, 0]
    dpdu = np.stack([np.ones_like(x), np.zeros_like(x), 0.6 * x], axis=1)
    dpdu -= n * np.sum(dpdu * n, axis=1, keepdims=True)
    dpdu /= np.linalg.norm(dpdu, axis=1, keepdims=True)
    ang = np.degrees(np.arccos(np.clip(np.sum(t[:, :3] * dpdu, axis=1), -1, 1)))
    assert ang.max() < 0.5
    np.testing.assert_array_equal(t[:, 3], 1.0)


def test_unit_orthogonal_on_a_sphere_with_seams():
    s = trimesh.creation.uv_sphere(radius=0.8, count=[16, 16])
    p = s.vertices / 0.8  # longitude / latitude layout, with a seam
    uv = np.stack([(np.arctan2(p[:, 1], p[:, 0]) / (2 * np.pi)) % 1.0, np.arccos(np.clip(-p[:, 2], -1, 1)) / np.pi], 1)
    m = Mesh(vertices=s.vertices, faces=s.faces.astype(np.int64), uv=uv[s.faces])
    from neural_bake.mesh.unwrap import split_uv_seams

    split, _ = split_uv_seams(m)
    t = tangent_frames(split)
    n = vertex_normals(split)
    assert np.isfinite(t).all()
    np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0, atol=1e-12)
    assert np.abs(np.sum(t[:, :3] * n, axis=1)).max() < 1e-12
    assert set(np.unique(t[:, 3])) <= {-1.0, 1.0}


def _slow_reference(mesh):
    """Per-face loop version of the same accumulation (MikkTSpace-like, angle weights)."""
    uvv = vertex_uv(mesh)
    n = vertex_normals(mesh)
    acc_t = np.zeros((mesh.n_vertices, 3))
    acc_b = np.zeros((mesh.n_vertices, 3))
    for f in mesh.faces:
        p = mesh.vertices[f]
        uv = uvv[f]
        e1, e2 = p[1] - p[0], p[2] - p[0]
        (du1, dv1), (du2, dv2) = uv[1] - uv[0], uv[2] - uv[0]
        det = du1 * dv2 - du2 * dv1
        if abs(det) <= 1e-14:
            continue
        tt = (e1 * dv2 - e2 * dv1) / det
        bb = (e2 * du1 - e1 * du2) / det
        tt /= np.linalg.norm(tt)
        bb /= np.linalg.norm(bb)
        for k in range(3):
            a = p[(k + 1) % 3] - p[k]
            b = p[(k + 2) % 3] - p[k]
            ang = np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))
            acc_t[f[k]] += ang * tt
            acc_b[f[k]] += ang * bb
    out = np.zeros((mesh.n_vertices, 4))
    for i in range(mesh.n_vertices):
        t = acc_t[i] - n[i] * (n[i] @ acc_t[i])
        t /= np.linalg.norm(t)
        out[i, :3] = t
        out[i, 3] = -1.0 if np.cross(n[i], t) @ acc_b[i] < 0 else 1.0
    return out


def test_matches_slow_reference_on_random_uvs(rng):
    m = grid(n=5, z=lambda x, y: 0.2 * np.sin(3 * x) * y)
    uvv = rng.uniform(0, 1, size=(m.n_vertices, 2))
    m.uv = uvv[m.faces]
    np.testing.assert_allclose(tangent_frames(m), _slow_reference(m), atol=1e-12)


def test_degenerate_uvs_give_finite_fallback():
    m = grid(n=3)
    m.uv = np.full_like(m.uv, 0.5)  # every face collapses to one UV point
    t = tangent_frames(m)
    n = vertex_normals(m)
    assert np.isfinite(t).all()
    np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0)
    assert np.abs(np.sum(t[:, :3] * n, axis=1)).max() < 1e-12


def test_degenerate_face_gives_finite_output():
    m = grid(n=2)
    m.vertices = m.vertices.copy()
    m.faces = np.concatenate([m.faces, [[0, 0, 1]]])
    m.uv = np.concatenate([m.uv, m.uv[:1]])
    m.uv[-1] = [m.uv[0][0], m.uv[0][0], m.uv[0][1]]
    t = tangent_frames(m)
    assert np.isfinite(t).all()


def test_unsplit_uvs_raise():
    m = grid(n=2)
    m.uv = m.uv.copy()
    m.uv[0, 0] += 0.1  # vertex 0 now has two different UVs
    with pytest.raises(MeshError, match="vertex 0 has different UVs"):
        tangent_frames(m)


def test_no_uvs_raise():
    m = grid(n=2)
    m.uv = None
    with pytest.raises(MeshError, match="no UVs"):
        tangent_frames(m)


def test_vertex_normals_fallback_for_unused_vertex():
    m = grid(n=1)
    m.vertices = np.concatenate([m.vertices, [[5.0, 5.0, 5.0]]])
    n = vertex_normals(m)
    np.testing.assert_allclose(n[:4], np.tile([0, 0, 1.0], (4, 1)))
    np.testing.assert_allclose(n[4], [0, 0, 1.0])
