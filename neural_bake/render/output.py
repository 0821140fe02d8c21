"""Writing a render's channels: the colour image to OUT, every other channel beside it.

``write_render(result, "shot.png")`` writes the colour (sRGB-encoded 8-bit PNG; linear floats in an EXR)
to ``shot.png`` and each other channel asked for to ``shot.<channel>.<ext>`` with ``ext`` "exr" (values as
they are: depth in source units with 0 where missed, normals in [-1, 1], iteration counts, masks 0/1) or
"png" (for viewing: depth mapped near → white, far → black; normals as (n + 1) / 2; iterations divided by
their maximum; masks 0/1). Each file is written atomically (:mod:`neural_bake.io.atomic`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..constants import MIN_SPAN
from ..io.images import write_image
from .asset import RenderError

__all__ = ["write_render", "channel_image", "CHANNEL_FORMATS"]

#: File formats of the extra channels.
CHANNEL_FORMATS = ("exr", "png")


def channel_image(name: str, array: np.ndarray, hit: np.ndarray, fmt: str) -> np.ndarray:
    """The (H, W[, C]) float32 image written for channel ``name`` in format ``fmt`` (module docstring)."""
    a = np.asarray(array)
    if name == "depth":
        d = np.where(hit, a, 0.0).astype(np.float32)
        if fmt == "exr" or not hit.any():
            return d
        lo, hi = float(d[hit].min()), float(d[hit].max())
        return np.where(hit, 1.0 - 0.8 * (d - lo) / max(hi - lo, MIN_SPAN), 0.0).astype(np.float32)
    if name == "normal":
        return (a if fmt == "exr" else np.where(hit[..., None], (a + 1) / 2, 0.0)).astype(np.float32)
    if name == "iterations":
        a = a.astype(np.float32)
        return a if fmt == "exr" else a / max(float(a.max()), 1.0)
    if name == "lod":
        a = np.where(hit, a, 0.0).astype(np.float32)
        return a if fmt == "exr" else a / max(float(a.max()), 1.0)
    if name in ("hit", "holes"):
        return a.astype(np.float32)
    return a.astype(np.float32)


def write_render(result, out, *, channel_format: str = "png") -> list[Path]:
    """Write ``result.channels`` (see the module docstring); returns the paths written, colour first.

    Without a colour channel, OUT receives the first channel asked for. Raises RenderError for an unknown
    channel format, ImageError (from the image writer) for an unwritable OUT.
    """
    if channel_format not in CHANNEL_FORMATS:
        raise RenderError(f"channel format {channel_format!r}: expected one of {', '.join(CHANNEL_FORMATS)}")
    out = Path(out)
    hit = result.channels["hit"]
    names = [c for c in result.stats.get("channels", []) if c in result.channels] or ["hit"]
    main = "color" if "color" in names else names[0]
    is_float_out = out.suffix.lower() == ".exr"
    paths = []
    if main == "color":
        paths.append(write_image(out, np.clip(result.channels["color"], 0.0, None) if is_float_out
                                 else result.channels["color"], colour="linear" if is_float_out else "srgb"))
    else:
        img = channel_image(main, result.channels[main], hit, "exr" if is_float_out else "png")
        paths.append(write_image(out, img, colour="data"))
    for name in names:
        if name == main:
            continue
        path = out.with_name(f"{out.stem}.{name}.{channel_format}")
        img = channel_image(name, result.channels[name], hit, channel_format)
        paths.append(write_image(path, img, colour="data", bits=32 if channel_format == "exr" else None))
    return paths
