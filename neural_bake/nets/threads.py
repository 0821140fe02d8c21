"""How many threads torch's CPU kernels use: chosen by timing the work itself, and followed as the load changes.

torch starts one intra-op thread per core and splits each kernel among them; when another program takes one
of the cores, every kernel waits for the thread that shares it, and the work slows down many times instead of
by the share that was taken. Fewer threads than cores then run faster. Which count is fastest depends on
the machine as it is and on the work, so it is measured, not assumed:

- :func:`choose_threads` times a slice of the work about to run (a field evaluation, a few training steps)
  with 1 … usable cores threads and keeps the fastest (:class:`ThreadChoice` says what ran);
- :class:`ThreadTuner` does the same inside a loop, with the loop's own steps as the trials (no work is
  thrown away), then watches the step time and probes again when its median drifts by more than
  ``drift`` (a program started beside it), and again every ``reprobe`` seconds while it runs with fewer
  threads than cores (a program that stopped: fewer threads do not slow down when it does);
- ``NEURAL_BAKE_THREADS`` = N (or ``auto``, the default) fixes the count for every command, as the CLI's
  global ``--threads N`` does. On a device other than the CPU nothing is changed.

The clock is injectable everywhere (tests drive the decisions with a simulated one).
"""

from __future__ import annotations

import os
import statistics
import time
from dataclasses import dataclass, field
from typing import Callable

import torch

from ..constants import (THREAD_ABORT_FACTOR, THREAD_DECISIVE, THREAD_DRIFT, THREAD_MARGIN, THREAD_PROBE_INTERVAL_S,
                         THREAD_PROBE_SHARE, THREAD_REPROBE_S, THREAD_TRIAL_STEPS, THREAD_WARMUP_STEPS, THREAD_WINDOW)
from ..errors import NeuralBakeError
from .heap import wait_reserved

__all__ = ["ENV_THREADS", "ENV_MAX_THREADS", "ThreadChoice", "ThreadTuner", "choose_threads", "fixed_threads", "usable_cores",
           "thread_candidates"]

#: Environment variable fixing the thread count ("auto" or unset: measured).
ENV_THREADS = "NEURAL_BAKE_THREADS"

#: Environment variable capping the counts a probe tries (a batch worker's share of the cores).
ENV_MAX_THREADS = "NEURAL_BAKE_MAX_THREADS"


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not Linux
        return max(1, os.cpu_count() or 1)


def fixed_threads(env: str | None = None) -> int | None:
    """The thread count ``NEURAL_BAKE_THREADS`` fixes (``env``: its value, default from the environment), or
    None for "auto"; :class:`NeuralBakeError` naming the variable for anything else."""
    value = (os.environ.get(ENV_THREADS, "") if env is None else env).strip().lower()
    if value in ("", "auto"):
        return None
    try:
        n = int(value)
    except ValueError:
        n = 0
    if not 1 <= n <= 4096:
        raise NeuralBakeError(f"{ENV_THREADS}={value!r}: must be auto or a thread count from 1 to 4096",
                              parameter=ENV_THREADS)
    return n


def thread_candidates(cores: int | None = None) -> tuple[int, ...]:
    """The counts a probe tries: 1 … ``cores`` (default :func:`usable_cores`, capped by
    ``NEURAL_BAKE_MAX_THREADS`` when set), at most 8 of them (the powers of two and ``cores`` itself on large
    machines), largest first."""
    if cores is None:
        cores = usable_cores()
        cap = os.environ.get(ENV_MAX_THREADS, "").strip()
        if cap.isdigit() and int(cap) >= 1:
            cores = min(cores, int(cap))
    n = max(1, int(cores))
    if n <= 8:
        return tuple(range(n, 0, -1))
    counts = {n, *[2**k for k in range(0, n.bit_length()) if 2**k <= n]}
    return tuple(sorted(counts, reverse=True)[:8])


@dataclass
class ThreadChoice:
    """What a thread probe decided: ``threads`` (the count in force), ``reason`` (one line), the seconds per
    trial of each count tried (``seconds``; empty when fixed) and how the count was set (``how``: "measured",
    "fixed" by ``NEURAL_BAKE_THREADS`` / ``--threads``, or "device" when the work is not on the CPU)."""

    threads: int
    reason: str
    seconds: dict[int, float] = field(default_factory=dict)
    how: str = "measured"

    def as_dict(self) -> dict:
        return {"threads": self.threads, "how": self.how, "reason": self.reason,
                "seconds_per_trial": {str(k): v for k, v in self.seconds.items()}}


def _best(seconds: dict[int, float]) -> int:
    """The fastest count, unless a larger count is within :data:`~neural_bake.constants.THREAD_MARGIN` of it
    (then the largest such: a short probe's noise must not take threads from a quiet machine; a busy
    neighbour makes the extra threads several times slower, far beyond the margin)."""
    fastest = min(seconds.values())
    return max(n for n, s in seconds.items() if s <= fastest * THREAD_MARGIN)


