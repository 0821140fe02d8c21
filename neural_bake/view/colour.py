"""The baked albedo beside the source texture at the same surface points, and the colour error between them.

Each texel centre of the bake's UV layout is a point on the coarse mesh; its closest point on the source
mesh carries the source's own UVs, where the source texture is read (bilinear). The two colours of a
texel are then the same place of the model seen through both UV layouts.

The colour error is per-texel RGB error: the mean over R, G, B of the absolute difference of the
sRGB-encoded values, in 8-bit levels (0 … 255) — what an artist sees side by side, and what an 8-bit map
can hold (one level is its quantisation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..io.colour import linear_to_srgb
from ..types import Mesh
from .meshes import ViewError, ViewMesh

__all__ = ["ColourComparison", "compare_colours", "colour_error", "colour_heat", "COLOUR_ERROR_SCALE"]

#: A colour error at or above this many 8-bit levels draws white in a colour error map (smaller errors
#: scale linearly from black through red and yellow).
COLOUR_ERROR_SCALE = 32.0


def colour_error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-point colour error of linear-RGB colours ``a`` and ``b`` (..., ≥3): mean over R, G, B of
    |sRGB(a) − sRGB(b)| (values clipped to [0, 1] first), in 8-bit levels; shape (...)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.shape[-1] < 3:
        raise ViewError(f"colour error: colours must be (..., 3) of one shape, got {a.shape} and {b.shape}")
    da = linear_to_srgb(np.clip(a[..., :3], 0.0, 1.0))
    db = linear_to_srgb(np.clip(b[..., :3], 0.0, 1.0))
    return np.abs(da - db).mean(axis=-1) * 255.0


def colour_heat(error: np.ndarray, coverage: np.ndarray | None = None, scale: float = COLOUR_ERROR_SCALE
                ) -> np.ndarray:
    """(H, W, 3) float32 display-ready heat image of an (H, W) error in levels: black for 0, through red and
    yellow to white at ``scale``; texels outside ``coverage`` dark blue-grey."""
    d = np.clip(np.nan_to_num(np.asarray(error, dtype=np.float64)) / float(scale), 0.0, 1.0)
    img = np.stack([np.clip(2 * d, 0, 1), np.clip(2 * d - 1, 0, 1), np.clip(4 * d - 3, 0, 1)], axis=-1)
    if coverage is not None:
        img[~np.asarray(coverage, dtype=bool)] = (0.15, 0.16, 0.2)
    return img.astype(np.float32)


@dataclass
class ColourComparison:
    """What :func:`compare_colours` measured, on the bake's (H, W) texel grid.

    - ``source``: (H, W, 3) float32 linear RGB, the source texture read at each texel's surface point.
    - ``baked``: (H, W, 3) float32 linear RGB, the baked albedo.
    - ``error``: (H, W) float64 colour error in 8-bit levels (:func:`colour_error`), 0 outside ``coverage``.
    - ``coverage``: (H, W) bool, texels whose centre lies in a UV triangle of the bake.
    - ``stats``: median, mean, p95 and max of the error over the covered texels, and their count.
    """

    source: np.ndarray
    baked: np.ndarray
    error: np.ndarray
    coverage: np.ndarray
    stats: dict


def _texel_points(baked: ViewMesh, shape: tuple[int, int]):
    """The covered texel centres of ``baked``'s UV layout: ((M, 2) pixel (row from the top, column),
    (M, 3) points, source frame)."""
    from ..mesh.texels import rasterize_texels

    tx = rasterize_texels(baked.to_mesh(), shape, tangents=baked.tangents, conservative=False)
    return np.asarray(tx.pixel), np.asarray(tx.points, dtype=np.float64)


def compare_colours(baked: ViewMesh, source: Mesh) -> ColourComparison:
    """The source texture beside the baked albedo at the same surface points (module docstring).

    - ``baked``: the bake's mesh with its albedo (``view_mesh_from_glb``; source frame, its UV layout).
    - ``source``: the source mesh as loaded (unit frame with its ``frame``, its own UVs and texture).

    Raises :class:`ViewError` when either has no texture or UVs.
    """
    from ..bake.baseline import closest_surface
    from ..io.colour import sample_texture

    if baked.texture is None or baked.uv is None:
        raise ViewError(f"{baked.name}: no baked albedo to compare")
    if source.texture is None or source.uv is None:
        raise ViewError(f"{source.source or 'source mesh'}: no texture to compare the baked albedo with")
    shape = baked.texture.shape[:2]
    pixel, points = _texel_points(baked, shape)
    near = closest_surface(source, source.frame.to_unit(points))
    uv = np.einsum("mk,mkc->mc", near["bary"], np.asarray(source.uv, dtype=np.float64)[near["face"]])
    tex = np.asarray(source.texture, dtype=np.float32)
    if tex.shape[2] < 3:
        tex = np.repeat(tex[..., :1], 3, axis=2)
    src = sample_texture(tex[..., :3], uv, source.uv_policy)
    ours = baked.texture[pixel[:, 0], pixel[:, 1], :3]
    err = colour_error(ours, src)
    coverage = np.zeros(shape, dtype=bool)
    coverage[pixel[:, 0], pixel[:, 1]] = True
    error = np.zeros(shape, dtype=np.float64)
    error[pixel[:, 0], pixel[:, 1]] = err
    src_img = np.zeros((*shape, 3), dtype=np.float32)
    src_img[pixel[:, 0], pixel[:, 1]] = src
    stats = {"median": None, "mean": None, "p95": None, "max": None, "count": 0, "unit": "8-bit levels"}
    if err.size:
        stats.update(median=float(np.median(err)), mean=float(err.mean()), p95=float(np.percentile(err, 95)),
                     max=float(err.max()), count=int(err.size))
    return ColourComparison(source=src_img, baked=np.asarray(baked.texture[..., :3], dtype=np.float32),
                            error=error, coverage=coverage, stats=stats)
