"""Edge padding of UV charts, so that bilinear and mip-map filtering do not bleed background into seams."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..errors import NeuralBakeError

__all__ = ["pad_charts", "PADDING_METHODS"]

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
    work = img.astype(np.float64)
    if method == "dilate":
        out = _dilate(work, covered, 16 if pixels is None else int(pixels))
    else:
        out = _pull_push(work, covered)
        # the first rings come from dilation (values of the nearest chart only), so that bilinear and the
        # first mip levels at a chart's edge never mix in a neighbouring chart's pushed-down colours
        rings = PULL_PUSH_DILATE if pixels is None else min(int(pixels), PULL_PUSH_DILATE)
        near, near_mask = _dilate(work, covered, rings, return_mask=True)
        out[near_mask] = near[near_mask]
        if pixels is not None:
            dist = ndimage.distance_transform_cdt(~covered, metric="chessboard")
            far = dist > pixels
            out[far] = img[far]
    out[covered] = img[covered]
    out = out.astype(img.dtype, copy=False)
    return out[:, :, 0] if squeeze else out


def _dilate(img: np.ndarray, filled: np.ndarray, steps: int, return_mask: bool = False):
    img = img.copy()
    filled = filled.copy()
    kernel = np.ones((3, 3))
    for _ in range(steps):
        if filled.all():
            break
        w = filled.astype(np.float64)
        count = ndimage.convolve(w, kernel, mode="constant")
        grow = (~filled) & (count > 0)
        if not grow.any():
            break
        for c in range(img.shape[2]):
            s = ndimage.convolve(img[:, :, c] * w, kernel, mode="constant")
            img[:, :, c][grow] = s[grow] / count[grow]
        filled |= grow
    return (img, filled) if return_mask else img


def _pull_push(img: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """Pull: 2×2 box-filter the (premultiplied colour, weight) pyramid; push: fill holes from coarser levels."""
    levels = [(img * covered[:, :, None], covered.astype(np.float64))]
    while max(levels[-1][1].shape) > 1:
        c, w = levels[-1]
        h, wd = w.shape
        ph, pw = h % 2, wd % 2
        c = np.pad(c, ((0, ph), (0, pw), (0, 0)))
        w = np.pad(w, ((0, ph), (0, pw)))
        c2 = c[0::2, 0::2] + c[1::2, 0::2] + c[0::2, 1::2] + c[1::2, 1::2]
        w2 = w[0::2, 0::2] + w[1::2, 0::2] + w[0::2, 1::2] + w[1::2, 1::2]
        # normalise so a level holds averages of the filled texels with weight min(1, sum)
        avg = np.divide(c2, w2[:, :, None], out=np.zeros_like(c2), where=w2[:, :, None] > 0)
        wn = np.minimum(w2, 1.0)
        levels.append((avg * wn[:, :, None], wn))
    # push: from the coarsest level down, blend each level's own value with the upsampled coarser one
    c, w = levels[-1]
    cur = np.divide(c, w[:, :, None], out=np.zeros_like(c), where=w[:, :, None] > 0)
    for c, w in reversed(levels[:-1]):
        h, wd = w.shape
        up = _upsample(cur, (h, wd))
        own = np.divide(c, w[:, :, None], out=np.zeros_like(c), where=w[:, :, None] > 0)
        a = np.clip(w, 0.0, 1.0)[:, :, None]
        cur = a * own + (1 - a) * up
    return cur


def _upsample(img: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Bilinear ×2 upsampling (texel centres aligned) cropped to ``shape``."""
    h, w = shape
    ch, cw = img.shape[:2]
    y = (np.arange(h) + 0.5) / 2 - 0.5
    x = (np.arange(w) + 0.5) / 2 - 0.5
    y0 = np.clip(np.floor(y).astype(int), 0, ch - 1)
    x0 = np.clip(np.floor(x).astype(int), 0, cw - 1)
    y1 = np.clip(y0 + 1, 0, ch - 1)
    x1 = np.clip(x0 + 1, 0, cw - 1)
    fy = np.clip(y - np.floor(y), 0, 1)[:, None, None]
    fx = np.clip(x - np.floor(x), 0, 1)[None, :, None]
    top = img[y0][:, x0] * (1 - fx) + img[y0][:, x1] * fx
    bot = img[y1][:, x0] * (1 - fx) + img[y1][:, x1] * fx
    return top * (1 - fy) + bot * fy
