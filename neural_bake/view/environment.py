"""A directional environment for glTF viewers: an equirectangular HDR sky with one bright sun.

model-viewer's default neutral lighting is nearly uniform and hides normal-map detail; a sun placed where
our renderer's key light comes from shows it, and makes the viewer's picture comparable to our turntable.
The map is equirectangular, row 0 at the top (+Y up), column u = atan2(z, x) / 2π + 1/2 (three.js's
``equirectUv``), written as Radiance RGBE (.hdr), which three.js's HDR loader reads.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..constants import RGBE_MIN
from ..io.atomic import atomic_path
from .meshes import ViewError

__all__ = ["sun_environment", "write_hdr", "SUN_RADIUS_DEG"]

#: Angular radius of the sun disc, degrees (large enough for a 256-wide map to hold it with a few texels).
SUN_RADIUS_DEG = 6.0


def equirect_directions(width: int, height: int) -> np.ndarray:
    """(H, W, 3) float64 unit directions of the texel centres of an equirectangular map (row 0 up)."""
    u = (np.arange(width) + 0.5) / width
    v = 1.0 - (np.arange(height) + 0.5) / height  # v = 1 at the top row
    phi = (u - 0.5) * 2 * math.pi  # atan2(z, x)
    lat = (v - 0.5) * math.pi  # asin(y)
    pp, ll = np.meshgrid(phi, lat)
    return np.stack([np.cos(ll) * np.cos(pp), np.sin(ll), np.cos(ll) * np.sin(pp)], axis=-1)


def sun_environment(sun_direction, *, width: int = 256, sky: float = 0.15, irradiance: float = math.pi,
                    radius_deg: float = SUN_RADIUS_DEG) -> np.ndarray:
    """(width/2, width, 3) float32 linear radiance: a uniform ``sky`` plus a disc around ``sun_direction``
    (towards the sun, any length) whose radiance gives ``irradiance`` on a surface facing it (π: a white
    Lambertian surface facing the sun reflects radiance 1, like a light of intensity 1 in our shading)."""
    d = np.asarray(sun_direction, dtype=np.float64)
    if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
        raise ViewError(f"sun direction: expected 3 finite numbers, not all zero, got {sun_direction!r}")
    if int(width) < 8 or int(width) % 2:
        raise ViewError(f"environment width: expected an even number ≥ 8, got {width!r}")
    d = d / np.linalg.norm(d)
    dirs = equirect_directions(int(width), int(width) // 2)
    cos_r = math.cos(math.radians(radius_deg))
    disc = dirs @ d >= cos_r
    # texel solid angles: the disc's radiance is set from the solid angle its texels really cover
    h = int(width) // 2
    lat = (0.5 - (np.arange(h) + 0.5) / h) * math.pi
    texel = (2 * math.pi / int(width)) * (math.pi / h) * np.cos(lat)[:, None] * np.ones((1, int(width)))
    omega = float((texel * disc * np.clip(dirs @ d, 0, None)).sum())
    img = np.full(dirs.shape, float(sky), dtype=np.float64)
    if omega > 0:
        img[disc] += irradiance / omega
    return img.astype(np.float32)


def _rgbe(rgb: np.ndarray) -> np.ndarray:
    rgb = np.clip(np.asarray(rgb, dtype=np.float64), 0, None)
    m = rgb.max(axis=-1)
    mant, expo = np.frexp(m)
    scale = np.divide(mant * 256.0, m, out=np.zeros_like(m), where=m > RGBE_MIN)
    out = np.zeros(rgb.shape[:-1] + (4,), dtype=np.uint8)
    out[..., :3] = np.clip(np.floor(rgb * scale[..., None]), 0, 255).astype(np.uint8)
    out[..., 3] = np.where(m > RGBE_MIN, expo + 128, 0).astype(np.uint8)
    return out


def write_hdr(path, image: np.ndarray) -> Path:
    """Write (H, W, 3) linear radiance as a flat (not run-length encoded) Radiance RGBE file, atomically."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ViewError(f"{path}: an HDR image must be (H, W, 3), got shape {img.shape}")
    h, w = img.shape[:2]
    header = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n".encode("ascii")
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(header + _rgbe(img).tobytes())
    return path
