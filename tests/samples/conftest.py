"""Shared by the sample tests: a central finite-difference gradient, the oracle the analytic normals meet."""

import numpy as np
import pytest


def _fd_gradient(f, p, h=1e-6):
    """Central differences of ``f`` (points (N, 3) → (N,)) at ``p`` (N, 3), step ``h``."""
    g = np.zeros_like(p)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        g[:, k] = (f(p + e) - f(p - e)) / (2 * h)
    return g


@pytest.fixture
def fd_gradient():
    return _fd_gradient
