"""Edge padding of UV charts, so that bilinear and mip-map filtering do not bleed background into seams."""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

from ..errors import NeuralBakeError
from ..nets.native import Kernel, threads

__all__ = ["pad_charts", "PADDING_METHODS", "kernel_status", "ENV_SWITCH"]

#: 0/off/false: the torch pull-push and numpy dilation even where the C kernel (padding.c) builds (A/B checks).
ENV_SWITCH = "NEURAL_BAKE_NATIVE_PADDING"


def _declare(lib) -> None:
    p, i64 = ctypes.c_void_p, ctypes.c_int64
    lib.nb_pull_push_work.argtypes = [i64, i64, i64]
    lib.nb_pull_push_work.restype = i64
    for suffix in ("f32", "f64"):
        getattr(lib, f"nb_pull_push_{suffix}").argtypes = [p, p, i64, i64, i64, p, p, i64]
        getattr(lib, f"nb_pull_push_{suffix}").restype = None
        getattr(lib, f"nb_dilate_{suffix}").argtypes = [p, p, i64, i64, i64, i64, i64]
        getattr(lib, f"nb_dilate_{suffix}").restype = ctypes.c_int


#: The C kernel (padding.c, :class:`neural_bake.nets.native.Kernel`; the pull-push's rows on torch's OpenMP team
#: where it shares it); torch and numpy where it does not build.
KERNEL = Kernel(Path(__file__).with_name("padding.c"), switch=ENV_SWITCH, declare=_declare, openmp=True)

_SUFFIX = {np.dtype(np.float32): "f32", np.dtype(np.float64): "f64"}


def kernel_status() -> str:
    """Which padding runs here: the C kernel (and its file), or why the torch and numpy one does."""
    return KERNEL.status()

PADDING_METHODS = ("pull-push", "dilate")

#: Rings around the charts that "pull-push" fills by dilation before the pyramid fills the rest.
PULL_PUSH_DILATE = 4


def pad_charts(
    image: np.ndarray,
    coverage: np.ndarray,
    *,
    method: str = "pull-push",
    pixels: int | None = None,
) -> np.ndarray:
    """Fill the texels outside the charts from the nearby chart texels.

    - ``image``: (H, W, C) or (H, W) float array; the values at covered texels are kept bit for bit.
    - ``coverage``: (H, W) bool or float; texels with coverage > 0 are *covered* (inside a chart).
    - ``method``: "pull-push" (the first :data:`PULL_PUSH_DILATE` rings by dilation, the rest from a mip
      pyramid of coverage-weighted averages pushed back down into the holes: smooth, fills everything) or "dilate" (each step gives an empty texel the mean of its filled
      8-neighbours, like texture bakers' "edge padding").
    - ``pixels``: fill only texels within this many texels (chessboard distance) of a chart; None fills
      every texel for "pull-push" and 16 texels for "dilate".

    Returns a new array of the same shape and dtype. An image without covered texels is returned unchanged.
    """
    if method not in PADDING_METHODS:
        raise NeuralBakeError(f"padding method must be one of {PADDING_METHODS}, got {method!r}")
    if pixels is not None and (int(pixels) != pixels or pixels < 0):
        raise NeuralBakeError(f"padding pixels must be a non-negative integer, got {pixels!r}")
    img = np.asarray(image)
    squeeze = img.ndim == 2
    if squeeze:
        img = img[:, :, None]
    if img.ndim != 3:
        raise NeuralBakeError(f"pad_charts: image must be (H, W, C), got shape {img.shape}")
    cov = np.asarray(coverage)
    if cov.shape != img.shape[:2]:
        raise NeuralBakeError(f"pad_charts: coverage shape {cov.shape} does not match image {img.shape[:2]}")
    covered = cov > 0
    if not covered.any() or covered.all() or pixels == 0:
        return np.array(image, copy=True)
    ftype = np.float32 if img.dtype == np.float32 else np.float64
    if method == "dilate":
        out = np.array(img, dtype=ftype, order="C")  # a copy, filled in place
        _dilate(out, covered, 16 if pixels is None else int(pixels))
    else:
        work = np.ascontiguousarray(img, dtype=ftype)  # read only: the image itself where it is one already
        out = _pull_push(work, covered)
        # the first rings come from dilation (values of the nearest chart only), so that bilinear and the
        # first mip levels at a chart's edge never mix in a neighbouring chart's pushed-down colours
        rings = PULL_PUSH_DILATE if pixels is None else min(int(pixels), PULL_PUSH_DILATE)
        _dilate(out, covered, rings)
        if pixels is not None:
            from scipy import ndimage

            dist = ndimage.distance_transform_cdt(~covered, metric="chessboard")
            far = dist > pixels
            np.copyto(out, img, where=far[:, :, None], casting="same_kind")
    out = out.astype(img.dtype, copy=False)
    return out[:, :, 0] if squeeze else out


_NEIGHBOURS = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if di or dj]


def _dilate(out: np.ndarray, filled: np.ndarray, steps: int) -> None:
    """:func:`_dilate_numpy` by the C kernel where it runs (equal bit for bit), else by numpy."""
    lib = KERNEL.lib()
    if lib is not None and out.flags.c_contiguous and out.dtype in _SUFFIX:
        state = np.ascontiguousarray(filled, dtype=np.uint8)  # a copy: the kernel marks the rings in it
        h, w, c = out.shape
        if getattr(lib, f"nb_dilate_{_SUFFIX[out.dtype]}")(out.ctypes.data, state.ctypes.data, h, w, c, int(steps),
                                                           threads()):
            return
    _dilate_numpy(out, filled, steps)


