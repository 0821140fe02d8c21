"""Checks of the values a field file's JSON header holds (frame, δ, numbers), before anything is built.

Each failure is a one-line :class:`ModelFileError` naming the file and the field, e.g.
``"bunny.sdf: frame.scale = 0 is not a finite positive number"``.
"""

from __future__ import annotations

import math

from ..errors import ModelFileError
from ..types import Frame

__all__ = ["check_frame", "check_delta", "check_number"]


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def check_number(value, path, field: str, *, positive: bool = False, allow_none: bool = False) -> float | None:
    """``value`` as a float: finite and ≥ 0 (> 0 with ``positive``); None passes with ``allow_none``."""
    if value is None and allow_none:
        return None
    ok = _is_number(value) and math.isfinite(value) and (value > 0 if positive else value >= 0)
    if not ok:
        what = "a finite positive number" if positive else "a finite number >= 0"
        raise ModelFileError(f"{path}: {field} = {value!r:.40} is not {what}")
    return float(value)


def check_frame(value, path, field: str = "frame", *, required: bool = False) -> Frame | None:
    """A :class:`Frame` from ``{"center": [x, y, z], "scale": s}``: a finite 3-vector and a finite s > 0
    (a scale of 0, −1 or NaN would silently turn, flip or flatten every normal). None is allowed unless
    ``required``."""
    if value is None and not required:
        return None
    if not isinstance(value, dict):
        raise ModelFileError(f"{path}: {field} = {value!r:.40} is not an object {{center, scale}}")
    center = value.get("center")
    if (not isinstance(center, list) or len(center) != 3
            or not all(_is_number(c) and math.isfinite(c) for c in center)):
        raise ModelFileError(f"{path}: {field}.center = {center!r:.60} is not a finite 3-vector")
    scale = check_number(value.get("scale"), path, f"{field}.scale", positive=True)
    return Frame(tuple(float(c) for c in center), scale)


def check_delta(value, path, field: str = "delta") -> float | None:
    """δ, finite and ≥ 0, or None when absent. δ = 0 (no band recorded) loads as None."""
    d = check_number(value, path, field, allow_none=True)
    return d if d else None
