"""Colour spaces and texture lookup.

Convention (docs/design.md, "Colour"): compute in *linear* RGB. 8-bit and 16-bit colour images are taken as
sRGB-encoded and decoded to linear on read; colour maps are sRGB-encoded on write; normal maps, masks and
float (EXR) images are data and never converted. A colour network may hold sRGB-encoded values, decoded on
read with :func:`srgb_to_linear` (numpy arrays and torch tensors alike).
"""

from __future__ import annotations

import numpy as np

from ..constants import UV_POLICIES

__all__ = ["srgb_to_linear", "linear_to_srgb", "sample_texture"]


def srgb_to_linear(c):
    """IEC 61966-2-1 sRGB decoding of values in [0, 1] (any shape); same dtype (float32 for ints). A torch
    tensor is decoded as a tensor (same device and dtype), its values clipped to [0, 1] first."""
    if not isinstance(c, np.ndarray) and hasattr(c, "clamp"):
        x = c.clamp(0.0, 1.0)
        return (x / 12.92).where(x <= 0.04045, ((x.clamp_min(0.04045) + 0.055) / 1.055) ** 2.4)
    c = np.asarray(c)
    c = c.astype(np.float32) if not np.issubdtype(c.dtype, np.floating) else c
    return np.where(c <= 0.04045, c / 12.92, ((np.clip(c, 0.04045, None) + 0.055) / 1.055) ** 2.4).astype(c.dtype)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding of linear values (any shape), clipped to [0, 1]; same dtype."""
    c = np.asarray(c)
    c = c.astype(np.float32) if not np.issubdtype(c.dtype, np.floating) else c
    x = np.clip(c, 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(np.clip(x, 0.0031308, None), 1 / 2.4) - 0.055).astype(c.dtype)


def sample_texture(texture: np.ndarray, uv: np.ndarray, policy: str = "wrap") -> np.ndarray:
    """Bilinear lookup of ``texture`` at ``uv``.

    - ``texture``: (H, W, C) float array, row 0 the *top* row of the image (as stored in files).
    - ``uv``: (N, 2) float, glTF/OpenGL texture coordinates with v = 0 at the *bottom* row; texel centres
      sit at ((i + 0.5) / W, 1 - (j + 0.5) / H).
    - ``policy``: "wrap" repeats the texture (UV 1.25 reads like 0.25), "clamp" clamps to the border.

    Returns (N, C) in the texture's dtype (float64 if the texture is not floating point). Non-finite UVs
    give zeros (never NaN).
    """
    if policy not in UV_POLICIES:
        raise ValueError(f"sample_texture: policy must be one of {UV_POLICIES}, got {policy!r}")
    tex = np.asarray(texture)
    if tex.ndim == 2:
        tex = tex[:, :, None]
    if tex.ndim != 3:
        raise ValueError(f"sample_texture: texture must be (H, W, C), got shape {tex.shape}")
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"sample_texture: uv must be (N, 2), got shape {uv.shape}")
    h, w, c = tex.shape
    finite = np.isfinite(uv).all(axis=1)
    uv = np.where(finite[:, None], uv, 0.0)
    out_dtype = tex.dtype if np.issubdtype(tex.dtype, np.floating) else np.float64
    work = np.promote_types(out_dtype, np.float32)  # a half-float texture is blended in float32
    # continuous pixel coordinates, (0, 0) at the centre of the top-left texel
    x = uv[:, 0] * w - 0.5
    y = (1.0 - uv[:, 1]) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0).astype(work)[:, None], (y - y0).astype(work)[:, None]
    # the four texels as rows of the flattened image (wrapped or clamped while still floats: a UV far outside
    # [0, 1] must not overflow the integers), in int32 where the image allows
    itype = np.int32 if h * w < 2**31 else np.int64
    if policy == "wrap":
        x0, x1 = _wrapped(x0, w, itype)
        y0, y1 = _wrapped(y0, h, itype)
    else:
        x0, x1 = np.clip(x0, 0, w - 1).astype(itype), np.clip(x0 + 1, 0, w - 1).astype(itype)
        y0, y1 = np.clip(y0, 0, h - 1).astype(itype), np.clip(y0 + 1, 0, h - 1).astype(itype)
    y0 *= w
    y1 *= w
    t = tex.reshape(h * w, c).astype(work, copy=False)
    top, right = t[y0 + x0], t[y0 + x1]
    right -= top
    right *= fx
    top += right  # t00 + (t01 − t00)·fx
    bot, right = t[y1 + x0], t[y1 + x1]
    right -= bot
    right *= fx
    bot += right
    bot -= top
    bot *= fy
    top += bot
    top[~finite] = 0
    return top.astype(out_dtype, copy=False)


def _wrapped(i0: np.ndarray, n: int, itype) -> tuple[np.ndarray, np.ndarray]:
    """Whole-number floats ``i0`` and ``i0 + 1`` repeated into [0, n), as ``itype`` (the modulo only where
    ``i0`` is outside)."""
    out = (i0 < 0) | (i0 >= n)
    if out.any():
        i0[out] = np.mod(i0[out], n)
    j0 = i0.astype(itype)
    j1 = j0 + 1
    j1[j1 == n] = 0
    return j0, j1
