"""UV unwrap with xatlas; splitting vertices at UV seams (one UV per vertex, as glTF needs)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..constants import UNWRAP_PACK_SIDE
from ..errors import MeshError, NeuralBakeError
from ..types import Mesh
from ..geometry import vertex_normals
from .tangents import vertex_uv

__all__ = ["UnwrapConfig", "unwrap", "unwrap_with_mapping", "split_uv_seams", "vertex_uv"]


@dataclass
class UnwrapConfig:
    """xatlas options (ChartOptions and PackOptions); ``None`` keeps xatlas' default."""

    resolution: int = 1024
    """Texel resolution the charts are packed for (the atlas is resolution × resolution). Above
    :data:`~neural_bake.constants.UNWRAP_PACK_SIDE` they are packed on that grid with the padding scaled to it
    (rounded up), which keeps the gaps in texels of the map and takes a fraction of the time."""
    padding: int = 4
    """Texels left between charts, so padding/dilation and mip-maps do not bleed across charts."""
    max_chart_area: float | None = None
    """Largest chart area (mesh units²); 0 or None: unlimited."""
    max_boundary_length: float | None = None
    """Longest chart boundary (mesh units); 0 or None: unlimited."""
    normal_deviation_weight: float | None = None
    """Chart growing cost: angle between face and average chart normal."""
    roundness_weight: float | None = None
    """Chart growing cost: chart roundness."""
    straightness_weight: float | None = None
    """Chart growing cost: straight chart boundaries."""
    normal_seam_weight: float | None = None
    """Chart growing cost: prefer seams along hard normal edges (> 1000 forbids crossing them)."""
    texture_seam_weight: float | None = None
    """Chart growing cost: prefer seams along existing texture seams."""
    max_cost: float | None = None
    """Chart growing stops above this cost (lower: more, smaller, flatter charts)."""
    max_iterations: int | None = None
    """Chart optimisation iterations (more: better charts, slower)."""
    bilinear: bool = True
    """Leave a texel around each chart for bilinear filtering."""
    block_align: bool = False
    """Align charts to 4×4 blocks (texture compression)."""
    brute_force: bool = False
    """Slower, tighter packing."""
    rotate_charts: bool = True
    """Allow chart rotation while packing."""


_CHART_FIELDS = (
    "max_chart_area",
    "max_boundary_length",
    "normal_deviation_weight",
    "roundness_weight",
    "straightness_weight",
    "normal_seam_weight",
    "texture_seam_weight",
    "max_cost",
    "max_iterations",
)


