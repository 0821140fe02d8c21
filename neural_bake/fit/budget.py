"""Honest time budgets: the steps a time-budgeted fit made beside the steps its preset makes on this machine.

A preset's cost per step is stored as machine-independent work: :data:`STEP_WORK` (GFLOP-equivalents, the
step's seconds on a reference machine times that machine's sgemm rate). At the start of a budgeted fit
:func:`probe_gflops` times 30 512³ float32 GEMMs and takes the best of them and of the best rate this machine
(CPU model, thread count) has shown before (kept in a small cache file): the machine's speed, not its current
share of it, which a busy machine cuts. :func:`expected_steps` = budget seconds × rate / work. A fit that made fewer than
:data:`~neural_bake.constants.BUDGET_WARN_FRACTION` of them was slowed by something else (other processes,
a throttled machine): :func:`budget_record` says so in one line, and the fitters record both figures in the
model file.
"""

from __future__ import annotations

import functools
import time
from typing import Callable

import torch

from ..constants import BUDGET_SAMPLING_SHARE, BUDGET_WARN_FRACTION, MIN_SECONDS

__all__ = ["STEP_WORK", "probe_gflops", "expected_steps", "budget_record", "fit_budget", "stop_note", "cache_file"]

#: GFLOP-equivalents of one Adam step per preset (seconds per step × sgemm GFLOP/s of the machine it was
#: measured on; BENCHMARKS.md, "Honest budgets"). SDF presets by name ("quick", "high", "WxD"), texture
#: presets by "texture:NAME". Measured on a quiet machine (BENCHMARKS.md): 64x1, texture:default ((192,3),
#: λ = 0: the median of five fits of the tea set, the cabinet and Spot) and texture:quick ((64,1), λ = 0: the
#: tea set), quick
#: (192x3, uncompiled: the median of eight meshes, 52–101 ms a step), default (192x3, compiled: nefertiti,
#: 5,862 steps in 5 minutes), high (256x4, compiled: nefertiti) and
#: 256x3 (9,109–9,363 steps in the Adam part of 10 minutes on four meshes, float32 GEMMs on oneDNN). 128x2 and
#: 256x2 are estimates between the measured compiled and uncompiled costs (the loss is compiled for budgets of
#: five minutes or more); texture:high is its cost with the orthogonality term divided by what the term cost
#: (128,2) on Spot (1.74×).
STEP_WORK: dict[str, float] = {
    "quick": 12.3,
    "default": 11.2,
    "high": 21.4,
    "64x1": 1.76,
    "128x2": 4.2,
    "256x2": 16.7,
    "256x3": 14.1,
    "texture:quick": 0.38,
    "texture:default": 3.6,
    "texture:high": 7.4,
}


@functools.lru_cache(maxsize=None)
def _probe_cached(size: int, repeat: int, threads: int) -> float:
    rate = _probe(size, repeat, time.perf_counter)
    return _best_seen(f"{_cpu_name()}|{threads}|{size}", rate)


def _cpu_name() -> str:
    import platform

    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def cache_file():
    """The file keeping the best sgemm rate seen per machine: ``$NEURAL_BAKE_CACHE_DIR/gflops.json`` (default
    ``$XDG_CACHE_HOME/neural_bake`` or ``~/.cache/neural_bake``)."""
    import os
    from pathlib import Path

    base = os.environ.get("NEURAL_BAKE_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "neural_bake")
    return Path(base) / "gflops.json"


def _best_seen(key: str, rate: float) -> float:
    """max(rate, the best rate recorded under ``key``); records it when higher. An unreadable or unwritable
    cache only loses the record (the probe's own rate is used)."""
    import json

    from ..io.atomic import atomic_write_text

    path = cache_file()
    try:
        seen = json.loads(path.read_text(encoding="utf-8"))
        seen = seen if isinstance(seen, dict) else {}
    except (OSError, ValueError):
        seen = {}
    best = seen.get(key)
    best = float(best) if isinstance(best, (int, float)) and best > 0 else 0.0
    if rate > best:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, json.dumps({**seen, key: rate}, indent=1))
        except OSError:
            pass
    return max(rate, best)


def _probe(size: int, repeat: int, clock: Callable[[], float]) -> float:
    g = torch.Generator().manual_seed(0)
    a = torch.rand(size, size, generator=g)
    b = torch.rand(size, size, generator=g)
    torch.mm(a, b)  # warm-up: first-call costs are not the machine's speed
    best = float("inf")
    for _ in range(repeat):
        t0 = clock()
        torch.mm(a, b)
        best = min(best, clock() - t0)
    return 2.0 * size**3 / max(best, MIN_SECONDS) / 1e9


