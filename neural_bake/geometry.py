"""Small geometric measures that fitting, baking and rendering all use (numpy; no stage imports)."""

from __future__ import annotations

import numpy as np

__all__ = ["angular_error", "frame_mismatch"]


def angular_error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles in degrees (M,) between unit vectors a and b (M, 3), float64; a zero vector gives 90°."""
    d = np.einsum("ij,ij->i", np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return np.degrees(np.arccos(np.clip(d, -1.0, 1.0)))


def frame_mismatch(a, b) -> float:
    """How far apart two :class:`~neural_bake.types.Frame` s are, in unit-frame terms: the larger of the centre
    offset measured in ``b``'s unit frame and the relative scale difference |s_a / s_b − 1|."""
    offset = float(np.linalg.norm(np.subtract(a.center, b.center))) * float(b.scale)
    return max(offset, abs(float(a.scale) / float(b.scale) - 1.0))
