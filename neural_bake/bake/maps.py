"""Normal-map encoding and decoding, and assembling per-sample values into images.

Conventions (docs/design.md, "Tangent space"):

- A *tangent-space* normal map stores the coordinates (x, y, z) of the object-space normal n in the frame
  a glTF renderer reconstructs at the texel: ``n = normalize(x·T + y·B + z·N)`` with N the normalised
  interpolated vertex normal, T the normalised interpolated tangent and ``B = w·cross(N, T)``
  (:class:`neural_bake.mesh.texels.TexelSet` gives these three vectors). The frame may be non-orthogonal,
  so encoding solves the 3×3 system ``[T B N] x = n`` and renormalises x. glTF / OpenGL convention: +Y
  (green) points along B ("up" in the image); the DirectX convention flips green.
- An *object-space* map stores n itself (unit frame axes = source frame axes: the frame is a similarity).
- Encoding ``x -> (x + 1) / 2`` into [0, 1]; the map is DATA (linear, never sRGB-encoded).
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

from ..constants import DIRECTION_EPS, TBN_DET_REL_EPS
from ..errors import NeuralBakeError
from ..nets.native import Kernel, threads

__all__ = [
    "NORMAL_SPACES",
    "Y_CONVENTIONS",
    "encode_tangent_space",
    "decode_tangent_space",
    "normals_to_colors",
    "colors_to_normals",
    "splat",
    "splat_into",
    "normal_map_from_sums",
    "kernel_status",
    "ENV_SWITCH",
]

#: 0/off/false: the numpy encoding even where the C kernel (maps.c) builds (A/B checks).
ENV_SWITCH = "NEURAL_BAKE_NATIVE_MAPS"


def _declare(lib) -> None:
    p = ctypes.c_void_p
    lib.nb_encode_tangent.argtypes = [p, p, p, p, ctypes.c_int64, ctypes.c_double, ctypes.c_double, ctypes.c_int, p, p,
                                      ctypes.c_int64]
    lib.nb_encode_tangent.restype = None
    lib.nb_splat.argtypes = [p, p, p, ctypes.c_int64, ctypes.c_int64, p, p]
    lib.nb_splat.restype = None
    lib.nb_normal_map.argtypes = [p, ctypes.c_int64, ctypes.c_double, ctypes.c_int64]
    lib.nb_normal_map.restype = None


#: The C kernel (maps.c, :class:`neural_bake.nets.native.Kernel`; the encoding and the normal map on torch's
#: OpenMP team where it shares it); numpy where it does not build.
KERNEL = Kernel(Path(__file__).with_name("maps.c"), switch=ENV_SWITCH, declare=_declare, openmp=True)
_kernel = KERNEL.lib


def kernel_status() -> str:
    """Which tangent-space encoding runs here: the C kernel (and its file), or why the numpy one does."""
    return KERNEL.status()


NORMAL_SPACES = ("tangent", "object")
Y_CONVENTIONS = ("opengl", "directx")


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = (norm[..., 0] > DIRECTION_EPS) & np.isfinite(norm[..., 0])
    out = np.divide(v, norm, out=np.zeros_like(v), where=ok[..., None])
    return out, ok


def encode_tangent_space(
    normals: np.ndarray,
    tangent: np.ndarray,
    bitangent: np.ndarray,
    normal: np.ndarray,
    y_convention: str = "opengl",
) -> tuple[np.ndarray, np.ndarray]:
    """Object-space unit normals (M, 3) -> unit tangent-space vectors (M, 3) and a valid mask (M,).

    ``tangent``, ``bitangent``, ``normal``: (M, 3) float, the (possibly non-orthogonal) frame the renderer
    reconstructs at each sample. Solves ``[T B N] x = n`` exactly and renormalises, so that
    :func:`decode_tangent_space` gives back n. A singular frame (degenerate UVs or normals) gives
    x = (0, 0, 1) and valid False. ``y_convention="directx"`` negates y (green down).
    """
    if y_convention not in Y_CONVENTIONS:
        raise NeuralBakeError(f"y_convention must be one of {Y_CONVENTIONS}, got {y_convention!r}")
    n = np.asarray(normals, dtype=np.float64)
    t, b, g = (np.asarray(v, dtype=np.float64) for v in (tangent, bitangent, normal))
    lib = _kernel()
    if lib is not None and n.ndim == 2 and n.shape[1] == 3 and t.shape == b.shape == g.shape == n.shape:
        n, t, b, g = (np.ascontiguousarray(v) for v in (n, t, b, g))
        out, ok = np.empty_like(n), np.empty(len(n), dtype=np.uint8)
        lib.nb_encode_tangent(n.ctypes.data, t.ctypes.data, b.ctypes.data, g.ctypes.data, len(n), TBN_DET_REL_EPS,
                              DIRECTION_EPS, int(y_convention == "directx"), out.ctypes.data, ok.ctypes.data, threads())
        return out, ok.view(bool)
    # inverse of the matrix with columns T, B, N: rows cross(B, N), cross(N, T), cross(T, B) over det
    r0, r1, r2 = _cross(b, g), _cross(g, t), _cross(t, b)
    det = np.einsum("ij,ij->i", t, r0)
    scale = np.linalg.norm(t, axis=-1) * np.linalg.norm(b, axis=-1) * np.linalg.norm(g, axis=-1)
    ok = (np.isfinite(det) & (np.abs(det) > TBN_DET_REL_EPS * np.maximum(scale, DIRECTION_EPS))
          & np.isfinite(n).all(axis=-1))
    x = np.stack([np.einsum("ij,ij->i", r, n) for r in (r0, r1, r2)], axis=-1) * np.sign(det)[:, None]
    x, ok_norm = _unit(x)
    ok &= ok_norm
    x[~ok] = (0.0, 0.0, 1.0)
    if y_convention == "directx":
        x[:, 1] *= -1.0
    return x, ok


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (M, 3) arrays: np.cross's arithmetic, without its overhead on long arrays."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def decode_tangent_space(
    x: np.ndarray,
    tangent: np.ndarray,
    bitangent: np.ndarray,
    normal: np.ndarray,
    y_convention: str = "opengl",
) -> np.ndarray:
    """What a renderer does: tangent-space (M, 3) -> ``normalize(x·T + y·B + z·N)`` (M, 3) object space."""
    x = np.asarray(x, dtype=np.float64)
    y_sign = -1.0 if y_convention == "directx" else 1.0
    n = x[:, :1] * tangent + (y_sign * x[:, 1:2]) * bitangent + x[:, 2:3] * normal
    return _unit(n)[0]


def normals_to_colors(x: np.ndarray) -> np.ndarray:
    """Unit vectors (..., 3) in [-1, 1] -> encoded colours ``(x + 1) / 2`` in [0, 1] (linear data)."""
    return np.clip((np.asarray(x, dtype=np.float64) + 1.0) * 0.5, 0.0, 1.0)


def colors_to_normals(c: np.ndarray) -> np.ndarray:
    """Encoded colours (..., 3) in [0, 1] -> unit vectors ``normalize(2c - 1)``; zero vectors stay zero."""
    return _unit(np.asarray(c, dtype=np.float64) * 2.0 - 1.0)[0]


def _one_per_texel(flat: np.ndarray) -> bool:
    """Are the samples' flat texel indices strictly increasing (one sample per texel, in the rasteriser's
    order)? Then their sums are a scatter."""
    return len(flat) > 0 and bool((flat[1:] > flat[:-1]).all())


def normal_map_from_sums(vec: np.ndarray) -> np.ndarray:
    """The encoded normal map (H, W, 3) in [0, 1] from the per-texel weighted sums of unit vectors ``vec`` (H, W, 3),
    in place: each texel's average direction (the weight sum cancels out), (0, 0, 1) where the sum is not longer
    than :data:`~neural_bake.constants.DIRECTION_EPS` (texels whose samples cancel out, and the background), then
    ``(x + 1) / 2`` clipped. Float32 maps take the C kernel (maps.c) where it builds."""
    lib = _kernel()
    if lib is not None and vec.dtype == np.float32 and vec.flags.c_contiguous:
        lib.nb_normal_map(vec.ctypes.data, vec.size // 3, float(DIRECTION_EPS), threads())
        return vec
    return _normal_map_numpy(vec)


def _normal_map_numpy(vec: np.ndarray) -> np.ndarray:
    """:func:`normal_map_from_sums` in numpy."""
    norm = np.sqrt(np.einsum("ijk,ijk->ij", vec, vec))[:, :, None]
    np.divide(vec, norm, out=vec, where=norm > DIRECTION_EPS)
    vec[norm[:, :, 0] <= DIRECTION_EPS] = (0.0, 0.0, 1.0)
    vec += 1.0
    vec *= 0.5
    np.clip(vec, 0.0, 1.0, out=vec)
    return vec


def splat_into(
    acc: np.ndarray,
    wsum: np.ndarray | None,
    values: np.ndarray,
    pixel: np.ndarray,
    weight: np.ndarray | None,
) -> None:
    """Add the weighted sums of per-sample ``values`` (M, C) into the image ``acc`` (H, W, C) in place (and
    the weight sums into ``wsum`` (H, W), unless None): :func:`splat` without a full-size temporary when the
    samples' texels are strictly increasing (one sample per texel, as rasterised), the sums otherwise. Float32
    images take the C kernel (maps.c, sample by sample, the same arithmetic as the scatter) where it builds."""
    h, w = acc.shape[:2]
    flat = np.asarray(pixel[:, 0], dtype=np.int64) * w + np.asarray(pixel[:, 1], dtype=np.int64)
    if len(flat) == 0:
        return
    lib = _kernel()
    if lib is not None and acc.dtype == np.float32 and acc.flags.c_contiguous and (
            wsum is None or (wsum.dtype == np.float32 and wsum.flags.c_contiguous)):
        if flat.min() < 0 or flat.max() >= h * w:
            raise NeuralBakeError(f"splat: texel indices outside the {h}x{w} image")
        vals = np.ascontiguousarray(values, dtype=np.float64).reshape(len(flat), -1)
        wt_c = None if weight is None else np.ascontiguousarray(weight, dtype=np.float64)
        flat = np.ascontiguousarray(flat)
        lib.nb_splat(vals.ctypes.data, flat.ctypes.data, None if wt_c is None else wt_c.ctypes.data, len(flat),
                     vals.shape[1], acc.ctypes.data, None if wsum is None else wsum.ctypes.data)
        return
    _splat_into_numpy(acc, wsum, values, pixel, weight, flat)


def _splat_into_numpy(acc: np.ndarray, wsum: np.ndarray | None, values: np.ndarray, pixel: np.ndarray,
                      weight: np.ndarray | None, flat: np.ndarray) -> None:
    """:func:`splat_into` in numpy (``flat``: the samples' flat texel indices)."""
    h, w = acc.shape[:2]
    wt = np.ones(len(flat)) if weight is None else np.asarray(weight, dtype=np.float64)
    if _one_per_texel(flat):
        a = acc.reshape(h * w, -1)
        a[flat] += np.asarray(values, dtype=np.float64) * wt[:, None]
        if wsum is not None:
            wsum.reshape(-1)[flat] += wt
        return
    r0, r1 = int(pixel[:, 0].min()), int(pixel[:, 0].max()) + 1
    part, ws = splat(values, pixel, weight, (h, w), rows=(r0, r1), average=False)
    acc[r0:r1] += part
    if wsum is not None:
        wsum[r0:r1] += ws


def splat(
    values: np.ndarray,
    pixel: np.ndarray,
    weight: np.ndarray | None,
    size: tuple[int, int],
    *,
    rows: tuple[int, int] | None = None,
    average: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted average (or weighted sum) of per-sample ``values`` (M, C) into an image.

    ``pixel``: (M, 2) int (row from the top, column); ``weight``: (M,) or None (all ones); ``size``: (H, W).
    ``rows=(a, b)``: build only image rows [a, b) (all samples must lie there), for streamed bands.
    ``average=False`` returns the weighted sums instead of averages. Returns the (b − a, W, C) float64 image
    (texels without samples are 0) and the per-texel weight sum (b − a, W).
    """
    h, w = size
    a, b = (0, h) if rows is None else rows
    values = np.asarray(values, dtype=np.float64)
    flat = (np.asarray(pixel[:, 0], dtype=np.int64) - a) * w + np.asarray(pixel[:, 1], dtype=np.int64)
    wt = np.ones(len(flat)) if weight is None else np.asarray(weight, dtype=np.float64)
    n = (b - a) * w
    c = values.shape[1]
    if _one_per_texel(flat):  # a scatter, the same sums
        acc = np.zeros((n, c))
        acc[flat] = values * wt[:, None]
        wsum = np.zeros(n)
        wsum[flat] = wt
    else:
        acc = np.empty((n, c))
        for k in range(c):
            acc[:, k] = np.bincount(flat, weights=values[:, k] * wt, minlength=n)
        wsum = np.bincount(flat, weights=wt, minlength=n)
    if average:
        np.divide(acc, wsum[:, None], out=acc, where=wsum[:, None] > 0)
    return acc.reshape(b - a, w, c), wsum.reshape(b - a, w)
