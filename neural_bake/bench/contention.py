"""`neural-bake bench contention`: what one other busy program on the machine costs the commands a user runs.

Three commands, each run as the user runs it (its own `neural-bake` process, wall time end to end): the
``quick`` SDF fit of the bumpy sphere sample for a fixed time budget (measured: the steps it made), a bake of
that SDF (decimate:2000, normal map only, no baseline) and a render of it. Each runs quiet and beside a
competitor: a CPU-bound process started with ``setsid`` (detached, as a program started from
another terminal is; with autogroup scheduling it takes its share of the CPU whatever its niceness). Each
runs with torch's default threads (one per core, fixed) and with the thread count chosen by measurement
(:mod:`neural_bake.nets.threads`), so every ratio is measured in the same run.

Figures per command and thread setting: quiet and busy value, busy ÷ quiet (for the fit: busy steps ÷ quiet
steps, the share of the quiet fit it kept), and the measured setting's quiet value against the default's
(what the measurement costs on an idle machine). Targets: with one of two cores taken a fit keeps at least
45 % of its quiet steps, a bake takes at most 2.2× its quiet time; idle, the measured setting is no slower
than the default (within 5 %).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Iterator

from ..errors import NeuralBakeError
from .common import last_error_line, load_note, machine_info, run_command

__all__ = ["run", "COLUMNS", "WORKLOADS", "competitor", "rows_from", "TARGETS"]

COLUMNS = ["command", "threads", "measure", "quiet", "busy", "busy ÷ quiet", "target", "met", "idle ÷ default"]

#: The commands measured.
WORKLOADS = ("fit", "bake", "render")

#: Targets per command: (figure, comparison, value), for the measured thread setting beside a competitor.
TARGETS = {"fit": ("kept", ">=", 0.45), "bake": ("slowdown", "<=", 2.2), "render": ("slowdown", "<=", 2.2)}

#: Largest idle slowdown of the measured setting against the default one.
IDLE_TOLERANCE = 1.05

_SPIN = "import os\nwhile True:\n    pass\n"


@contextlib.contextmanager
def competitor(busy: bool = True) -> Iterator[int | None]:
    """A CPU-bound Python process started with ``setsid`` for the body; yields its pid (None when not
    ``busy``). It is killed on exit, whatever happens in the body."""
    if not busy:
        yield None
        return
    proc = subprocess.Popen([sys.executable, "-c", _SPIN], start_new_session=True, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(0.5)  # let the scheduler see it as a running neighbour
        yield proc.pid
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _cli(args: list[str], threads: str) -> float:
    """Run `neural-bake ARGS` with NEURAL_BAKE_THREADS=``threads``; its wall seconds (RuntimeError naming the
    command's last error line if it fails)."""
    seconds, proc = run_command(args, env={**os.environ, "NEURAL_BAKE_THREADS": threads})
    if proc.returncode != 0:
        raise RuntimeError(f"bench contention: `neural-bake {' '.join(args[:2])}` failed: {last_error_line(proc)}")
    return seconds


def _fit_steps(path: Path) -> int:
    """The Adam steps a fit's file records: its budget's count (a construction's: both levels'), else its own."""
    from ..fields import load_field

    training = load_field(path).metadata["training"]
    return int((training.get("budget") or {}).get("steps") or training["steps"])


def rows_from(measured: dict) -> list[dict]:
    """Table rows from ``measured[command][threads][busy or quiet]`` (fit: steps made; others: seconds)."""
    rows = []
    for command, by_threads in measured.items():
        default_quiet = by_threads.get("default", {}).get("quiet")
        for threads, v in by_threads.items():
            quiet, busy = v.get("quiet"), v.get("busy")
            fit = command == "fit"
            ratio = None if not quiet or busy is None else busy / quiet
            target = met = None
            if threads == "measured" and ratio is not None:
                _, op, value = TARGETS[command]
                target = f"{op} {value:g}"
                met = ratio >= value if op == ">=" else ratio <= value
            idle = None
            if threads == "measured" and quiet and default_quiet:
                idle = default_quiet / quiet if fit else quiet / default_quiet
            rows.append({"command": command, "threads": threads, "measure": "steps made" if fit else "seconds",
                         "quiet": quiet, "busy": busy, "busy ÷ quiet": ratio, "target": target, "met": met,
                         "idle ÷ default": idle})
    return rows


def run(quick: bool = False, *, workloads: tuple[str, ...] | None = None, fit_seconds: float | None = None,
        bake_size: int | None = None, render_size: int | None = None, mesh=None, fit_args: tuple[str, ...] = (),
        log=None) -> dict:
    """Measure (module docstring); returns the result dict of :mod:`neural_bake.bench.common`.

    - ``workloads``: which of :data:`WORKLOADS` (default all; the bake and the render use the fit's model).
    - ``fit_seconds``: the fit's time budget (default 60; quick 12); ``bake_size``: the map (default 2048;
      quick 512); ``render_size``: the image (default 256; quick 128).
    - ``mesh``: the mesh file (default the bumpy sphere sample); ``fit_args``: more `fit sdf` options (tests
      shrink the network and pools with them).
    """
    from ..samples.generate import sample_path

    say = log or (lambda s: None)
    workloads = tuple(workloads or WORKLOADS)
    bad = [w for w in workloads if w not in WORKLOADS]
    if bad:
        raise NeuralBakeError(f"bench contention: unknown workload {bad[0]!r} (choose from {', '.join(WORKLOADS)})",
                              parameter="workloads")
    fit_seconds = float(fit_seconds or (12.0 if quick else 60.0))
    bake_size = int(bake_size or (512 if quick else 2048))
    render_size = int(render_size or (128 if quick else 256))
    cores = os.cpu_count() or 1
    settings = {"default": str(cores), "measured": "auto"}
    mesh = Path(mesh) if mesh is not None else sample_path("bumpy_sphere")
    measured: dict = {w: {t: {} for t in settings} for w in workloads}
    with tempfile.TemporaryDirectory(prefix="nb-bench-contention-") as tmp:
        root = Path(tmp)
        model = root / "model.sdf"
        fit_cmd = ["fit", "sdf", str(mesh), "--preset", "quick", "--minutes", f"{fit_seconds / 60.0:.6f}",
                   "--no-metrics", "--no-progress", "--compile", "off", *fit_args]
        if {"bake", "render"} & set(workloads):  # the model they use: a quiet fit with the default threads
            say(f"fit sdf: the model the bake and render use ({fit_seconds:.0f} s, quiet)")
            _cli([*fit_cmd, "-o", str(model)], settings["default"])
        for busy in (False, True):
            state = "busy" if busy else "quiet"
            with competitor(busy):
                for threads, value in settings.items():
                    if "fit" in workloads:
                        out = root / f"fit-{state}-{threads}.sdf"
                        say(f"fit sdf, {state}, {threads} threads: {fit_seconds:.0f} s")
                        _cli([*fit_cmd, "-o", str(out)], value)
                        measured["fit"][threads][state] = _fit_steps(out)
                    if "bake" in workloads:
                        say(f"bake {bake_size}², {state}, {threads} threads")
                        measured["bake"][threads][state] = _cli(
                            ["bake", str(mesh), "--sdf", str(model), "--coarse", "decimate:2000", "--maps", "normal",
                             "--size", str(bake_size), "--no-baseline", "-o", str(root / f"bake-{state}-{threads}")],
                            value)
                    if "render" in workloads:
                        say(f"render {render_size}², {state}, {threads} threads")
                        measured["render"][threads][state] = _cli(
                            ["render", str(model), "-o", str(root / f"shot-{state}-{threads}.png"), "--size",
                             str(render_size)], value)
    rows = rows_from(measured)
    notes = [f"mesh: {mesh.name}" + (f"; fit options {' '.join(fit_args)}" if fit_args else ""),
             f"competitor: one CPU-bound process started with setsid on {cores} cores; default threads: "
             f"{cores} fixed (torch's one per core), measured: NEURAL_BAKE_THREADS=auto",
             f"fit: the quick preset on the bumpy sphere sample for {fit_seconds:.0f} s (steps made); bake: "
             f"decimate:2000, normal map {bake_size}², no baseline; render: {render_size}²; wall time of each "
             "command, its start-up included",
             f"idle ÷ default: the measured setting's quiet figure against the default's (target ≤ {IDLE_TOLERANCE:g}: "
             "slowdown for seconds, steps lost for the fit)", load_note()]
    return {"name": "contention", "title": "contention: the commands beside one busy program", "quick": quick,
            "machine": machine_info(), "measured": json.loads(json.dumps(measured)), "rows": rows, "notes": notes}
