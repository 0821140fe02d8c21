"""USD and USDZ export of a baked asset: the coarse mesh, its UVs and normals and the baked maps, through
:mod:`neural_bake.io.usd` (Pixar's usd-core, the optional extra ``usd``).

What goes in: points in the SOURCE frame, ``primvars:st`` per vertex (the mesh split at UV seams, v = 0 at
the image's bottom, as USD reads images), vertex normals, and a ``UsdPreviewSurface`` whose base colour and
tangent-space normal map (OpenGL, +Y green up) are the baked PNG files. USD has no standard tangent
attribute: a renderer rebuilds the tangent frame from ``st`` and the normals (MikkTSpace-like), which is how
the baker's per-vertex tangents are made too. The stage states metres per unit and the up axis
(:data:`SOURCE_METERS_PER_UNIT`, :data:`SOURCE_UP_AXIS`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..constants import DIRECTION_EPS
from ..errors import MeshError
from ..types import Mesh

__all__ = ["export_usd", "usd_frame", "SOURCE_METERS_PER_UNIT", "SOURCE_UP_AXIS"]

#: Metres per source unit written into a stage. A mesh file states no unit and the toolkit keeps none, so the
#: source frame is taken as glTF's (the GLB beside it): metres.
SOURCE_METERS_PER_UNIT = 1.0
#: Up axis written into a stage: +Y, glTF's (source meshes are not rotated on load).
SOURCE_UP_AXIS = "Y"


def _unit_normals(mesh: Mesh, normals) -> np.ndarray:
    from ..geometry import vertex_normals

    nrm = vertex_normals(mesh) if normals is None else np.asarray(normals, dtype=np.float64)
    return nrm / np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), DIRECTION_EPS)


def export_usd(path, mesh: Mesh, *, base_colour=None, normal_map=None, normals: np.ndarray | None = None) -> Path:
    """Write ``mesh`` with its baked maps as a USD stage (``.usd``/``.usda``/``.usdc``) or USDZ package at
    ``path`` (atomically); return the path.

    - ``mesh``: unit-frame mesh (``Baker.mesh``: split at UV seams when it has UVs); written in the source frame.
    - ``base_colour``: path of the baked base-colour PNG (sRGB-encoded), or None.
    - ``normal_map``: path of the baked tangent-space normal map PNG (OpenGL, +Y up, linear data), or None.
    - ``normals``: (V, 3) vertex normals; default the mesh's.

    Raises :class:`~neural_bake.errors.MissingExtraError` without usd-core, :class:`MeshError` for maps on a
    mesh without UVs, :class:`~neural_bake.errors.NeuralBakeError` from :func:`neural_bake.io.usd.write_usd`.
    """
    from ..io.usd import StageOptions, write_usd
    from ..mesh.tangents import vertex_uv

    if (base_colour is not None or normal_map is not None) and mesh.uv is None:
        raise MeshError(f"{mesh.name}: export_usd: texture maps need a mesh with UVs")
    uv = vertex_uv(mesh) if mesh.uv is not None else None
    return write_usd(path, mesh.frame.to_source(mesh.vertices), mesh.faces, uv=uv, normals=_unit_normals(mesh, normals),
                     base_colour=base_colour, normal_map=normal_map,
                     options=StageOptions(meters_per_unit=SOURCE_METERS_PER_UNIT, up_axis=SOURCE_UP_AXIS))


def usd_frame(mesh: Mesh, normals: np.ndarray | None = None, colours: np.ndarray | None = None) -> dict:
    """One frame of :func:`neural_bake.io.usd.write_usd_frames`: ``mesh`` (unit frame) in the source frame,
    its unit ``normals`` (default the mesh's) and linear ``colours`` (V, 3|4) or None."""
    return {"points": mesh.frame.to_source(mesh.vertices), "faces": mesh.faces,
            "normals": _unit_normals(mesh, normals), "colours": None if colours is None else np.asarray(colours)[:, :3]}
