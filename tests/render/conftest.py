"""Fixtures of the renderer's tests."""

import pytest

from neural_bake.samples.shapes import SAMPLES
from render_cases import nested_sphere_asset


@pytest.fixture
def nested_sphere():
    """h1 = |p| − 0.52 with δ1 = 0.04 around f = |p| − 0.5 (|h1 − f| = 0.02 < δ1: nested)."""
    return nested_sphere_asset()


@pytest.fixture(params=sorted(SAMPLES))
def sample(request):
    return SAMPLES[request.param]
