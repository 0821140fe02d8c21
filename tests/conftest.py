"""Shared test set-up: one torch thread per test process (pytest-xdist runs one process per core), no
hypothesis example database in the working directory (tests write only under tmp_path), Ctrl-C live in
the CLI processes the tests start, and the long runs first."""

import os
import signal
import tempfile

# hypothesis keeps caches in ./.hypothesis unless told otherwise: keep them out of the working tree
os.environ.setdefault("HYPOTHESIS_STORAGE_DIRECTORY", os.path.join(tempfile.gettempdir(), "neural-bake-hypothesis"))
# the fit budgets' record of this machine's best GEMM rate (neural_bake.fit.budget) stays out of the home folder
os.environ.setdefault("NEURAL_BAKE_CACHE_DIR", tempfile.mkdtemp(prefix="neural-bake-cache-"))

import numpy as np
import pytest
import torch
from hypothesis import settings

from neural_bake.nets.siren import Siren

torch.set_num_threads(1)
os.environ.setdefault("NEURAL_BAKE_THREADS", "1")  # fits and bakes keep that one thread (no thread probes)

# a test run started in the background of a non-interactive shell inherits SIGINT ignored, and every CLI it
# starts would too (an ignored signal stays ignored across exec): the Ctrl-C tests need SIGINT to act
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

settings.register_profile("neural_bake", database=None, deadline=None)
settings.load_profile("neural_bake")


def pytest_collection_modifyitems(config, items):
    """The long end-to-end runs (marked ``slow``) first: pytest-xdist hands tests out in collection order, and
    one started last would keep a worker busy after the rest have finished."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


class Ticker:
    """A clock that advances ``dt`` seconds on every read: every measured interval is a multiple of it, and a
    budget follows it, not the machine's load."""

    def __init__(self, dt):
        self.t, self.dt, self.calls = 0.0, dt, 0

    def __call__(self):
        self.t += self.dt
        self.calls += 1
        return self.t


@pytest.fixture
def ticker():
    """The :class:`Ticker` class: ``ticker(dt)`` is a simulated clock."""
    return Ticker


def _fit_sphere_siren(r: float = 0.7, width: int = 32, steps: int = 250, depth: int = 1, seed: int = 0) -> Siren:
    """A small Siren (ω0 10) fitted to the sphere SDF |x| − r on [-1, 1]³ by ``steps`` Adam steps; seeded."""
    net = Siren(width, depth, omega_0=10.0, generator=torch.Generator().manual_seed(seed))
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    gen = torch.Generator().manual_seed(seed + 1)
    for _ in range(steps):
        x = torch.rand(1024, 3, generator=gen) * 2 - 1
        loss = ((net(x)[:, 0] - (x.norm(dim=1) - r)) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net.eval()


@pytest.fixture(scope="session")
def fit_sphere_siren():
    """The function that fits a small Siren to a sphere's SDF (:func:`_fit_sphere_siren`)."""
    return _fit_sphere_siren
