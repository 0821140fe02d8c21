"""Shared test set-up: small thread count (tests run two at a time on a 2-core machine), seeds."""

import numpy as np
import pytest
import torch

torch.set_num_threads(1)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
