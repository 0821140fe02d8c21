"""Checks that the fitters' configs share: counts, loss weights, near-surface σ and dtypes, each refused by a
one-line FitError that names the fitter and the field."""

from __future__ import annotations

import math

import torch

from ..errors import FitError

__all__ = ["DTYPES", "check_counts", "check_weights", "check_sigmas"]

#: The training dtypes a fit config's ``dtype`` names.
DTYPES = {"float32": torch.float32, "float64": torch.float64}


def check_counts(cfg, fn: str, names, *, least: int) -> None:
    """Each field of ``names`` a whole number ≥ ``least`` (1: "a positive integer", 0: "a non-negative integer")."""
    what = "a positive integer" if least == 1 else "a non-negative integer"
    for name in names:
        v = getattr(cfg, name)
        if int(v) != v or v < least:
            raise FitError(f"{fn}: {name} must be {what}, got {v!r}")


def check_weights(cfg, fn: str, names) -> None:
    """Each field of ``names`` a finite number ≥ 0."""
    for name in names:
        v = getattr(cfg, name)
        if not (math.isfinite(v) and v >= 0):
            raise FitError(f"{fn}: {name} must be a non-negative number, got {v!r}")


def check_sigmas(cfg, fn: str) -> None:
    """``cfg.sigmas``: one or more positive finite standard deviations."""
    if not cfg.sigmas or not all(math.isfinite(s) and s > 0 for s in cfg.sigmas):
        raise FitError(f"{fn}: sigmas must be positive numbers, got {cfg.sigmas!r}")
