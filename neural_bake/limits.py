"""Caps on the sizes a user can ask for (image sides, frame counts, map samples, workers…).

Each check is one line naming the parameter and the allowed range (a :class:`NeuralBakeError` whose
``parameter`` is that name, so the CLI names its option), raised where the value enters the library and
before anything of that size is allocated. The caps themselves are in :mod:`neural_bake.constants`.
"""

from __future__ import annotations

import math

from .constants import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, MAX_MAP_SAMPLES_SIDE
from .errors import NeuralBakeError

__all__ = ["check_count", "check_image_size", "check_magnitude", "check_map_samples"]


def check_count(value, name: str, cap: int, *, minimum: int = 1, error: type[NeuralBakeError] = NeuralBakeError,
                what: str = "") -> int:
    """``value`` as an int: a whole number in ``minimum``..``cap``, else ``error("<name> <value>: must be a
    whole number in <minimum>..<cap>[ (what)]", parameter=name)``."""
    try:
        number = float(value)
        ok = (not isinstance(value, (bool, str)) and math.isfinite(number) and number == int(number)
              and minimum <= int(number) <= cap)
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        suffix = f" ({what})" if what else ""
        raise error(f"{name} {value!r:.40}: must be a whole number in {minimum}..{cap}{suffix}", parameter=name)
    return int(number)


def check_image_size(width, height, name: str = "size", *, error: type[NeuralBakeError] = NeuralBakeError
                     ) -> tuple[int, int]:
    """``(width, height)`` of an image: whole numbers of pixels in 1..``MAX_IMAGE_SIDE`` whose product is at
    most ``MAX_IMAGE_PIXELS``, else one line naming ``name``."""
    w = check_count(width, f"{name} width" if name != "size" else name, MAX_IMAGE_SIDE, error=error,
                    what="pixels per side")
    h = check_count(height, f"{name} height" if name != "size" else name, MAX_IMAGE_SIDE, error=error,
                    what="pixels per side")
    if w * h > MAX_IMAGE_PIXELS:
        raise error(f"{name} {w}x{h}: {w * h} pixels, more than the {MAX_IMAGE_PIXELS} a render may have",
                    parameter=name)
    return w, h


def check_magnitude(value, name: str, cap: float, *, error: type[NeuralBakeError] = NeuralBakeError) -> float:
    """``value`` as a float: finite with |value| ≤ ``cap``, else one line naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        v = math.nan
    if isinstance(value, bool) or not (math.isfinite(v) and abs(v) <= cap):
        raise error(f"{name} {value!r:.40}: must be a finite number within ±{cap:g}", parameter=name)
    return v


def check_map_samples(size, supersample) -> tuple[int, int]:
    """``(size, supersample)`` of a texel map: whole numbers ≥ 1 with size × supersample (samples per side) at
    most ``MAX_MAP_SAMPLES_SIDE``, else one line naming ``size`` or ``supersample``."""
    size = check_count(size, "size", MAX_MAP_SAMPLES_SIDE, what="texels per side")
    supersample = check_count(supersample, "supersample", MAX_MAP_SAMPLES_SIDE, what="samples per texel side")
    if size * supersample > MAX_MAP_SAMPLES_SIDE:
        raise NeuralBakeError(f"supersample {supersample}: a {size}x{size} map with {supersample}x{supersample} "
                              f"samples per texel has {size * supersample} samples per side, more than "
                              f"{MAX_MAP_SAMPLES_SIDE}", parameter="supersample")
    return size, supersample
