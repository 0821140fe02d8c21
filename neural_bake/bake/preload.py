"""The source mesh read, decimated and unwrapped in a forked process while the bake imports torch.

A bake's first seconds go to importing torch and to the source mesh: reading it, decimating it and unwrapping
the coarse mesh, none of which needs torch (their seconds: BENCHMARKS.md, the bake command). With a second
usable core, :func:`start` forks a process that does the mesh work while this one imports torch and reads
the model files; :meth:`Preload.result` waits for it and returns what the same calls make here
(:func:`load_source`, the same functions in the same order).

The preload is a shortcut, never a second way to fail: any failure in the child (bad input included) or a
child that dies makes :meth:`Preload.result` return None, and the bake then does the work itself, so that its
errors and messages are the ones it gives without the preload. The child's own warnings are not shown; the
mesh's load warnings (``Mesh.warnings``) are issued again here (:func:`reissue_warnings`).

Forking is safe only while the process runs no other thread and has not started torch (its OpenMP team) or
any OpenMP kernel: :func:`start` returns None when torch is imported or another thread runs, in a daemonic
process (a pool's worker), where ``fork`` does not exist or fails, with one usable core, or when
``NEURAL_BAKE_PRELOAD`` is ``0`` (the bake then does the work
itself, as a library caller that imported torch already does).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field
from typing import Any

from ..errors import NeuralBakeWarning
from ..types import Mesh

__all__ = ["Preload", "PreloadedSource", "start", "load_source", "reissue_warnings", "ENV_SWITCH"]

#: 0/off/false: no preloading process (A/B checks, or a machine where forking is unwelcome).
ENV_SWITCH = "NEURAL_BAKE_PRELOAD"

#: The signals blocked across the fork (the child sets its own handlers before it takes them).
_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})


@dataclass
class PreloadedSource:
    """What the child made: the source mesh, its asset and shading reference, the decimated coarse mesh and
    its info (None: the spec is not a decimation), its unwrap (None: not asked for) and the seconds of each."""

    fine: Mesh
    asset: Any
    reference: Mesh
    coarse: tuple[Mesh, dict] | None = None
    layout: Mesh | None = None
    layout_size: int | None = None
    """The map side the layout was unwrapped for (its xatlas resolution)."""
    seconds: dict = field(default_factory=dict)

    def made(self, mesh: Mesh) -> bool:
        """Whether ``mesh`` is the coarse mesh this made (this very object)."""
        return self.coarse is not None and mesh is self.coarse[0]


def load_source(mesh_path: str, *, texture_image: str | None = None, coarse: str | None = None,
                layout_size: int | None = None, layout_cache: bool = False) -> PreloadedSource:
    """Read ``mesh_path`` (and its asset), decimate it when ``coarse`` is a decimation spec, and unwrap the
    result for a ``layout_size``² map (None: no unwrap), with the layout cache when ``layout_cache``: the calls
    :func:`neural_bake.bake.job.load_inputs`, :func:`~neural_bake.bake.job.make_coarse` and the
    :class:`~neural_bake.bake.baker.Baker` make, in their order. Runs in the preloading child; torch-free."""
    from ..mesh.coarse import parse_coarse
    from .job import read_source

    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    fine, asset, reference = read_source(mesh_path, texture_image)
    seconds["load"] = time.perf_counter() - t0
    out = PreloadedSource(fine=fine, asset=asset, reference=reference, seconds=seconds)
    if coarse is None or parse_coarse(coarse)[0] != "decimate":
        return out
    from ..mesh.layout_cache import LayoutCache
    from .job import coarse_of_source

    cache = LayoutCache() if layout_cache else None
    t0 = time.perf_counter()
    out.coarse = coarse_of_source(fine, coarse, cache=cache, mesh_path=mesh_path)
    seconds["coarse"] = time.perf_counter() - t0
    mesh = out.coarse[0]
    if layout_size is not None and mesh.uv is None:
        from ..mesh.unwrap import unwrap

        t0 = time.perf_counter()
        options = {"resolution": int(layout_size)}
        out.layout = cache.unwrap(mesh, **options)[0] if cache is not None else unwrap(mesh, **options)
        out.layout_size = int(layout_size)
        seconds["unwrap"] = time.perf_counter() - t0
    return out


def reissue_warnings(mesh: Mesh) -> None:
    """Issue ``mesh``'s load warnings here, as :func:`~neural_bake.io.mesh_io.load_mesh` issued them in the
    child (where they were not shown)."""
    for message in mesh.warnings:
        warnings.warn(message, NeuralBakeWarning, stacklevel=2)


class Preload:
    """A forked child running :func:`load_source`; :meth:`result` waits for it, :meth:`close` ends it."""

    def __init__(self, process, connection):
        self._process, self._conn = process, connection
        self._result: PreloadedSource | None = None
        self._done = False
        self.waited = 0.0
        """Seconds :meth:`result` waited for the child."""
        self.failure: str | None = None
        """Why the child's work is not used (None: it is, or it was not asked for yet)."""

    def result(self) -> PreloadedSource | None:
        """The child's :class:`PreloadedSource`, or None when it failed or died (the caller does the work)."""
        if self._done:
            return self._result
        from multiprocessing.connection import wait

        t0 = time.perf_counter()
        try:
            wait([self._conn, self._process.sentinel])  # its message, or its end without one
            status, payload = self._conn.recv() if self._conn.poll() else ("died", None)
        except (EOFError, OSError):  # its end of the pipe closed without a message
            status, payload = "died", None
        self.waited = time.perf_counter() - t0
        self._done = True
        if status == "ok":
            self._result = payload
        else:
            self.failure = f"the preloading process {status}" + (f": {payload}" if payload else "")
        self.close()
        return self._result

    def summary(self) -> dict:
        """JSON-ready: the child's seconds per step, the seconds waited here, and why its work was not used."""
        r = self._result
        return {"seconds": None if r is None else {k: round(v, 4) for k, v in r.seconds.items()},
                "waited": round(self.waited, 4), "failure": self.failure}

    def close(self) -> None:
        """End the child (killed when it still runs) and release its pipe; safe to call more than once."""
        p = self._process
        if p.is_alive():
            p.kill()
        p.join()
        self._conn.close()