def choose_threads(work: Callable[[], object], *, device: torch.device | str = "cpu", repeats: int = 2,
                   candidates: tuple[int, ...] | None = None, clock: Callable[[], float] = time.perf_counter,
                   env: str | None = None) -> ThreadChoice:
    """Set torch's thread count to the fastest for ``work`` (a representative slice of what is about to run,
    called ``1 + repeats`` times per count: one warm-up, then the best of ``repeats`` timed rounds) and return
    the choice. The rounds stop early once one count is faster than every other by
    :data:`~neural_bake.constants.THREAD_DECISIVE` (a busy neighbour, or threads that pay, show that at once).

    A fixed count (``NEURAL_BAKE_THREADS``, or ``env``) is set without timing anything; work on a device
    other than the CPU leaves the setting alone.
    """
    fixed = fixed_threads(env)
    if torch.device(device).type != "cpu":
        return ThreadChoice(torch.get_num_threads(), f"work on {torch.device(device).type}: CPU threads unchanged",
                            how="device")
    if fixed is not None:
        torch.set_num_threads(fixed)
        return ThreadChoice(fixed, f"{ENV_THREADS}={fixed}", how="fixed")
    counts = candidates or thread_candidates()
    wait_reserved()  # pages being faulted in on another thread would look like a busy neighbour (nets.heap)
    seconds: dict[int, float] = {}
    for n in counts:  # the warm-ups: a count's first call starts its threads
        torch.set_num_threads(n)
        work()
    for _ in range(max(1, int(repeats))):  # rounds, the counts in turn
        if len(seconds) > 1 and _decisive(seconds):
            break
        for n in counts:
            torch.set_num_threads(n)
            t0 = clock()
            work()
            seconds[n] = min(seconds.get(n, float("inf")), clock() - t0)
    pick = _best(seconds)
    torch.set_num_threads(pick)
    return ThreadChoice(pick, _reason(pick, seconds), seconds)


def _decisive(seconds: dict[int, float]) -> bool:
    """True when the fastest count beats every other by :data:`~neural_bake.constants.THREAD_DECISIVE`."""
    times = sorted(seconds.values())
    return times[1] >= THREAD_DECISIVE * times[0]


def _reason(pick: int, seconds: dict[int, float]) -> str:
    if len(seconds) == 1:
        return f"{pick} thread{'s' if pick > 1 else ''}: the only count to try"
    tried = ", ".join(f"{n}: {1e3 * s:.1f} ms" for n, s in sorted(seconds.items()))
    return f"{pick} thread{'s' if pick > 1 else ''} measured fastest ({tried})"


