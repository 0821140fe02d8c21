"""Orthographic ray-cast views of a mesh (open3d): where each pixel's ray first hits it, for measures that
compare what a viewer sees (the texture fit's render error)."""

from __future__ import annotations

import numpy as np

from ..geometry import import_open3d, raycasting_scene
from ..types import Mesh

__all__ = ["render_views"]


def render_views(mesh: Mesh, n_views: int = 6, resolution: int = 128) -> list[dict]:
    """Ray-cast the ground-truth mesh (unit frame) from ``n_views`` orthographic views around it.

    Views look at the origin from directions spread on a sphere (Fibonacci lattice); each image covers
    [-1, 1]² of the view plane. Returns one dict per view: ``direction`` (3,), ``points`` (M, 3) hit points,
    ``face_index`` (M,), ``bary`` (M, 3) barycentrics, ``pixels`` (M,) flat pixel indices of the hits, and
    ``resolution``. Uses open3d's ``RaycastingScene``.
    """
    o3d = import_open3d()

    scene = raycasting_scene(mesh.vertices, mesh.faces)
    views = []
    k = np.arange(n_views) + 0.5
    z = 1 - 2 * k / n_views
    phi = np.pi * (1 + 5 ** 0.5) * k
    dirs = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], axis=1)
    s = (np.arange(resolution) + 0.5) / resolution * 2 - 1
    for d in dirs:
        d = d / np.linalg.norm(d)
        up = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        right = np.cross(up, d)
        right /= np.linalg.norm(right)
        up = np.cross(d, right)
        yy, xx = np.meshgrid(-s, s, indexing="ij")
        origins = 2.0 * d + xx[..., None] * right + yy[..., None] * up
        rays = np.concatenate([origins, np.broadcast_to(-d, origins.shape)], axis=-1).reshape(-1, 6)
        ans = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
        t = ans["t_hit"].numpy()
        hit = np.isfinite(t)
        fid = ans["primitive_ids"].numpy()[hit].astype(np.int64)
        uv = ans["primitive_uvs"].numpy()[hit].astype(np.float64)
        bary = np.stack([1 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1)
        pts = np.einsum("mk,mkj->mj", bary, mesh.vertices[mesh.faces[fid]])
        views.append({"direction": d, "points": pts, "face_index": fid, "bary": bary,
                      "pixels": np.flatnonzero(hit), "resolution": resolution})
    return views
