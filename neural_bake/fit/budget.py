"""Honest time budgets: the steps a time-budgeted fit made beside the steps its preset makes on this machine.

A preset's cost per step is stored as machine-independent work: :data:`STEP_COST`, in reference steps (a
preset step's seconds over the seconds of :class:`ReferenceStep`, a small Siren's training step through the
same loss, measured on the same machine). A fit step is not GEMM-bound: its sines, element-wise products and
autograd bookkeeping take as much time as its products, and how the two compare differs between CPUs (a
bare-GEMM probe read one CPU 1.8× faster than another where the fits ran 1.1× faster), so the probe times a
step of the same kind. At the start of a budgeted fit :func:`probe_rate` times the reference step and takes
the best of its readings and of the best rate this machine (CPU model, thread count) has shown before (kept
in a small cache file): the machine's speed, not its current share of it, which a busy machine cuts.
:func:`expected_steps` = budget seconds / (cost / rate + the asset's own seconds a step): a fit also pays
for work that grows with its mesh (an SDF fit's pool builds and refreshes, hard-example and zero-set mining:
distance queries and winding numbers against the mesh), which a cost measured on small meshes does not hold,
so the fit times that work on its own clock and the expected steps are this machine's for this asset. A fit
that made fewer than :data:`~neural_bake.constants.BUDGET_WARN_FRACTION` of them was slowed by something else
(other processes, a throttled machine: its steps' own work took over twice the quiet step's time):
:func:`budget_record` says so in one line, and the fitters record both figures in the model file.

A ``budget="steps"`` fit runs instead the steps its preset makes in its budget on the quiet reference machine
(:data:`~neural_bake.fit.presets.REFERENCE_STEPS`), so its result does not depend on the load; its time is
then the estimate (:func:`steps_budget`).
"""

from __future__ import annotations

import functools
import time
from typing import Callable

import torch

from ..constants import BUDGET_SAMPLING_SHARE, BUDGET_WARN_FRACTION, MIN_SECONDS
from ..nets.machine import cpu_model, machine_cache_dir, read_facts, write_fact

__all__ = ["STEP_COST", "REFERENCE_STEP", "TILE_STEP", "TILE_STEP_COST", "ReferenceStep", "probe_rate", "expected_steps",
           "tile_level_cost", "step_cost",
           "budget_record", "fit_budget", "steps_budget", "reference_steps", "stop_note", "cache_file"]

#: The reference step's network and batch: a (width, depth) Siren, points per step (half on the surface).
REFERENCE_STEP = (128, 2, 4096)

#: Reference steps (:class:`ReferenceStep`) in one Adam step per preset (a step's seconds × the reference
#: rate, both on one quiet machine: BENCHMARKS.md, "Honest budgets"). SDF presets by name ("quick", "high",
#: "WxD"), the levels of a preset's construction by "PRESET/coarse" and "PRESET/fine" (:mod:`.residual`; the
#: "quick" entry is its plain 192x3 network's), texture presets by "texture:NAME". Measured: quick/coarse (64x3)
#: and quick/fine (128x3 on the coarse level) in one ``neural-bake bench budget`` run, quiet; default's and
#: high's levels (64x3 with zero-set mining and 128x3; 64x4 and 192x4) against quick's in another, scaled by
#: quick's levels' table ÷ measured (uncompiled; high's fine level compiles at its 9 minutes, so it makes
#: more steps than its cost predicts); quick (192x3,
#: loss not compiled: nefertiti, the tea set and Spot in 2 minutes, plainly), default (192x3, compiled: the
#: tea set and Spot in 5 minutes), high (256x4, compiled: nefertiti in 10 minutes), texture:quick and
#: texture:default (their feature grids, in ``neural-bake bench budget``; since scaled by the step time the
#: grid's C kernel and the fused Adam update saved, 1.94× and 2.20×, then the loop's cheaper finiteness check,
#: 1.50× and 1.53×, old against new on one machine; texture:default's 64x2 MLP, 1.15× its 64x1's). 64x1,
#: 128x2, 256x3 and 256x2 keep ratios to quick and default measured elsewhere; texture:high its ratio to
#: texture:default in ``neural-bake bench budget``, which checks the whole table on the machine it runs on.
STEP_COST: dict[str, float] = {
    "quick": 5.15,
    "quick/coarse": 1.46,
    "quick/fine": 2.67,
    "default": 3.90,
    "default/coarse": 1.63,
    "default/fine": 2.99,
    "high": 7.0,
    "high/coarse": 2.07,
    "high/fine": 5.78,
    "64x1": 0.74,
    "128x2": 1.46,
    "256x2": 3.93,
    "256x3": 4.91,
    "texture:quick": 0.63,
    "texture:default": 0.75,
    "texture:high": 1.41,
}

