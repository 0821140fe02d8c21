"""`neural-bake bench budget`: each preset's cost per Adam step on this machine against :data:`STEP_COST`.

A time-budgeted fit expects ``budget seconds × reference rate / STEP_COST[preset]`` steps
(:mod:`neural_bake.fit.budget`). This benchmark checks that table where it runs: for every preset it fits
the bundled bumpy sphere for a short budget, exactly as the preset fits (its network, batch, bf16 share of
the time and compiled loss as at its own budget; a compiled preset after an untimed fit of the same budget
that compiles its shapes), reads the seconds per step from the fit's history once it is warm (after the
first logged window: first-call costs, the micro-batch tuning's first trials), and measures
the reference rate (:func:`~neural_bake.fit.budget.probe_rate`, best of 30, not cached) before and after
the fits. Each row gives the measured cost in reference steps beside the table's, their ratio, and the
steps each predicts for the preset's whole budget. A ratio far from 1 on a quiet machine means the table is
off for that preset on this kind of CPU (the expected steps and the under-budget warning with it).

The texture presets are fitted against the 64x1 preset's SDF of the same run (fitted for them when 64x1 is
not measured). A preset whose own construction has two levels (``quick``: :mod:`neural_bake.fit.residual`)
is measured plainly under its name (its network alone) and by level under "PRESET/coarse" and
"PRESET/fine", both read from one fit of its construction (loss not compiled). The row ``tile`` checks
:data:`~neural_bake.fit.budget.TILE_STEP_COST`: the quick preset fitted by the ``tiles`` construction, its tile
level's step time ÷ its number of tiles (no budget of its own: a tile level's steps follow its tiles).
"""

from __future__ import annotations

import time
import warnings

from ..errors import NeuralBakeError, NeuralBakeWarning
from .common import load_note, machine_info

__all__ = ["run", "COLUMNS", "QUICK_PRESETS", "TILE", "warm_seconds_per_step"]

#: Table columns, in order.
COLUMNS = ["preset", "net", "compiled", "steps", "ms / step", "cost (reference steps)", "table cost",
           "measured ÷ table", "budget s", "steps in budget (measured)", "steps in budget (table)"]


def warm_seconds_per_step(history: list[dict], skip: int = 1) -> float | None:
    """Seconds per step from a fit's history (entries with ``step`` and ``seconds``), past its first ``skip``
    entries (the warm-up: a compile, first-call costs): the slope between the first kept entry and the last.
    None when fewer than two entries are left or no step or time passed between them."""
    kept = [e for e in history if "step" in e and "seconds" in e][skip:]
    if len(kept) < 2:
        return None
    steps = kept[-1]["step"] - kept[0]["step"]
    seconds = kept[-1]["seconds"] - kept[0]["seconds"]
    return seconds / steps if steps > 0 and seconds > 0 else None


#: The row of a tile level's step cost per tile (:data:`~neural_bake.fit.budget.TILE_STEP_COST`).
TILE = "tile"

#: The presets of ``--quick`` (none compiled: the run stays under two minutes).
QUICK_PRESETS = ("quick", "quick/coarse", "quick/fine", "64x1", "texture:quick")


def _presets(presets, quick: bool) -> list[str]:
    from ..fit.budget import STEP_COST

    names = list(presets or (QUICK_PRESETS if quick else [*STEP_COST, TILE]))
    bad = [p for p in names if p not in STEP_COST and p != TILE]
    if bad:
        raise NeuralBakeError(f"bench budget: no step cost for preset(s) {', '.join(bad)}; choose among "
                              f"{', '.join([*STEP_COST, TILE])}")
    # the texture presets need an SDF: the 64x1 fit of this run
    return sorted(names, key=lambda p: p.startswith("texture:"))


