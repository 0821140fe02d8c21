"""Shared pieces of the benchmarks: timing, tables, JSON output, machine description.

Every benchmark returns a dict ``{"name", "machine", "quick", "rows": [...], ...}``; the CLI prints it
with :func:`format_table` and writes it with :func:`write_json` when ``--json PATH`` is given.
"""

from __future__ import annotations

import functools
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Sequence

import torch

from ..io.atomic import atomic_write_text
from ..io.jsonio import dumps

__all__ = ["data_folder", "data_file", "timeit", "timeit_interleaved", "run_command", "last_error_line", "format_table",
           "write_json", "machine_info", "load_note"]


def data_folder(path: str | os.PathLike | None = None) -> Path | None:
    """The data folder: ``path``, else ``$NEURAL_BAKE_DATA``, else the first ``shared/data`` found beside the
    repository or its parent folders; None when there is none."""
    if path is not None:
        return Path(path) if Path(path).is_dir() else None
    env = os.environ.get("NEURAL_BAKE_DATA")
    if env:
        return Path(env) if Path(env).is_dir() else None
    here = Path(__file__).resolve()
    for parent in here.parents[2:5]:
        cand = parent / "shared" / "data"
        if cand.is_dir():
            return cand
    return None


def data_file(relative: str) -> Path:
    """``relative`` inside the data folder (:func:`data_folder`); a path that does not exist when there is none."""
    return (data_folder() or Path("shared") / "data") / relative


def timeit(fn: Callable[[], object], repeat: int = 3, warmup: int = 1, min_time: float = 0.0) -> float:
    """Best wall time in seconds of ``fn()`` over ``repeat`` runs after ``warmup`` runs.

    The best (not the mean) of several runs is the least disturbed by other work on the machine.
    ``min_time`` > 0 repeats until that many seconds have been spent, at least ``repeat`` times.
    """
    for _ in range(warmup):
        fn()
    best, spent, n = float("inf"), 0.0, 0
    while n < repeat or spent < min_time:
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        best, spent, n = min(best, dt), spent + dt, n + 1
    return best


def timeit_interleaved(methods: dict[str, Callable[[], object]], repeat: int = 3) -> dict[str, float]:
    """Best wall time in seconds of each ``methods[name]()`` over ``repeat`` rounds that call every method in
    turn (no warm-up: the caller does it), so that every method sees the same machine load."""
    best = {name: float("inf") for name in methods}
    for _ in range(repeat):
        for name, fn in methods.items():
            t0 = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - t0)
    return best


def run_command(args: Sequence[str], *, env: dict[str, str] | None = None) -> tuple[float, subprocess.CompletedProcess]:
    """Run ``neural-bake ARGS`` as a user does, in a process of its own (``python -m neural_bake.cli.main``,
    with ``env`` as its environment, default this one's): its wall seconds, start-up included, and the finished
    process (exit code, output captured as text). The package's bytecode is written first, once a process
    (:func:`compile_bytecode`; :func:`bytecode_note` says how that went)."""
    bytecode_note()
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "neural_bake.cli.main", *args], env=env, capture_output=True,
                          text=True)
    return time.perf_counter() - t0, proc


#: The packages of neural-bake: the library and the folders mapped under its namespace (pyproject.toml).
PACKAGES = ("neural_bake", "neural_bake.cli", "neural_bake.pipelines", "neural_bake.samples")


def compile_bytecode(packages: Sequence[str] = PACKAGES) -> str:
    """Write the bytecode of every module of ``packages`` (and their subpackages) that lacks it or has a stale
    one, as installing a package does, so a timed command starts as it does for a user and not after compiling
    its sources in memory (which every start does where bytecode is never written, e.g. under
    ``PYTHONDONTWRITEBYTECODE``). Returns a note for the bench's notes; a folder that cannot be written is
    named there, not raised (the command then runs as it is)."""
    import compileall
    import importlib

    folders: list[str] = []
    for name in packages:
        folders += list(importlib.import_module(name).__path__)
    roots = sorted({str(Path(f).resolve()) for f in folders})
    failed = []
    for root in roots:
        if any(root != other and root.startswith(other + os.sep) for other in roots):
            continue  # a subpackage inside another root (compile_dir recurses)
        if not compileall.compile_dir(root, quiet=2, workers=1):  # quiet=2: prints nothing, errors included
            failed.append(root)
    if failed:
        return f"bytecode could not be written in {', '.join(failed)}: the commands compiled their sources as they ran"
    return "the package's bytecode was written before the commands ran, as an installed package's is"


@functools.lru_cache(maxsize=1)
def bytecode_note() -> str:
    """:func:`compile_bytecode`'s note, compiling once a process."""
    return compile_bytecode()


def last_error_line(proc: subprocess.CompletedProcess) -> str:
    """The last line a finished command wrote to stderr (its one-line error), or "(no message)"."""
    return (proc.stderr.strip().splitlines() or ["(no message)"])[-1]


def load_note() -> str:
    """What the machine's load was (1- and 15-minute load averages against its cores), for a bench's notes:
    other work on the machine only slows a timing down, so under load the figures are upper bounds."""
    cores = os.cpu_count() or 1
    try:
        one, _, fifteen = os.getloadavg()
    except OSError:  # pragma: no cover - platforms without load averages
        return f"timings: best of repeats; load average not available ({cores} cores)"
    state = "busy: timings are upper bounds, compare ratios within the run" if one > cores + 0.5 else "quiet"
    return (f"timings: best of repeats; load average at the end {one:.1f} (15 min: {fifteen:.1f}) on {cores} "
            f"cores — {state}")


def machine_info() -> dict:
    """What the figures were measured on."""
    return {
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
    }


def _fmt(v) -> str:
    if isinstance(v, float):
        if v != v:
            return "nan"
        a = abs(v)
        if a == 0:
            return "0"
        if a >= 1e5 or a < 1e-3:
            return f"{v:.3g}"
        if a >= 100:
            return f"{v:.0f}"
        return f"{v:.4g}"
    return str(v)


def format_table(rows: Sequence[dict], columns: Sequence[str] | None = None) -> str:
    """A plain-text table of ``rows`` (dicts), columns in the given order (default: first row's keys)."""
    if not rows:
        return "(no rows)"
    columns = list(columns or rows[0].keys())
    cells = [[_fmt(r.get(c, "")) for c in columns] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(columns)]
    line = "  ".join(c.rjust(w) for c, w in zip(columns, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(v.rjust(w) for v, w in zip(row, widths)) for row in cells]
    return "\n".join([line, sep, *body])


def write_json(path: str | os.PathLike, result: dict) -> None:
    """Write a benchmark's result atomically as indented JSON."""
    atomic_write_text(path, dumps(result))
