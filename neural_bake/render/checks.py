"""Value checks shared by the camera, the lights and the scene: one-line errors naming where a value sits."""

from __future__ import annotations

import math

__all__ = ["finite_numbers"]


def finite_numbers(where: str, value, n: int, error: type[Exception]) -> tuple[float, ...]:
    """``value`` as a tuple of ``n`` finite floats, else ``error("<where>: expected n (finite) numbers, got …")``."""
    try:
        v = tuple(float(c) for c in value)
    except (TypeError, ValueError):
        raise error(f"{where}: expected {n} numbers, got {value!r}") from None
    if len(v) != n or not all(math.isfinite(c) for c in v):
        raise error(f"{where}: expected {n} finite numbers, got {value!r}")
    return v