def _dilate_numpy(out: np.ndarray, filled: np.ndarray, steps: int) -> None:
    """``steps`` rings of dilation into ``out`` (H, W, C), in place: each ring gives the unfilled texels next
    to a filled one the mean of their filled 8-neighbours; only texels of ``filled`` and of earlier rings
    are read. After the first ring (one pass over the image) the work is proportional to the rings: the
    next ring is the unfilled neighbours of the last one (an unfilled texel next to an older one would
    have been in an older ring)."""
    h, w = filled.shape
    fp = filled.copy()
    near = np.zeros_like(fp)
    for di, dj in _NEIGHBOURS:  # near[i, j] |= fp[i + di, j + dj] where that exists
        near[max(0, -di): h - max(0, di), max(0, -dj): w - max(0, dj)] |= \
            fp[max(0, di): h - max(0, -di), max(0, dj): w - max(0, -dj)]
    ii, jj = np.nonzero(near & ~fp)
    offsets = np.array(_NEIGHBOURS, dtype=np.int64)
    for step in range(steps):
        if ii.size == 0:
            break
        acc = np.zeros((ii.size, out.shape[2]), dtype=out.dtype)
        cnt = np.zeros(ii.size, dtype=out.dtype)
        for di, dj in _NEIGHBOURS:
            ni, nj = ii + di, jj + dj
            inside = (ni >= 0) & (ni < h) & (nj >= 0) & (nj < w)
            f = np.zeros(ii.size, dtype=bool)
            f[inside] = fp[ni[inside], nj[inside]]
            acc[f] += out[ni[f], nj[f]]
            cnt += f
        out[ii, jj] = acc / cnt[:, None]
        fp[ii, jj] = True
        if step + 1 < steps:
            ni, nj = (ii[:, None] + offsets[:, 0]).ravel(), (jj[:, None] + offsets[:, 1]).ravel()
            inside = (ni >= 0) & (ni < h) & (nj >= 0) & (nj < w)
            flat = ni[inside] * w + nj[inside]
            flat = np.unique(flat[~fp.reshape(-1)[flat]])  # sorted: the row-major order of np.nonzero
            ii, jj = np.divmod(flat, w)


def _pull_push(img: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """:func:`_pull_push_torch` by the C kernel where it runs (within a few ulps), else by torch; the covered texels
    of the result hold ``img``'s own values."""
    lib = KERNEL.lib()
    if lib is not None and img.flags.c_contiguous and img.dtype in _SUFFIX:
        h, w, c = img.shape
        cov = np.ascontiguousarray(covered, dtype=np.uint8)
        work = np.empty(int(lib.nb_pull_push_work(h, w, c)), dtype=img.dtype)
        out = np.empty_like(img)
        getattr(lib, f"nb_pull_push_{_SUFFIX[img.dtype]}")(img.ctypes.data, cov.ctypes.data, h, w, c,
                                                           work.ctypes.data, out.ctypes.data, threads())
        return out
    out = _pull_push_torch(img, covered)
    np.copyto(out, img, where=covered[:, :, None])
    return out


def _pull_push_torch(img: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """Pull: 2×2 box-filter the (premultiplied colour, weight) pyramid; push: fill holes from coarser levels.
    The covered texels of the result hold pushed-down values too: the caller restores them.

    Runs in torch on the image's dtype (channels first), whose pooling and bilinear ×2 upsampling
    (``align_corners=False``: texel centres aligned, borders replicated) are one pass each per level."""
    import torch
    import torch.nn.functional as F

    x = torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1).unsqueeze(0)  # (1, C, H, W)
    w0 = torch.from_numpy(covered).to(x.dtype)[None, None]
    levels = [(x * w0, w0)]
    while max(levels[-1][1].shape[-2:]) > 1:
        c, w = levels[-1]
        h, wd = w.shape[-2:]
        c = F.pad(c, (0, wd % 2, 0, h % 2))
        w = F.pad(w, (0, wd % 2, 0, h % 2))
        c2 = F.avg_pool2d(c, 2) * 4.0
        w2 = F.avg_pool2d(w, 2) * 4.0
        # normalise so a level holds averages of the filled texels with weight min(1, sum)
        wn = w2.clamp(max=1.0)
        levels.append((c2 / w2.clamp(min=1e-30) * wn, wn))
    c, w = levels[-1]
    cur = c / w.clamp(min=1e-30)  # w is 0 or ≥ 1 at the coarsest level, c 0 where w is
    # push: from the coarsest level down, blend each level's own value with the upsampled coarser one; the
    # full-resolution level keeps the upsampled values only (its covered texels are the caller's to restore)
    for i in range(len(levels) - 2, -1, -1):
        c, w = levels[i]
        h, wd = w.shape[-2:]
        up = F.interpolate(cur, scale_factor=2, mode="bilinear", align_corners=False)[:, :, :h, :wd]
        if i == 0:
            cur = up
            break
        own = c / w.clamp(min=1e-30)
        a = w.clamp(0.0, 1.0)
        cur = torch.lerp(up, own, a)
    return cur[0].permute(1, 2, 0).contiguous().numpy()
