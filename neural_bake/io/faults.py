"""Fault injection for the tests of the output guarantees: stop the process at a named step of a write.

The writers call :func:`fault_point` at each step of a commit (``"file-temp"``: a file's temporary copy is
complete; ``"file-renamed"``: it is in place; the folder steps of :mod:`neural_bake.io.outdir`). Unless the
environment variable ``NEURAL_BAKE_FAULT`` names that step, a call does nothing. Its grammar is a
comma-separated list of ``STEP[#N]:SIGNAL``: at the N-th time (default 1st) the process reaches STEP it sends
itself SIGNAL (``KILL``, ``TERM`` or ``INT``), e.g. ``NEURAL_BAKE_FAULT=file-renamed#3:KILL``.
"""

from __future__ import annotations

import os
import signal

__all__ = ["fault_point", "FAULT_ENV"]

#: The environment variable the fault-injection tests set.
FAULT_ENV = "NEURAL_BAKE_FAULT"

_counts: dict[str, int] = {}


def fault_point(step: str) -> None:
    """Send this process the signal that ``NEURAL_BAKE_FAULT`` asks for at ``step`` (usually: nothing)."""
    spec = os.environ.get(FAULT_ENV)
    if not spec:
        return
    _counts[step] = _counts.get(step, 0) + 1
    for item in spec.split(","):
        where, _, sig = item.strip().rpartition(":")
        name, _, nth = where.partition("#")
        if name == step and _counts[step] == (int(nth) if nth else 1):
            os.kill(os.getpid(), getattr(signal, "SIG" + sig.upper()))
