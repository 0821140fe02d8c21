"""Shared test set-up: one torch thread per test process (pytest-xdist runs one process per core), and no
hypothesis example database in the working directory (tests write only under tmp_path)."""

import os
import tempfile

# hypothesis keeps caches in ./.hypothesis unless told otherwise: keep them out of the working tree
os.environ.setdefault("HYPOTHESIS_STORAGE_DIRECTORY", os.path.join(tempfile.gettempdir(), "neural-bake-hypothesis"))

import numpy as np
import pytest
import torch
from hypothesis import settings

torch.set_num_threads(1)

settings.register_profile("neural_bake", database=None, deadline=None)
settings.load_profile("neural_bake")


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
