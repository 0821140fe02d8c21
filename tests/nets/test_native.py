"""neural_bake.nets.native: kernels built with OpenMP share torch's runtime, give the same bits with any thread
count, and build without OpenMP where it cannot be shared or does not build."""

import ctypes
from pathlib import Path

import pytest
import torch

from neural_bake.nets import native
from neural_bake.nets.native import Kernel, build, compiler, threads, torch_openmp

pytestmark = pytest.mark.skipif(compiler() is None, reason="no C compiler: no kernel builds")

SOURCE = """#include <stdint.h>
#ifdef _OPENMP
#include <omp.h>
#endif
/* the team a parallel region of `threads` gets (1 without OpenMP) */
int64_t nb_team(int64_t threads) {
    int64_t n = 1;
#ifdef _OPENMP
#pragma omp parallel num_threads((int)threads)
    {
#pragma omp single
        n = omp_get_num_threads();
    }
#endif
    return n;
}
"""


def _declare(lib) -> None:
    lib.nb_team.argtypes = [ctypes.c_int64]
    lib.nb_team.restype = ctypes.c_int64


def _runtimes() -> list[str]:
    """The OpenMP runtimes mapped here a kernel could bind to (not those a wheel vendors under its own name, as
    fast-simplification's, which its library alone uses)."""
    with open("/proc/self/maps") as fh:
        return native.openmp_runtimes({Path(line.split()[-1]).name for line in fh if "/" in line})


def test_vendored_runtimes_are_their_wheels_own():
    names = {"libgomp.so.1", "libgomp-e985bcbb.so.1.0.0", "libiomp5-0123abcd.so", "libtorch_cpu.so"}
    assert native.openmp_runtimes(names) == ["libgomp.so.1"]
    assert native.openmp_runtimes({"libgomp.so.1", "libiomp5.so"}) == ["libgomp.so.1", "libiomp5.so"]
    assert native.openmp_runtimes({"libomp.so"}) == ["libomp.so"]


@pytest.fixture
def team_source(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    src = tmp_path / "team.c"
    src.write_text(SOURCE)
    return src


def test_openmp_kernel_runs_on_torchs_runtime(team_source):
    usable, why = torch_openmp()
    lib, msg = build(team_source, switch="NEURAL_BAKE_TEST_TEAM", openmp=True)
    assert lib is not None
    _declare(lib)
    if not usable:  # built on the calling thread, and says why
        assert "one thread" in msg and why in msg and lib.nb_team(2) == 1
        return
    assert "OpenMP on torch's libgomp.so.1" in msg
    assert lib.nb_team(2) == 2 and lib.nb_team(1) == 1
    assert _runtimes() == ["libgomp.so.1"]  # no second OpenMP runtime was loaded beside torch's


def test_without_torchs_runtime_the_kernel_builds_for_one_thread(team_source, monkeypatch):
    monkeypatch.setitem(native._openmp, "state", (False, "torch's parallel backend is not OpenMP"))
    lib, msg = build(team_source, switch="NEURAL_BAKE_TEST_TEAM", openmp=True)
    assert lib is not None and msg.endswith("one thread (torch's parallel backend is not OpenMP)")
    _declare(lib)
    assert lib.nb_team(2) == 1


def test_a_failed_openmp_build_falls_back_to_one_thread(team_source, monkeypatch, tmp_path):
    # a compiler that refuses -fopenmp (as clang without libomp does) and builds everything else
    cc = tmp_path / "cc-no-openmp"
    cc.write_text(f'#!/bin/sh\nfor a in "$@"; do [ "$a" = -fopenmp ] && {{ echo "unsupported option -fopenmp" >&2; '
                  f'exit 1; }}; done\nexec {compiler()} "$@"\n')
    cc.chmod(0o755)
    monkeypatch.setenv("CC", str(cc))
    monkeypatch.setitem(native._openmp, "state", (True, "torch's libgomp.so.1"))
    lib, msg = build(team_source, switch="NEURAL_BAKE_TEST_TEAM", openmp=True)
    assert lib is not None and "one thread (the C kernel did not build (unsupported option -fopenmp))" in msg
    _declare(lib)
    assert lib.nb_team(2) == 1


def test_kernel_passes_openmp_on_and_switch_turns_it_off(team_source, monkeypatch):
    k = Kernel(team_source, switch="NEURAL_BAKE_TEST_TEAM", declare=_declare, openmp=True)
    assert k.lib() is not None and k.status().startswith("C kernel")
    monkeypatch.setenv("NEURAL_BAKE_TEST_TEAM", "0")
    off = Kernel(team_source, switch="NEURAL_BAKE_TEST_TEAM", declare=_declare, openmp=True)
    assert off.lib() is None and off.status() == "numpy (off (NEURAL_BAKE_TEST_TEAM=0))"


def test_threads_follows_torch(monkeypatch):
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert threads() == 1
        torch.set_num_threads(2)
        assert threads() == 2
    finally:
        torch.set_num_threads(before)
