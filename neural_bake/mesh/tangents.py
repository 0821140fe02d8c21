"""Per-vertex tangent frames for tangent-space normal maps (glTF / MikkTSpace-style)."""

from __future__ import annotations

import numpy as np

from ..constants import TANGENT_EPS, UV_DET_EPS, UV_MATCH_TOL
from ..errors import MeshError
from ..geometry import vertex_normals  # re-exported: the mesh layer's name for it
from ..types import Mesh

__all__ = ["tangent_frames", "vertex_normals", "vertex_uv"]


def vertex_uv(mesh: Mesh, *, atol: float = UV_MATCH_TOL) -> np.ndarray:
    """(V, 2) float64 per-vertex UVs of a mesh whose vertices are split at UV seams.

    Raises :class:`MeshError` if the mesh has no UVs or if two corners of one vertex carry different UVs
    (unsplit seams: call :func:`neural_bake.mesh.unwrap.split_uv_seams` or :func:`unwrap` first).
    Vertices that no face uses get (0, 0).
    """
    if mesh.uv is None:
        raise MeshError(f"{mesh.name}: mesh has no UVs (unwrap it first)")
    uv = np.asarray(mesh.uv, dtype=np.float64).reshape(-1, 2)
    idx = mesh.faces.reshape(-1)
    out = np.zeros((mesh.n_vertices, 2))
    out[idx] = uv  # last corner wins; check all agree below
    bad = np.abs(out[idx] - uv).max(axis=1) > atol
    if bad.any():
        v = int(idx[np.argmax(bad)])
        raise MeshError(
            f"{mesh.name}: vertex {v} has different UVs on its corners ({int(bad.sum())} corners disagree);"
            " split vertices at UV seams first"
        )
    return out


def _orthonormal_fallback(n: np.ndarray) -> np.ndarray:
    """(K, 3) unit vectors orthogonal to unit normals ``n`` (K, 3): the world axis least aligned with n,
    projected onto the tangent plane."""
    axis = np.zeros_like(n)
    axis[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0
    t = axis - n * np.sum(axis * n, axis=1, keepdims=True)
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def tangent_frames(mesh: Mesh) -> np.ndarray:
    """(V, 4) float64 per-vertex tangents: xyz unit and orthogonal to the vertex normal, w = ±1 handedness.

    The glTF TANGENT attribute: a renderer rebuilds the basis as ``n`` (vertex normal), ``t = xyz``,
    ``b = w · cross(n, t)`` (right-handed TBN, OpenGL +Y: ``b`` points towards increasing v, v up).
    ``t`` points towards increasing u.

    Accumulation as MikkTSpace: each face's UV-derivative tangent dP/du and bitangent dP/dv are normalised
    and added to its three corners weighted by the corner angle; per vertex the tangent is Gram-Schmidt
    orthogonalised against the normal and ``w = sign(<cross(n, t), Σ dP/dv>)`` (+1 when undetermined).
    Faces with degenerate UVs add nothing; a vertex left without a usable tangent gets a fallback unit
    vector orthogonal to its normal, so the output is never NaN.

    ``mesh`` must have per-vertex UVs (vertices split at seams, see :func:`vertex_uv`); the normals are
    :func:`vertex_normals`.
    """
    uvv = vertex_uv(mesh)
    n = vertex_normals(mesh)
    f = mesh.faces
    p = mesh.vertices[f]  # (F, 3, 3)
    uv = uvv[f]  # (F, 3, 2)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > UV_DET_EPS
    inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
    ft = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv[:, None]  # dP/du
    fb = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv[:, None]  # dP/dv

    def unit(x):
        nrm = np.linalg.norm(x, axis=1, keepdims=True)
        return np.divide(x, nrm, out=np.zeros_like(x), where=nrm > 0)

    ft, fb = unit(ft), unit(fb)
    acc_t = np.zeros((mesh.n_vertices, 3))
    acc_b = np.zeros((mesh.n_vertices, 3))
    for k in range(3):
        a = unit(p[:, (k + 1) % 3] - p[:, k])
        b = unit(p[:, (k + 2) % 3] - p[:, k])
        ang = np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0))[:, None]
        np.add.at(acc_t, f[:, k], ft * ang)
        np.add.at(acc_b, f[:, k], fb * ang)
    t = acc_t - n * np.sum(acc_t * n, axis=1, keepdims=True)
    tn = np.linalg.norm(t, axis=1)
    good = tn > TANGENT_EPS
    t[good] /= tn[good, None]
    if (~good).any():
        # no usable dP/du: try the direction orthogonal to the accumulated bitangent, then any axis
        alt = np.cross(acc_b[~good], n[~good])
        an = np.linalg.norm(alt, axis=1)
        fb_ok = an > TANGENT_EPS
        alt[fb_ok] /= an[fb_ok, None]
        alt[~fb_ok] = _orthonormal_fallback(n[~good][~fb_ok])
        t[~good] = alt
    s = np.sum(np.cross(n, t) * acc_b, axis=1)
    w = np.where(s < 0, -1.0, 1.0)
    return np.concatenate([t, w[:, None]], axis=1)