def run(quick: bool = False, *, presets=None, seconds: float | None = None, log_every: int = 25,
        sdf_overrides: dict | None = None, texture_overrides: dict | None = None, log=None) -> dict:
    """Run the benchmark (module docstring); returns the result dict of :mod:`neural_bake.bench.common`.

    - ``presets``: keys of :data:`~neural_bake.fit.budget.STEP_COST` (default all and :data:`TILE`; quick
      :data:`QUICK_PRESETS`; ``"texture:NAME"`` for a texture preset, ``"tile"`` for a tile level's step per tile).
    - ``seconds``: each fit's budget (default 30; quick 8).
    - ``log_every``: steps between the history entries the step time is read from.
    - ``sdf_overrides``, ``texture_overrides``: more settings for every SDF or texture fit (tests shrink the
      pools with them; a changed network or batch changes the step's cost).
    """
    from ..fit.budget import STEP_COST, probe_rate
    from ..fit.sdf import fit_sdf
    from ..fit.sdf_config import PRESETS as SDF_PRESETS
    from ..fit.texture import PRESETS as TEXTURE_PRESETS
    from ..fit.texture import fit_texture
    from ..io.mesh_io import load_mesh
    from ..nets.compiled import long_run
    from ..samples.generate import sample_path

    say = log or (lambda s: None)
    names = _presets(presets, quick)
    seconds = float(seconds if seconds is not None else (8.0 if quick else 30.0))
    if not seconds > 0:
        raise NeuralBakeError(f"bench budget: seconds must be positive, got {seconds!r}")
    sdf_over, tex_over = dict(sdf_overrides or {}), dict(texture_overrides or {})
    mesh = load_mesh(sample_path("bumpy_sphere"))
    rates = [probe_rate(clock=time.perf_counter)]
    rows, notes, sdf_models = [], [], {}  # the fitted SDFs by preset: the texture presets use 64x1's

    levels: dict = {}  # a preset's construction of two levels, fitted once for both of its rows

    def measure(name: str) -> dict:
        if name == TILE:  # the quick preset by the tiles construction: its tile level's step ÷ its tiles
            from ..fit.budget import TILE_STEP_COST

            fit = fit_sdf(mesh, preset="quick", construction="tiles", minutes=seconds / 60.0, progress=False,
                          log_every=log_every, compile="off", **sdf_over)
            k = fit.model.tiles.tiles
            per_step = warm_seconds_per_step(fit.history)
            if per_step is None:
                notes.append(f"{name}: too few steps in its part of {seconds:.0f} s to read a warm step time")
            return {"preset": name, "net": f"{k}x({fit.model.tiles.width}x{fit.model.tiles.depth})",
                    "compiled": False, "steps": fit.steps, "ms / step": None if per_step is None else
                    1000.0 * per_step / k, "_seconds_per_step": None if per_step is None else per_step / k,
                    "table cost": TILE_STEP_COST, "budget s": None}
        texture = name.startswith("texture:")
        preset, _, level = name.partition("/")
        preset = name.partition(":")[2] if texture else preset
        full = (TEXTURE_PRESETS if texture else SDF_PRESETS)[preset]
        if level:  # "PRESET/coarse", "PRESET/fine": a level of the preset's own construction
            if preset not in levels:
                levels[preset] = fit_sdf(mesh, preset=preset, minutes=seconds / 60.0, progress=False,
                                         log_every=log_every, compile="off", **sdf_over)
            whole = levels[preset]
            fit = whole.coarse if level == "coarse" else whole
            cfg = fit.config if level == "coarse" else whole.fine_config
            per_step = warm_seconds_per_step(fit.history)
            if per_step is None:
                notes.append(f"{name}: too few steps in its part of {seconds:.0f} s to read a warm step time")
            share = whole.config.coarse_share if level == "coarse" else 1.0 - whole.config.coarse_share
            return {"preset": name, "net": f"{cfg.width}x{cfg.depth}", "compiled": False, "steps": fit.steps,
                    "ms / step": None if per_step is None else 1000.0 * per_step, "_seconds_per_step": per_step,
                    "table cost": STEP_COST[name],
                    "budget s": share * 60.0 * float(full["minutes"]) if full.get("minutes") else None}
        if texture:
            if "64x1" not in sdf_models:  # the SDF presets ran first (_presets); 64x1 was not among them
                say("64x1: the SDF the texture presets are fitted against")
                sdf_models["64x1"] = fit_sdf(mesh, preset="64x1", minutes=seconds / 60.0, progress=False,
                                             **sdf_over).model
            fit = fit_texture(mesh, sdf_models["64x1"], preset=preset, minutes=seconds / 60.0, log_every=log_every,
                              **tex_over)
            compiled = False
        else:
            # compiled as at the preset's own budget, which a short run would not repay by itself; a first,
            # untimed fit of the same budget compiles every shape the timed one meets (the micro-batch
            # trials, both precisions), so the timed one reads warm steps
            compiled = long_run(int(full.get("steps", 5000)), full.get("minutes"))
            for _ in range(2 if compiled else 1):
                fit = fit_sdf(mesh, preset=preset, minutes=seconds / 60.0, progress=False, log_every=log_every,
                              compile="on" if compiled else "off", **{"construction": "plain", **sdf_over})
            compiled = fit.config.compile == "on"
            sdf_models[preset] = fit.model
        per_step = warm_seconds_per_step(fit.history)
        if per_step is None:
            notes.append(f"{name}: too few steps in {seconds:.0f} s to read a warm step time; give more seconds")
        return {"preset": name, "net": f"{fit.config.width}x{fit.config.depth}", "compiled": compiled,
                "steps": fit.steps, "ms / step": None if per_step is None else 1000.0 * per_step,
                "_seconds_per_step": per_step, "table cost": STEP_COST[name],
                "budget s": 60.0 * float(full["minutes"]) if full.get("minutes") else None}

    for name in names:
        say(f"{name}: fitting for {seconds:.0f} s")
        with warnings.catch_warnings():  # a short fit's own budget warning says nothing here: the row does
            warnings.simplefilter("ignore", NeuralBakeWarning)
            rows.append(measure(name))
    rates.append(probe_rate(clock=time.perf_counter))
    rate = max(rates)
    for r in rows:
        per_step = r.pop("_seconds_per_step")
        if per_step is None:
            continue
        cost = per_step * rate
        r["cost (reference steps)"] = cost
        r["measured ÷ table"] = cost / r["table cost"]
        if r["budget s"]:
            r["steps in budget (measured)"] = int(r["budget s"] / per_step)
            r["steps in budget (table)"] = int(r["budget s"] * rate / r["table cost"])
    notes.append(f"reference rate {rate:.1f} steps/s (best of 30 before and after the fits: "
                 f"{', '.join(f'{x:.1f}' for x in rates)}); a busy machine reads every cost high")
    notes.append(f"each fit: {seconds:.0f} s on the bumpy sphere sample, step time after its first "
                 f"{log_every}-step window; SDF presets with a budget of 5 minutes or more compiled, as they run, "
                 "each after an untimed fit of the same budget (the compiles); the fits' own budget warnings "
                 "are not shown")
    notes.append(load_note())
    return {"name": "budget", "title": "step cost per preset (reference steps) against fit.budget.STEP_COST",
            "machine": machine_info(), "quick": quick, "reference_rate": rate, "rows": rows, "notes": notes}
