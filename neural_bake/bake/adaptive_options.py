"""The settings of adaptive texel evaluation (:func:`neural_bake.bake.adaptive.adaptive_evaluate`), apart from
its kernels: a bake's settings are checked before torch is imported."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import (ADAPTIVE_COLOR_TOL, ADAPTIVE_LATTICE, ADAPTIVE_TOLERANCE_DEG, ADAPTIVE_VALUE_TOL,
                         ADAPTIVE_VERTEX_SIDE)
from ..errors import NeuralBakeError

__all__ = ["AdaptiveOptions"]


@dataclass(frozen=True)
class AdaptiveOptions:
    """Settings of adaptive texel evaluation (:func:`adaptive_evaluate`)."""

    tolerance_deg: float = ADAPTIVE_TOLERANCE_DEG
    """Largest angle (degrees) between a cell's evaluated midpoint normals and their interpolation from its corners."""
    lattice: int = ADAPTIVE_LATTICE
    """Side of the coarsest cells in sample-grid positions (a power of two ≥ 2)."""
    color_tol: float = ADAPTIVE_COLOR_TOL
    """Largest colour difference (linear RGB(A)) between a midpoint and its interpolation."""
    value_tol: float = ADAPTIVE_VALUE_TOL
    """Largest |f| difference (unit frame) between a midpoint and its interpolation."""
    vertex_side: int = ADAPTIVE_VERTEX_SIDE
    """Largest side of a cell that may hold a feature of the mesh (:func:`vertex_positions`: its bent edges)."""

    def __post_init__(self):
        t = self.tolerance_deg
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not (np.isfinite(t) and 0 < t < 90):
            raise NeuralBakeError(f"tolerance_deg must be a number of degrees in (0, 90), got {t!r}",
                                  parameter="tolerance_deg")
        k = self.lattice
        if isinstance(k, bool) or int(k) != k or k < 2 or int(k) & (int(k) - 1):
            raise NeuralBakeError(f"lattice must be a power of two >= 2, got {k!r}", parameter="lattice")
        for name in ("color_tol", "value_tol"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise NeuralBakeError(f"{name} must be a positive number, got {v!r}", parameter=name)