class ThreadTuner:
    """Chooses the thread count of a loop from the loop's own steps, and probes again when the step time drifts.

    Call :meth:`before_step` before each step (it sets the thread count the step runs with) and
    :meth:`after_step` with the step's seconds. The first ``warmup`` steps run untimed (a loop's first steps
    pay one-time costs) on every candidate thread, or on the count :func:`choose_threads` finds fastest for
    ``initial`` (a small slice of the loop's work: a busy neighbour then does not slow those costs too).
    Then a probe runs ``trial_steps`` steps per candidate count, the count in force first (the first step
    after a switch is not counted: new threads warm up; a count whose first step is already
    :data:`~neural_bake.constants.THREAD_ABORT_FACTOR` × slower than the best so far is not tried further),
    and keeps the fastest (:func:`_best`). Then the median of the last ``window`` step times is watched:
    beyond ``drift`` × (or below 1 / ``drift`` ×) the median the choice was made with, and at least
    ``interval`` seconds (by ``clock``) after the last probe, a new probe starts; so does one every
    ``reprobe`` seconds while fewer threads than the largest candidate run (their step time does not show
    that a neighbour stopped), or less often when the last probe cost more than
    :data:`~neural_bake.constants.THREAD_PROBE_SHARE` of that time. ``history`` lists every decision (step,
    threads, seconds per step of each count); ``threads_used`` the counts that ran. With a fixed count
    (``NEURAL_BAKE_THREADS``) or ``device`` not the CPU it never probes.
    """

    def __init__(self, *, device: torch.device | str = "cpu", candidates: tuple[int, ...] | None = None,
                 trial_steps: int = THREAD_TRIAL_STEPS, window: int = THREAD_WINDOW, drift: float = THREAD_DRIFT,
                 interval: float = THREAD_PROBE_INTERVAL_S, reprobe: float = THREAD_REPROBE_S,
                 warmup: int = THREAD_WARMUP_STEPS, initial: Callable[[], object] | None = None,
                 clock: Callable[[], float] = time.perf_counter, env: str | None = None,
                 on_change: Callable[[int], None] | None = None):
        if isinstance(trial_steps, bool) or int(trial_steps) != trial_steps or trial_steps < 1:
            raise NeuralBakeError(f"trial_steps must be a positive integer, got {trial_steps!r}",
                                  parameter="trial_steps")
        if not (drift > 1):
            raise NeuralBakeError(f"drift must be a factor above 1, got {drift!r}", parameter="drift")
        self.clock, self.on_change = clock, on_change
        self.trial_steps, self.window, self.drift = int(trial_steps), int(window), float(drift)
        self.interval, self.reprobe = float(interval), float(reprobe)
        self.fixed = fixed_threads(env)
        self.active = torch.device(device).type == "cpu" and self.fixed is None
        self.candidates = tuple(candidates or thread_candidates()) if self.active else ()
        self.history: list[dict] = []
        self.threads_used: set[int] = set()
        self.step = 0
        self.threads = torch.get_num_threads()
        if torch.device(device).type == "cpu" and self.fixed is not None:
            self._set(self.fixed)
            self.history.append({"step": 0, "threads": self.fixed, "how": "fixed", "seconds_per_step": {}})
        self._recent: list[float] = []
        self._reference: float | None = None
        self._last_probe = -float("inf")
        self._reprobe_after = self.reprobe
        self._probe: dict | None = None
        self._warm = 0
        self.initial: ThreadChoice | None = None
        if self.active and len(self.candidates) > 1:
            # the first steps of a loop pay one-time costs (pools, compiles, tunings): they are not timed, and
            # run on every candidate thread, or on the count a quick probe of ``initial`` (a slice of the
            # loop's work, timed in real seconds) finds fastest; the first probe of the steps follows them
            self._warm = int(warmup)
            self._set(max(self.candidates))
            if initial is not None:
                try:
                    self.initial = choose_threads(initial, candidates=self.candidates, env="auto")
                except (RuntimeError, TypeError, ValueError):  # a slice the model cannot run: no quick probe
                    torch.set_num_threads(max(self.candidates))
                else:
                    self._set(self.initial.threads)
            if self._warm == 0:
                self._start_probe("start")
        elif self.active:
            self.history.append({"step": 0, "threads": self.candidates[0], "how": "measured", "reason": "start",
                                 "seconds_per_step": {}})
            self._set(self.candidates[0])

    def _set(self, n: int) -> None:
        if n != torch.get_num_threads():
            torch.set_num_threads(n)
        changed = n != self.threads
        self.threads = n
        self.threads_used.add(n)
        if changed and self.on_change is not None:
            self.on_change(n)

    def _start_probe(self, why: str) -> None:
        order = [self.threads] + [n for n in self.candidates if n != self.threads] \
            if self.threads in self.candidates else list(self.candidates)
        self._probe = {"order": order, "times": {}, "current": [], "why": why, "start": self.clock(), "steps": 0}
        self._last_probe = self.clock()
        self._set(order[0])

    def before_step(self) -> int:
        """The thread count this step runs with (already set in torch)."""
        return self.threads

    def after_step(self, seconds: float) -> None:
        """Record the seconds of the step just run (and switch counts during a probe)."""
        self.step += 1
        if not self.active:
            return
        if self._warm > 0:
            self._warm -= 1
            if self._warm == 0:
                self._start_probe("start")
            return
        probe = self._probe
        if probe is not None:
            probe["current"].append(float(seconds))
            probe["steps"] += 1
            # the first step after a switch is the warm-up; one already far slower than the best count ends
            # this count's trial (a probe under load must not run many slow steps)
            slow = len(probe["current"]) == 1 and probe["times"] and \
                seconds > THREAD_ABORT_FACTOR * min(probe["times"].values())
            if slow or len(probe["current"]) > self.trial_steps:
                n = probe["order"].pop(0)
                probe["times"][n] = float(seconds) if slow else statistics.median(probe["current"][1:])
                probe["current"] = []
                if probe["order"]:
                    self._set(probe["order"][0])
                else:
                    pick = _best(probe["times"])
                    self.history.append({"step": self.step, "threads": pick, "how": "measured",
                                         "reason": probe["why"],
                                         "seconds_per_step": {str(k): v for k, v in probe["times"].items()}})
                    self._reference = probe["times"][pick]
                    # what the probe cost beyond running its steps at the chosen count: the periodic probe
                    # waits long enough for that to stay under THREAD_PROBE_SHARE of the loop's time
                    cost = max(0.0, self.clock() - probe["start"] - probe["steps"] * self._reference)
                    self._reprobe_after = max(self.reprobe, cost / THREAD_PROBE_SHARE)
                    self._recent = []
                    self._probe = None
                    self._set(pick)
            return
        self._recent.append(float(seconds))
        if len(self._recent) > self.window:
            self._recent.pop(0)
        if len(self._recent) < self.window or self._reference is None:
            return
        median = statistics.median(self._recent)
        ratio = median / max(self._reference, 1e-12)
        since = self.clock() - self._last_probe
        if (ratio > self.drift or ratio < 1.0 / self.drift) and since >= self.interval:
            self._start_probe(f"step time {ratio:.2f}× the last choice's")
        elif self.threads < max(self.candidates) and since >= self._reprobe_after:
            self._start_probe(f"{since:.0f} s with {self.threads} of {max(self.candidates)} threads")

    def summary(self) -> dict:
        """JSON-ready: the count in force, every count that ran, and each decision."""
        return {"threads": self.threads, "threads_used": sorted(self.threads_used),
                "how": "fixed" if self.fixed is not None else ("measured" if self.active else "device"),
                "initial": None if self.initial is None else self.initial.as_dict(), "decisions": self.history}