def _child(connection, parents_end, kwargs: dict) -> None:
    """The child's work: :func:`load_source`, its result or its failure sent to the parent."""
    parents_end.close()  # this copy open, a parent that has gone would leave a long send blocked, not failed
    # Ctrl-C reaches the whole process group: the parent handles it (and ends this process); a termination
    # ends this one quietly, without the parent's handler. Both were blocked across the fork (start).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _SIGNALS)
    warnings.simplefilter("ignore")  # shown by the parent (reissue_warnings), or by its own run on a failure
    try:
        payload: tuple[str, Any] = ("ok", load_source(**kwargs))
    except BaseException as exc:  # noqa: BLE001 - every failure is the parent's to redo, and say
        payload = ("failed", f"{type(exc).__name__}: {exc}")
    try:
        connection.send(payload)
    except (OSError, EOFError):  # the parent has gone or closed the pipe: no one to tell
        pass
    except Exception as exc:  # noqa: BLE001 - an unpicklable result: the parent does the work
        with contextlib.suppress(OSError, EOFError):
            connection.send(("failed", f"its result could not be sent ({type(exc).__name__})"))
    finally:
        connection.close()


def can_fork() -> str | None:
    """None when forking a preloading child is safe and useful here, else why not."""
    value = os.environ.get(ENV_SWITCH, "").strip().lower()
    if value in ("0", "off", "false", "no"):
        return f"{ENV_SWITCH}={value}"
    if not hasattr(os, "fork"):
        return "this platform cannot fork"
    if "torch" in sys.modules:
        return "torch is imported (its OpenMP team would not survive a fork)"
    if threading.active_count() > 1:
        return "another thread runs"
    import multiprocessing as mp

    if mp.current_process().daemon:
        return "a daemonic process (a pool's worker) cannot have children"
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    if cores < 2:
        return "one usable core"
    return None


def start(mesh_path: str, **kwargs) -> Preload | None:
    """Fork a child running :func:`load_source` (``mesh_path``, ``kwargs``), or None where that is not safe
    or useful (:func:`can_fork`)."""
    if can_fork() is not None:
        return None
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    receive, send = ctx.Pipe(duplex=False)
    process = ctx.Process(target=_child, args=(send, receive, {"mesh_path": str(mesh_path), **kwargs}),
                          name="neural-bake-preload", daemon=True)
    # the child starts with Ctrl-C and termination blocked, until it has set its own handlers; here they are
    # delivered once the fork is done
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
    try:
        process.start()
    except (OSError, AssertionError):  # no process to be had (limits, memory): the bake does the work itself
        receive.close()
        return None
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        send.close()
    return Preload(process, receive)
