"""What a glTF/GLB asset carries beside its geometry: its own vertex normals (hard edges, splits) and its
material's maps (normal, metallic-roughness, occlusion), so a bake onto the asset itself keeps them.

:func:`read_asset` reads them for a mesh :func:`~neural_bake.io.mesh_io.load_mesh` loaded from the same file
(same faces, same order); :func:`shading_mesh` splits that mesh's vertices wherever the file's normals differ,
so a renderer shades it exactly as the asset was shaded.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..constants import CORNER_NORMAL_MATCH_TOL, DIRECTION_EPS, FACE_MATCH_REL_TOL, MIN_SPAN
from ..errors import MeshError
from ..types import Mesh

__all__ = ["Asset", "file_corner_normals", "read_asset", "shading_mesh", "MATERIAL_MAPS"]

#: The material maps :func:`read_asset` keeps: glTF material slot -> name in :attr:`Asset.maps`.
MATERIAL_MAPS = {"normalTexture": "normal", "metallicRoughnessTexture": "metallic_roughness",
                 "occlusionTexture": "occlusion"}


@dataclass
class Asset:
    """The asset's own shading data, face-aligned with the :class:`Mesh` loaded from the same file.

    - ``corner_normals``: (F, 3, 3) float64 unit normals per face corner as the file gives them (node
      transforms applied), or None when the file has none (OBJ, PLY, or a glTF without NORMAL).
    - ``maps``: material maps by name ("normal", "metallic_roughness", "occlusion"): (H, W, C) float32 in
      [0, 1], the file's values as data (no colour decoding), row 0 the image's top row.
    - ``same_image``: names of maps that are one image in the file (e.g. occlusion packed with
      metallic-roughness in an ORM texture), as pairs.
    - ``factors``: the material's ``metallicFactor`` and ``roughnessFactor`` (glTF's default 1.0 when unset).
    """

    corner_normals: np.ndarray | None = None
    maps: dict[str, np.ndarray] = field(default_factory=dict)
    same_image: list[tuple[str, str]] = field(default_factory=list)
    factors: dict[str, float] = field(default_factory=dict)


def _image_data(img) -> np.ndarray:
    a = np.asarray(img.convert("RGBA") if img.mode not in ("RGB", "RGBA") else img)
    scale = 65535.0 if a.dtype == np.uint16 else 255.0
    return np.ascontiguousarray(a[..., :3] if a.shape[-1] == 4 else a, dtype=np.float32) / np.float32(scale)


def _placed(loaded) -> list[tuple]:
    """(geometry as the file stores it, (4, 4) node transform) of each triangle geometry with faces of a
    ``trimesh.load`` result, in the order of Scene.dump."""
    import trimesh

    if isinstance(loaded, trimesh.Scene):
        placed = [(loaded.geometry[name], np.asarray(t, dtype=np.float64))
                  for t, name in (loaded.graph[node] for node in loaded.graph.nodes_geometry)]
    else:
        placed = [(loaded, np.eye(4))]
    return [(g, t) for g, t in placed if isinstance(g, trimesh.Trimesh) and len(g.faces)]


def file_corner_normals(loaded, mesh: Mesh, path) -> np.ndarray | None:
    """(F, 3, 3) float64 unit normals per corner of ``mesh``'s faces, as the glTF/GLB file ``path`` gives them
    (node transforms applied, inverse transpose), from ``loaded`` (that file read by ``trimesh.load`` with
    ``process=False``; the order of Scene.dump, which :func:`~neural_bake.io.mesh_io.load_mesh` uses); None
    when a geometry of the file has no NORMAL attribute. The file's faces are matched to ``mesh.faces`` face by
    face (``load_mesh`` keeps the face order and may reverse every face's winding; both are handled).
    Raises :class:`MeshError` naming the file when its faces do not match ``mesh``."""
    corners, positions = [], []
    for g, t in _placed(loaded):
        if "vertex_normals" not in g._cache.cache:  # the file's NORMAL attribute (trimesh computes none on load)
            return None
        f = np.asarray(g.faces, dtype=np.int64)
        v = np.asarray(g.vertices, dtype=np.float64)
        positions.append((v @ t[:3, :3].T + t[:3, 3])[f])
        corners.append((np.asarray(g.vertex_normals, dtype=np.float64) @ np.linalg.inv(t[:3, :3]))[f])
    if not corners:
        return None
    normals = np.concatenate(corners)
    pos = np.concatenate(positions)
    if len(pos) != mesh.n_faces:
        raise MeshError(f"{path}: {len(pos)} faces in the file against {mesh.n_faces} loaded; not the same mesh")
    ours = mesh.frame.to_source(mesh.vertices[mesh.faces])
    scale = max(float(np.ptp(pos.reshape(-1, 3), axis=0).max()), MIN_SPAN)
    same = np.abs(ours - pos).max(axis=(1, 2)) <= FACE_MATCH_REL_TOL * scale
    flipped = np.abs(ours - pos[:, ::-1]).max(axis=(1, 2)) <= FACE_MATCH_REL_TOL * scale
    if not (same | flipped).all():
        raise MeshError(f"{path}: the file's faces do not match the loaded mesh's")
    normals = np.where(same[:, None, None], normals, normals[:, ::-1])
    norm = np.linalg.norm(normals, axis=2, keepdims=True)
    return np.divide(normals, norm, out=np.zeros_like(normals), where=norm > DIRECTION_EPS)


def read_asset(path: str | os.PathLike, mesh: Mesh) -> Asset:
    """The vertex normals (:func:`file_corner_normals`) and material maps of the glTF/GLB file ``path`` that
    ``mesh`` was loaded from.

    Other formats give an empty :class:`Asset`. Raises :class:`MeshError` naming the file when its faces do not
    match ``mesh``.
    """
    p = Path(path)
    if p.suffix.lower() not in (".glb", ".gltf"):
        return Asset()
    import trimesh

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loaded = trimesh.load(str(p), file_type=p.suffix.lower()[1:], process=False)
    asset = Asset(corner_normals=file_corner_normals(loaded, mesh, path))
    geoms = [g for g, _ in _placed(loaded)]
    images: dict[int, str] = {}
    for g in geoms:
        mat = getattr(g.visual, "material", None)
        for slot, name in MATERIAL_MAPS.items():
            img = getattr(mat, slot, None) if mat is not None else None
            if img is None or name in asset.maps:
                continue
            asset.maps[name] = _image_data(img)
            if id(img) in images:
                asset.same_image.append((images[id(img)], name))
            images[id(img)] = name
        if mat is not None and not asset.factors:
            for k in ("metallicFactor", "roughnessFactor"):
                v = getattr(mat, k, None)
                asset.factors[k] = 1.0 if v is None else float(v)
    return asset


def shading_mesh(mesh: Mesh, corner_normals: np.ndarray, *, atol: float = CORNER_NORMAL_MATCH_TOL) -> Mesh:
    """``mesh`` with its vertices split wherever ``corner_normals`` (F, 3, 3) differ (hard edges), and those
    normals as its vertex normals: (V', 3) float64 unit. UVs, texture, frame and faces' order are kept; the
    result is not watertight where it was split. Corners whose normals agree within ``atol`` share a vertex.
    """
    cn = np.asarray(corner_normals, dtype=np.float64)
    if cn.shape != (mesh.n_faces, 3, 3):
        raise MeshError(f"{mesh.name}: corner normals must be ({mesh.n_faces}, 3, 3), got {cn.shape}")
    vid = mesh.faces.reshape(-1)
    keys = np.concatenate([vid[:, None].astype(np.float64), np.round(cn.reshape(-1, 3) / atol)], axis=1)
    _, first, inv = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    vmap = vid[first]
    normals = cn.reshape(-1, 3)[first]
    return Mesh(
        vertices=mesh.vertices[vmap].copy(),
        faces=inv.reshape(-1, 3).astype(np.int64),
        uv=None if mesh.uv is None else mesh.uv.copy(),
        texture=mesh.texture,
        vertex_normals=normals,
        frame=mesh.frame,
        degenerate=None if mesh.degenerate is None else mesh.degenerate.copy(),
        uv_policy=mesh.uv_policy,
        watertight=mesh.watertight and len(first) == len(np.unique(vid)),
        source=mesh.source,
        warnings=list(mesh.warnings),
    )
