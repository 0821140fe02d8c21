"""Pixel comparisons of renders of one view: MSE, PSNR and a difference image.

Images are compared as displayed: linear RGB is sRGB-encoded and clipped to [0, 1] first, so the figures
match what a person sees side by side. The region compared is the union of both renders' masks (a pixel the
mesh covers in either), so silhouette differences count and the shared background does not dilute them.
"""

from __future__ import annotations

import math

import numpy as np

from ..io.colour import linear_to_srgb
from ..constants import INTERIOR_ERODE_PX
from .meshes import ViewError

__all__ = ["image_metrics", "difference_image", "silhouette_iou", "detail_correlation", "DIFF_SCALE", "REGIONS"]

#: "union": pixels either render covers (silhouette differences count); "interior": pixels both cover, less a
#: border of INTERIOR_ERODE_PX (shading only: the coarse mesh's outline does not count).
REGIONS = ("union", "interior")

#: An absolute sRGB difference at or above this draws full red in a difference image (0.25: a quarter of
#: the display range; smaller differences scale linearly to black).
DIFF_SCALE = 0.25


def _displayed(rgb: np.ndarray) -> np.ndarray:
    return linear_to_srgb(np.clip(np.asarray(rgb, dtype=np.float64), 0.0, 1.0))


def _check_pair(a: np.ndarray, b: np.ndarray) -> None:
    if np.shape(a) != np.shape(b) or np.ndim(a) != 3:
        raise ViewError(f"image comparison: renders must be (H, W, 3) of one size, got {np.shape(a)} and {np.shape(b)}")


def _region(shape, mask_a, mask_b, region: str) -> np.ndarray:
    if region not in REGIONS:
        raise ViewError(f"image comparison region {region!r}: expected one of {', '.join(REGIONS)}")
    masks = [np.asarray(m, dtype=bool) for m in (mask_a, mask_b) if m is not None]
    if not masks:
        return np.ones(shape, dtype=bool)
    for m in masks:
        if m.shape != shape:
            raise ViewError(f"image comparison: mask of shape {m.shape} for images of {shape}")
    if region == "union":
        return np.logical_or.reduce(masks)
    from scipy.ndimage import binary_erosion

    return binary_erosion(np.logical_and.reduce(masks), iterations=INTERIOR_ERODE_PX)


def image_metrics(a: np.ndarray, b: np.ndarray, mask_a: np.ndarray | None = None,
                  mask_b: np.ndarray | None = None, *, region: str = "union") -> dict:
    """MSE and PSNR (dB, peak 1) of two linear-RGB renders (H, W, 3) on sRGB-encoded values, over a
    ``region`` of their masks (H, W) (see :data:`REGIONS`; the whole image when both masks are None); plus
    ``pixels`` compared and ``mean_abs`` difference. PSNR is inf for equal images; an empty region gives
    None figures."""
    _check_pair(a, b)
    region = _region(np.shape(a)[:2], mask_a, mask_b, region)
    da, db = _displayed(a)[region], _displayed(b)[region]
    if da.size == 0:
        return {"mse": None, "psnr_db": None, "mean_abs": None, "pixels": 0}
    mse = float(np.mean((da - db) ** 2))
    return {"mse": mse, "psnr_db": math.inf if mse == 0 else float(10 * np.log10(1.0 / mse)),
            "mean_abs": float(np.mean(np.abs(da - db))), "pixels": int(region.sum())}


def silhouette_iou(mask_a: np.ndarray, mask_b: np.ndarray) -> float | None:
    """Intersection over union of two (H, W) masks; None when both are empty."""
    a, b = np.asarray(mask_a, dtype=bool), np.asarray(mask_b, dtype=bool)
    union = int((a | b).sum())
    return None if union == 0 else float((a & b).sum() / union)


def difference_image(a: np.ndarray, b: np.ndarray, scale: float = DIFF_SCALE) -> np.ndarray:
    """(H, W, 3) float32 display-ready (sRGB-encoded) heat image of |a − b| (mean over RGB of the sRGB
    values): black for equal, through red to yellow-white at ``scale`` and above."""
    _check_pair(a, b)
    d = np.abs(_displayed(a) - _displayed(b)).mean(axis=2) / float(scale)
    d = np.clip(d, 0.0, 1.0)
    return np.stack([np.clip(2 * d, 0, 1), np.clip(2 * d - 1, 0, 1), np.clip(4 * d - 3, 0, 1)], axis=2).astype(np.float32)


def detail_correlation(a: np.ndarray, b: np.ndarray, mask: np.ndarray, sigma: float = 4.0) -> float | None:
    """Correlation of the fine detail of two linear-RGB renders (H, W, 3) over ``mask`` (H, W): each sRGB grey
    image minus its Gaussian blur of ``sigma`` pixels (what a normal map adds; smooth shading cancels), so
    renderers with different shading models still agree where the bumps are. None for fewer than 16 pixels."""
    from scipy.ndimage import gaussian_filter

    _check_pair(a, b)
    mask = np.asarray(mask, dtype=bool)
    if mask.sum() < 16:
        return None
    da, db = (_displayed(x).mean(axis=2) for x in (a, b))
    ha, hb = (x - gaussian_filter(x, float(sigma)) for x in (da, db))
    return float(np.corrcoef(ha[mask], hb[mask])[0, 1])