#: The tiles :data:`TILE_STEP_COST` was measured with: (width, depth, points a tile a step).
TILE_STEP = (64, 2, 576)

#: Reference steps in one step of a tile level (:mod:`~neural_bake.fit.tiles`), per tile, for the tiles of
#: :data:`TILE_STEP`: a tile level's step time over the reference step's, ÷ its tiles, quiet (how it was
#: measured, and ``neural-bake bench budget --preset tile`` beside it: BENCHMARKS.md, "budget").
TILE_STEP_COST = 0.090


class ReferenceStep:
    """One training step of the reference network (:data:`REFERENCE_STEP`) through the SDF loss, called as
    ``step()``: forward with the closed-form gradient, the loss, one backward (no optimiser). Its network
    (``model``) and inputs are made once, so a call is the step's own work."""

    def __init__(self, generator: torch.Generator | None = None):
        from ..nets.siren import Siren
        from .sdf_config import SdfFitConfig
        from .sdf_loss import sdf_loss_terms

        self._loss = sdf_loss_terms
        width, depth, n = REFERENCE_STEP
        g = generator or torch.Generator().manual_seed(0)
        self.model = Siren(width, depth, generator=g)
        self._surf = torch.rand(n // 2, 3, generator=g) * 2 - 1
        self._normals = torch.nn.functional.normalize(torch.randn(n // 2, 3, generator=g), dim=1)
        self._vol = torch.rand(n - n // 2, 3, generator=g) * 2 - 1
        self._dist = torch.rand(n - n // 2, generator=g) * 0.1
        self._cfg = SdfFitConfig()

    def __call__(self) -> None:
        self.model.zero_grad(set_to_none=True)
        self._loss(self.model, self._surf, self._normals, self._vol, self._dist, self._cfg)["loss"].backward()


@functools.lru_cache(maxsize=None)
def _probe_cached(repeat: int, threads: int) -> float:
    rate = _probe(repeat, time.perf_counter)
    width, depth, n = REFERENCE_STEP
    return _best_seen(f"{cpu_model()}|{threads}|siren {width}x{depth} {n}", rate)


def cache_file():
    """The file keeping the best reference-step rate seen per machine: ``$NEURAL_BAKE_CACHE_DIR/step_rate.json``
    (default ``$XDG_CACHE_HOME/neural_bake`` or ``~/.cache/neural_bake``)."""
    return machine_cache_dir() / _STEP_RATE_FILE


#: The file of :func:`cache_file` (in :func:`~neural_bake.nets.machine.machine_cache_dir`).
_STEP_RATE_FILE = "step_rate.json"


def _best_seen(key: str, rate: float) -> float:
    """max(rate, the best rate recorded under ``key``); records it when higher. An unreadable or unwritable
    cache only loses the record (the probe's own rate is used)."""
    best = read_facts(_STEP_RATE_FILE).get(key)
    best = float(best) if isinstance(best, (int, float)) and best > 0 else 0.0
    if rate > best:
        write_fact(_STEP_RATE_FILE, key, rate)
    return max(rate, best)


def _probe(repeat: int, clock: Callable[[], float]) -> float:
    step = ReferenceStep()
    for _ in range(3):  # warm-up: first-call costs and a cold cache are not the machine's speed
        step()
    best = float("inf")
    for _ in range(repeat):
        t0 = clock()
        step()
        best = min(best, clock() - t0)
    return 1.0 / max(best, MIN_SECONDS)


def probe_rate(repeat: int = 30, *, clock: Callable[[], float] | None = None) -> float:
    """This machine's speed in reference steps (:class:`ReferenceStep`) per second: the best of ``repeat``
    timed steps on torch's current threads and of the best rate recorded for this CPU model and thread count
    (:func:`cache_file`). Measured once per process (per repeat and thread count); with ``clock`` measured
    each call, with that clock, and neither read nor recorded."""
    if clock is not None:
        return _probe(int(repeat), clock)
    return _probe_cached(int(repeat), torch.get_num_threads())


def step_cost(step: Callable[[], None], repeat: int = 5, *, clock: Callable[[], float] | None = None) -> float:
    """Reference steps (:class:`ReferenceStep`) in one call of ``step``, for a fit without a :data:`STEP_COST`
    entry: the best of ``repeat`` timed calls over the best of as many reference steps, the two interleaved so
    that whatever else the machine runs slows both alike (``clock``: default ``time.perf_counter``)."""
    clock = clock or time.perf_counter
    ref = ReferenceStep()
    for _ in range(2):  # warm-up of both
        step()
        ref()
    best_step = best_ref = float("inf")
    for _ in range(max(1, int(repeat))):
        t0 = clock()
        step()
        t1 = clock()
        ref()
        t2 = clock()
        best_step, best_ref = min(best_step, t1 - t0), min(best_ref, t2 - t1)
    return max(best_step, MIN_SECONDS) / max(best_ref, MIN_SECONDS)


def expected_steps(preset: str | None, seconds: float | None, rate: float | None = None,
                   asset_seconds: float | None = None, *, cost: float | None = None) -> int | None:
    """Adam steps ``preset`` (a :data:`STEP_COST` key) makes in ``seconds`` on a machine making ``rate``
    reference steps a second (default: :func:`probe_rate`) when each step also pays ``asset_seconds`` of the
    asset's own work (its sampling; None: none); None for a preset without a reference or a run without a
    budget. ``cost``: the step's reference steps instead of the preset's (a tile level's, which grows with
    its number of tiles: :func:`tile_level_cost`)."""
    cost = STEP_COST.get(preset) if cost is None and preset is not None else cost
    if cost is None or not seconds or seconds <= 0:
        return None
    rate = probe_rate() if rate is None else float(rate)
    return int(seconds / (cost / rate + max(0.0, float(asset_seconds or 0.0))))


def tile_level_cost(tiles: int, width: int, depth: int, points: int) -> float | None:
    """Reference steps in one step of a tile level of ``tiles`` networks (:mod:`~neural_bake.fit.tiles`): the
    number of tiles × :data:`TILE_STEP_COST` for the tiles it was measured with (:data:`TILE_STEP`); None for
    other tiles (no reference)."""
    if (int(width), int(depth), int(points)) != TILE_STEP or tiles < 1:
        return None
    return int(tiles) * TILE_STEP_COST


def reference_steps(preset: str | None) -> int | None:
    """The Adam steps ``preset`` (a :data:`STEP_COST` key) makes in its budget on the quiet reference machine
    (:data:`~neural_bake.fit.presets.REFERENCE_STEPS`); None for a preset without a reference."""
    from .presets import REFERENCE_STEPS

    return REFERENCE_STEPS.get(preset) if preset is not None else None


def budget_record(steps: int, expected: int | None, *, preset: str | None = None, seconds: float | None = None,
                  rate: float | None = None, stopped_reason: str | None = None,
                  sampling_share: float | None = None, what: str | None = None,
                  step_seconds: float | None = None, asset_seconds: float | None = None,
                  compute_seconds: float | None = None, preset_steps: int | None = None) -> dict:
    """The budget's account, JSON-ready: ``budget`` ("time"), ``steps`` made, ``expected`` (the steps this
    machine makes for this asset; None: no reference), their ``ratio``, the probe's ``reference_rate``
    (reference steps a second), ``sampling_share`` (the part of the fit's time spent drawing training samples,
    or None when not measured), ``step_seconds`` (the preset's step on this machine, quiet: cost / rate),
    ``asset_seconds_per_step`` (the asset's own work a step, measured; counted in ``expected``),
    ``compute_seconds_per_step`` (the steps' own work, measured), ``preset_steps`` (the steps without the
    asset's work), ``note``: one line when the asset's own work took at least
    :data:`~neural_bake.constants.BUDGET_SAMPLING_SHARE` of the time (None otherwise), and ``warning``: one
    line when fewer than half the expected steps were made (None otherwise): the machine was busy or slowed,
    with how much slower than quiet its steps' own work ran when measured. A run that stopped at its step cap
    is not short of time and gets no warning. ``what``: the fit the warning names (default: the preset)."""
    ratio = None if not expected else steps / expected
    share = None if sampling_share is None else float(sampling_share)
    warning = note = None
    name = what or preset or "fit"
    if ratio is not None and ratio < BUDGET_WARN_FRACTION and stopped_reason != "steps":
        why = "the machine was busy or slowed"
        if compute_seconds and step_seconds:
            why = (f"its steps' own work took {compute_seconds / step_seconds:.1f}× the "
                   f"{1e3 * step_seconds:.1f} ms this machine takes for one when quiet: {why}")
        warning = (f"{name}: made {steps} steps of the ~{expected} this machine makes in "
                   f"{seconds or 0:.0f} s ({100 * ratio:.0f} %): {why}; the fit is weaker than the preset's")
    if share is not None and share >= BUDGET_SAMPLING_SHARE and asset_seconds is not None:
        note = (f"{name}: drawing training samples (this mesh's pools and mined points) took {100 * share:.0f} % "
                f"of its time; the ~{expected} steps expected count it"
                + (f" (~{preset_steps} without it)" if preset_steps is not None else ""))
    return {"budget": "time", "preset": preset, "steps": int(steps), "expected_steps": expected, "ratio": ratio,
            "budget_seconds": seconds, "reference_rate": rate, "sampling_share": share,
            "step_seconds": step_seconds, "asset_seconds_per_step": asset_seconds,
            "compute_seconds_per_step": compute_seconds, "preset_steps": preset_steps, "note": note,
            "warning": warning}


def stop_note(stopped_reason: str, steps: int, seconds: float, minutes: float | None, step_cap: int) -> str:
    """Why a fit stopped, in words: its time budget, or its step cap (and how much of the budget was left)."""
    if stopped_reason == "time budget":
        return f"time budget ({60 * minutes:.0f} s) used"
    if stopped_reason == "steps" and minutes:
        return f"step cap ({step_cap}) reached after {seconds:.1f} s of the {60 * minutes:.0f}-s budget"
    if stopped_reason == "steps":
        return f"step count ({step_cap}) done"
    return stopped_reason


def _full_rate() -> float:
    """:func:`probe_rate` with every usable thread (the count a quiet machine runs), whatever count the fit
    chose under load: the expected steps are the machine's, not its busy share's. Threads restored after."""
    from ..nets.threads import thread_candidates

    before = torch.get_num_threads()
    full = thread_candidates()[0]
    if full == before:
        return probe_rate()
    torch.set_num_threads(full)
    try:
        return probe_rate()
    finally:
        torch.set_num_threads(before)


def fit_budget(preset: str | None, *, steps: int, seconds: float, minutes: float | None, step_cap: int,
               stopped_reason: str, budget_seconds: float | None = None,
               sampling_share: float | None = None, asset_seconds: float | None = None,
               compute_seconds: float | None = None, cost: float | None = None, what: str | None = None
               ) -> dict | None:
    """The budget account of a finished fit (:func:`budget_record` plus ``stopped``: :func:`stop_note`), and
    its warning issued as a :class:`~neural_bake.errors.NeuralBakeWarning`; None for a fit without a time
    budget. ``budget_seconds``: the part of the budget the counted steps had (default: all of it);
    ``sampling_share``: the part of the steps' time spent drawing training samples; ``asset_seconds``: the
    seconds a step spent on the asset's own work (sampling that grows with the mesh), counted in the expected
    steps; ``compute_seconds``: the seconds a step spent on its own work, the rest (each None: not measured);
    ``cost``: the step's reference steps instead of the preset's (:func:`tile_level_cost`); ``what``: the fit
    the warning names."""
    if not minutes:
        return None
    import warnings

    from ..errors import NeuralBakeWarning

    span = 60.0 * minutes if budget_seconds is None else budget_seconds
    cost = STEP_COST.get(preset) if cost is None and preset is not None else cost
    rate = _full_rate() if cost is not None else None
    step_seconds = None if rate is None or cost is None else cost / rate
    rec = budget_record(steps, expected_steps(preset, span, rate, asset_seconds, cost=cost), preset=preset,
                        seconds=span, rate=rate, stopped_reason=stopped_reason, sampling_share=sampling_share,
                        step_seconds=step_seconds, asset_seconds=asset_seconds, compute_seconds=compute_seconds,
                        preset_steps=expected_steps(preset, span, rate, cost=cost) if asset_seconds is not None
                        else None, what=what)
    rec["stopped"] = stop_note(stopped_reason, steps, seconds, minutes, step_cap)
    if rec["warning"]:
        warnings.warn(rec["warning"], NeuralBakeWarning, stacklevel=3)
    return rec


def steps_budget(preset: str | None, *, steps: int, seconds: float, asset_seconds: float | None = None,
                 sampling_share: float | None = None, cost: float | None = None,
                 reference: int | None = None) -> dict:
    """The account of a ``budget="steps"`` fit, JSON-ready: ``budget`` ("steps"), the ``steps`` made and the
    preset's ``reference_steps`` (:func:`reference_steps`; also as ``expected_steps``), ``estimated_seconds``:
    the time they take on this machine, quiet (steps × (cost / rate + the asset's own seconds a step,
    ``asset_seconds``, when measured)), beside the ``seconds`` they took, ``step_seconds``,
    ``asset_seconds_per_step``, ``reference_rate``, ``sampling_share``, ``stopped`` and no warning (the load
    changes its time, not its result). ``cost`` and ``reference``: the step's reference steps and the steps to
    make instead of the preset's (a tile level's: :func:`tile_level_cost`)."""
    rate = _full_rate()
    step_seconds = (STEP_COST[str(preset)] if cost is None else cost) / rate
    n = reference_steps(preset) if reference is None else int(reference)
    return {"budget": "steps", "preset": preset, "steps": int(steps), "reference_steps": n, "expected_steps": n,
            "estimated_seconds": steps * (step_seconds + max(0.0, float(asset_seconds or 0.0))),
            "seconds": seconds, "step_seconds": step_seconds, "asset_seconds_per_step": asset_seconds,
            "reference_rate": rate, "sampling_share": sampling_share, "warning": None,
            "stopped": stop_note("steps", steps, seconds, None, steps)}