def _options(cfg: UnwrapConfig):
    import xatlas

    co = xatlas.ChartOptions()
    for name in _CHART_FIELDS:
        v = getattr(cfg, name)
        if v is not None:
            setattr(co, name, type(getattr(co, name))(v))
    po = xatlas.PackOptions()
    # a map wider than UNWRAP_PACK_SIDE is packed on that grid, its padding scaled (rounded up), and scaled up
    po.resolution = min(int(cfg.resolution), UNWRAP_PACK_SIDE)
    po.padding = -(-int(cfg.padding) * po.resolution // int(cfg.resolution))
    po.bilinear = bool(cfg.bilinear)
    po.blockAlign = bool(cfg.block_align)
    po.bruteForce = bool(cfg.brute_force)
    po.rotate_charts = bool(cfg.rotate_charts)
    return co, po


def unwrap_with_mapping(mesh: Mesh, config: UnwrapConfig | None = None, **options) -> tuple[Mesh, np.ndarray]:
    """Unwrap ``mesh`` with xatlas; returns (split mesh, (V',) int64 index of each new vertex's source vertex).

    The new mesh has the same faces in the same order and winding (indices into the split vertices),
    vertices duplicated at chart seams so that every corner's UV equals its vertex's UV, ``uv`` (F, 3, 2)
    in [0, 1] with v = 0 at the bottom (glTF after the image flip), vertex normals copied from the
    source vertices (so seams do not show in shading), and the same ``frame``. Existing UVs and texture
    are replaced (the texture no longer matches) and dropped.

    ``config`` or keyword ``options``: the fields of :class:`UnwrapConfig` (resolution, padding, chart
    options). Raises :class:`NeuralBakeError` for an unknown option or a non-positive resolution.
    """
    if config is None:
        config = UnwrapConfig()
    names = {f.name for f in dataclasses.fields(UnwrapConfig)}
    for k in options:
        if k not in names:
            raise NeuralBakeError(f"unwrap: unknown option {k!r} (known: {', '.join(sorted(names))})")
    config = dataclasses.replace(config, **options)
    if int(config.resolution) < 8:
        raise NeuralBakeError(f"unwrap: resolution must be at least 8 texels, got {config.resolution!r}")
    if int(config.padding) < 0:
        raise NeuralBakeError(f"unwrap: padding must be >= 0, got {config.padding!r}")
    if mesh.n_faces == 0:
        raise MeshError(f"{mesh.name}: mesh has no faces to unwrap")
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(
        np.ascontiguousarray(mesh.vertices, dtype=np.float32),
        np.ascontiguousarray(mesh.faces, dtype=np.uint32),
        np.ascontiguousarray(vertex_normals(mesh), dtype=np.float32),
    )
    co, po = _options(config)
    atlas.generate(co, po)
    vmap, indices, uvs = atlas[0]
    vmap = np.asarray(vmap, dtype=np.int64)
    faces = np.asarray(indices, dtype=np.int64)
    uvs = np.clip(np.asarray(uvs, dtype=np.float64), 0.0, 1.0)
    if faces.shape != mesh.faces.shape or not np.array_equal(vmap[faces], mesh.faces):
        raise MeshError(f"{mesh.name}: xatlas changed the face list; cannot keep the face order")
    normals = vertex_normals(mesh)[vmap]
    out = Mesh(
        vertices=mesh.vertices[vmap].copy(),
        faces=faces,
        uv=uvs[faces],
        texture=None,
        vertex_normals=normals,
        frame=mesh.frame,
        degenerate=None if mesh.degenerate is None else mesh.degenerate.copy(),
        uv_policy="clamp",
        watertight=False,
        source=mesh.source,
        warnings=list(mesh.warnings),
    )
    return out, vmap


def unwrap(mesh: Mesh, config: UnwrapConfig | None = None, **options) -> Mesh:
    """:func:`unwrap_with_mapping` without the mapping; see there. The mapping is also kept on the result
    as ``result.source_vertex`` ((V',) int64)."""
    out, vmap = unwrap_with_mapping(mesh, config, **options)
    out.source_vertex = vmap  # type: ignore[attr-defined]  # plain attribute: the dataclass has no field for it
    return out


def split_uv_seams(mesh: Mesh, *, atol: float = 0.0, by_handedness: bool = True) -> tuple[Mesh, np.ndarray]:
    """Split vertices whose corners carry different UVs: returns (mesh, (V',) int64 source vertex index).

    Corners of one vertex whose UVs agree (exactly, or within ``atol``) share a new vertex.
    ``by_handedness``: corners whose faces have opposite UV orientation (mirrored UVs meeting along a
    mirror line with equal UVs) are split too, as MikkTSpace does, so each vertex has one tangent
    handedness. Faces keep
    their order and winding; vertex normals are copied from the source vertices. A mesh already split
    comes back with the identity mapping (vertices not used by any face are dropped).
    """
    if mesh.uv is None:
        raise MeshError(f"{mesh.name}: mesh has no UVs to split at")
    uv = np.asarray(mesh.uv, dtype=np.float64).reshape(-1, 2)
    vid = mesh.faces.reshape(-1)
    key_uv = np.round(uv / atol) if atol > 0 else uv
    keys = np.concatenate([vid[:, None].astype(np.float64), key_uv], axis=1)
    if by_handedness:
        fu = np.asarray(mesh.uv, dtype=np.float64)
        d1, d2 = fu[:, 1] - fu[:, 0], fu[:, 2] - fu[:, 0]
        sign = np.sign(d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1])
        keys = np.concatenate([keys, np.repeat(sign, 3)[:, None]], axis=1)
    _, first, inv = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    vmap = vid[first].astype(np.int64)
    normals = vertex_normals(mesh)[vmap]
    out = Mesh(
        vertices=mesh.vertices[vmap].copy(),
        faces=inv.reshape(-1, 3).astype(np.int64),
        uv=uv[first][inv].reshape(-1, 3, 2),
        texture=mesh.texture,
        vertex_normals=normals,
        frame=mesh.frame,
        degenerate=None if mesh.degenerate is None else mesh.degenerate.copy(),
        uv_policy=mesh.uv_policy,
        watertight=False,
        source=mesh.source,
        warnings=list(mesh.warnings),
    )
    return out, vmap