def probe_gflops(size: int = 512, repeat: int = 30, *, clock: Callable[[], float] | None = None) -> float:
    """The sgemm rate of this machine in GFLOP/s: the best of ``repeat`` ``size``³ float32 products on torch's
    current threads and of the best rate recorded for this CPU model and thread count (:func:`cache_file`).
    Measured once per process (per size, repeat and thread count); with ``clock`` measured each call, with
    that clock, and neither read nor recorded."""
    if clock is not None:
        return _probe(size, repeat, clock)
    return _probe_cached(int(size), int(repeat), torch.get_num_threads())


def expected_steps(preset: str | None, seconds: float | None, gflops: float | None = None) -> int | None:
    """Adam steps ``preset`` (a :data:`STEP_WORK` key) makes in ``seconds`` on a machine of ``gflops``
    (default: :func:`probe_gflops`); None for a preset without a reference or a run without a budget."""
    if preset not in STEP_WORK or not seconds or seconds <= 0:
        return None
    rate = probe_gflops() if gflops is None else float(gflops)
    return int(seconds * rate / STEP_WORK[preset])


def budget_record(steps: int, expected: int | None, *, preset: str | None = None, seconds: float | None = None,
                  gflops: float | None = None, stopped_reason: str | None = None,
                  sampling_share: float | None = None) -> dict:
    """The budget's account, JSON-ready: ``steps`` made, ``expected`` (None: no reference), their ``ratio``,
    the ``gflops`` probe, ``sampling_share`` (the part of the fit's time spent drawing training samples, or
    None when not measured), and ``warning``: one line when fewer than half the expected steps were
    made (None otherwise), naming the sampling as the cause when it took at least
    :data:`~neural_bake.constants.BUDGET_SAMPLING_SHARE` of the budget, else a busy or slowed machine. A run
    that stopped at its step cap is not short of time and gets no warning."""
    ratio = None if not expected else steps / expected
    share = None if sampling_share is None else float(sampling_share)
    warning = None
    if ratio is not None and ratio < BUDGET_WARN_FRACTION and stopped_reason != "steps":
        why = (f"drawing training samples took {100 * share:.0f} % of its time (an open mesh's winding "
               "numbers are costly)" if share is not None and share >= BUDGET_SAMPLING_SHARE
               else "the machine was busy or slowed")
        warning = (f"{preset or 'fit'}: made {steps} steps of the ~{expected} this machine makes in "
                   f"{seconds or 0:.0f} s ({100 * ratio:.0f} %): {why}; the fit is weaker than the preset's")
    return {"preset": preset, "steps": int(steps), "expected_steps": expected, "ratio": ratio,
            "budget_seconds": seconds, "gflops": gflops, "sampling_share": share, "warning": warning}


def stop_note(stopped_reason: str, steps: int, seconds: float, minutes: float | None, step_cap: int) -> str:
    """Why a fit stopped, in words: its time budget, or its step cap (and how much of the budget was left)."""
    if stopped_reason == "time budget":
        return f"time budget ({60 * minutes:.0f} s) used"
    if stopped_reason == "steps" and minutes:
        return f"step cap ({step_cap}) reached after {seconds:.1f} s of the {60 * minutes:.0f}-s budget"
    if stopped_reason == "steps":
        return f"step count ({step_cap}) done"
    return stopped_reason


def fit_budget(preset: str | None, *, steps: int, seconds: float, minutes: float | None, step_cap: int,
               stopped_reason: str, budget_seconds: float | None = None,
               sampling_share: float | None = None) -> dict | None:
    """The budget account of a finished fit (:func:`budget_record` plus ``stopped``: :func:`stop_note`), and
    its warning issued as a :class:`~neural_bake.errors.NeuralBakeWarning`; None for a fit without a time
    budget. ``budget_seconds``: the part of the budget the counted steps had (default: all of it);
    ``sampling_share``: the part of the steps' time spent drawing training samples (None: not measured)."""
    if not minutes:
        return None
    import warnings

    from ..errors import NeuralBakeWarning

    span = 60.0 * minutes if budget_seconds is None else budget_seconds
    gflops = probe_gflops() if preset in STEP_WORK else None
    rec = budget_record(steps, expected_steps(preset, span, gflops), preset=preset, seconds=span, gflops=gflops,
                        stopped_reason=stopped_reason, sampling_share=sampling_share)
    rec["stopped"] = stop_note(stopped_reason, steps, seconds, minutes, step_cap)
    if rec["warning"]:
        warnings.warn(rec["warning"], NeuralBakeWarning, stacklevel=3)
    return rec
