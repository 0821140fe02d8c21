"""Measured facts of this machine kept between processes (the best reference-step rate, the float32 GEMM
route): small JSON files of key → value in :func:`machine_cache_dir`, read tolerantly (an unreadable file is
empty) and replaced whole (written beside, then renamed), so that a failure only loses a record."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

__all__ = ["cpu_model", "machine_cache_dir", "read_facts", "write_fact"]


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``, else the platform's processor or machine): what measured
    machine facts are kept under."""
    import platform

    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_cache_dir() -> Path:
    """The folder the facts are kept in: ``$NEURAL_BAKE_CACHE_DIR``, else ``$XDG_CACHE_HOME/neural_bake``, else
    ``~/.cache/neural_bake`` (created on the first write)."""
    base = os.environ.get("NEURAL_BAKE_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "neural_bake")
    return Path(base)


def read_facts(name: str) -> dict:
    """The facts of file ``name`` ({} when it is missing, unreadable or not a JSON object)."""
    try:
        data = json.loads((machine_cache_dir() / name).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def write_fact(name: str, key: str, value) -> None:
    """Set ``key`` to ``value`` in file ``name``; a failure (no writable folder, a full disk) is ignored."""
    path = machine_cache_dir() / name
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}-", suffix=".json")
    except OSError:
        return
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump({**read_facts(name), key: value}, f, indent=1, sort_keys=True)
        os.replace(tmp, path)
    except OSError:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
