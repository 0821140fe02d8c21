"""Keep freed memory for reuse, so that the tensors of a training step do not page-fault.

A training step allocates and frees the same few-megabyte tensors over and over (activations, their cosines,
the gradient stream, their gradients). glibc's malloc serves blocks above its mmap threshold with a fresh
``mmap`` and returns them to the kernel on ``free``, and trims the top of its heaps past a trim threshold,
so every step touches new pages, and each first touch is a page fault (tens of thousands per (256, 3) SDF
step). :func:`keep_freed_memory` raises both thresholds (``mallopt``), so freed blocks stay in the heap and
the next step reuses them: a handful of faults per step, and markedly faster steps (docs/findings.md).

Blocks above that threshold (glibc caps it at 32 MB) would still be mapped afresh at every allocation and
unmapped at every ``free``: a 2048² bake's per-sample arrays (tens of MB each) page-fault in full each time.
:func:`keep_freed_memory` therefore also stops malloc from serving blocks with their own ``mmap``
(``M_MMAP_MAX`` = 0): every block comes from the heap and is reused once freed. (A thread's own arena still
maps a block larger than its heap; glibc falls back to that by itself.)

numpy asks the kernel for transparent huge pages for its large arrays (``madvise``), and a fresh huge page is
zeroed whole at its first touch, which a virtual machine may hand out slowly (the profile: docs/findings.md,
"Baking"). :func:`keep_freed_memory` turns numpy's request off as well (``NUMPY_MADVISE_HUGEPAGE=0``, the
setting numpy reads at import, does the same for a whole program).

The cost: memory a run freed stays with the process (its peak, not its current need), and large blocks come
from the heap. It changes the whole process, so the library calls it where it owns the process's work: the training loop (:func:`neural_bake.fit.training.train`, so every fitter and the
CLI's ``fit`` commands), the baker (:class:`neural_bake.bake.baker.Baker`: the layout's and the maps' arrays of
a 2048² bake are rasterised, evaluated and freed band after band) and the step timing of ``bench fit``. Only glibc on Linux is tuned; elsewhere (and
with ``NEURAL_BAKE_KEEP_HEAP=0``) nothing changes. :func:`status` says what happened.

Reused memory still page-faults once, at its first touch, and on a virtual machine a first touch can cost
far more than the kernel's own work (the host backs the page then: about 1.4 s a GB on a cold machine against
0.1 s warm). :func:`reserve` pays that on a background thread: it grows the heap by the memory a job is about
to use (malloc and free of one block, which the raised trim threshold keeps) and faults the block's pages in
with ``madvise(MADV_POPULATE_WRITE)`` (Linux 5.14 and later), which maps them writable without touching
their contents, so the job's own allocations find them ready while it loads: a 2048² bake's preparation
(rasterisation) went from 0.5 to 0.22 s (docs/findings.md). Call it once the heavy imports are done: each
``madvise`` call holds the process's memory-map lock, which a shared library being loaded waits for (the
block is faulted in 4 MB at a time for that reason, and torch's import beside it still took 0.1–0.3 s
longer). :func:`wait_reserved` waits for the thread; a thread probe calls it first, so that the pages being
faulted in do not look like a busy neighbour.
"""

from __future__ import annotations

import ctypes
import errno
import os
import platform
import threading

from .compiled import env_switch

__all__ = ["keep_freed_memory", "status", "reserve", "wait_reserved", "ENV_SWITCH", "MMAP_THRESHOLD",
           "TRIM_THRESHOLD", "RESERVE_MAX"]

#: 0/off/false: leave malloc as it is (A/B measurements; a process that must return memory at once).
ENV_SWITCH = "NEURAL_BAKE_KEEP_HEAP"

#: Blocks up to this size come from the heap (and are reused after ``free``) instead of a fresh ``mmap``;
#: 32 MB is the largest value every 64-bit glibc accepts, and above a (256, 3) step's largest tensor.
MMAP_THRESHOLD = 32 << 20

#: Free memory at the top of a heap is returned to the kernel only past this size.
TRIM_THRESHOLD = 512 << 20

#: The most :func:`reserve` grows the heap by: the trim threshold that keeps it is a C int (below 2 GB).
RESERVE_MAX = 3 << 29

_M_TRIM_THRESHOLD = -1  # glibc's malloc.h
_M_MMAP_THRESHOLD = -3
_M_MMAP_MAX = -4
_MADV_POPULATE_WRITE = 23  # Linux's mman.h (5.14)
_PAGE = 4096
_POPULATE_STEP = 4 << 20
_lock = threading.Lock()
_state: dict = {"status": None, "any_size": False, "reserved": 0, "thread": None, "reserve": None}


def _tune() -> str:
    _state["any_size"] = False  # set below once every block size is kept
    if env_switch(ENV_SWITCH) is False:
        return f"off ({ENV_SWITCH}=0): malloc left as it is"
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return f"not glibc ({platform.system()}): malloc left as it is"
    try:
        mallopt = _libc().mallopt  # the C library this process runs on
    except (OSError, AttributeError) as exc:
        return f"mallopt not found ({exc}): malloc left as it is"
    if mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) != 1:
        return "mallopt refused the mmap threshold: malloc left as it is"
    if mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) != 1:
        return f"mallopt refused the trim threshold: blocks up to {MMAP_THRESHOLD >> 20} MB come from the heap"
    if mallopt(_M_MMAP_MAX, 0) != 1:
        return f"glibc malloc keeps freed blocks up to {MMAP_THRESHOLD >> 20} MB for reuse" + _small_pages()
    _state["any_size"] = True
    return "glibc malloc keeps freed blocks of any size for reuse" + _small_pages()


def _small_pages() -> str:
    """numpy's large arrays on ordinary pages (module docstring); what was done, as a clause."""
    import importlib

    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):  # numpy 2, numpy 1
        try:
            setter = getattr(importlib.import_module(name), "_set_madvise_hugepage", None)
        except ImportError:
            continue
        if setter is not None:
            break
    else:
        return ""
    setter(False)
    return "; numpy's arrays on ordinary pages, not transparent huge pages"


def keep_freed_memory() -> str:
    """Tune this process's malloc once (module docstring); later calls do nothing. Returns :func:`status`."""
    if _state["status"] is None:
        with _lock:
            if _state["status"] is None:
                _state["status"] = _tune()
    return status()


def status() -> str:
    """What :func:`keep_freed_memory` did ("not called yet" before its first call), and :func:`reserve`."""
    return (_state["status"] or "not called yet") + (f"; {_state['reserve']}" if _state["reserve"] else "")


def _libc():
    """The C library this process runs on, its malloc calls typed."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mallopt.argtypes, libc.mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    libc.malloc.argtypes, libc.malloc.restype = [ctypes.c_size_t], ctypes.c_void_p
    libc.free.argtypes, libc.free.restype = [ctypes.c_void_p], None
    libc.madvise.argtypes, libc.madvise.restype = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int], ctypes.c_int
    return libc


def reserve(nbytes: int) -> str:
    """Grow this process's heap by ``nbytes`` (at most :data:`RESERVE_MAX`) and fault its pages in on a
    background thread (module docstring); returns what was done. Tunes malloc first
    (:func:`keep_freed_memory`). Does nothing where malloc is not tuned, for a size not above what an earlier
    call reserved, or while an earlier call's thread still runs."""
    nbytes = min(int(nbytes), RESERVE_MAX)
    tuned = keep_freed_memory()
    if not _state["any_size"]:  # off, not glibc, or large blocks still mapped on their own
        return f"nothing reserved: {tuned}"
    with _lock:
        if nbytes <= _state["reserved"] or (_state["thread"] is not None and _state["thread"].is_alive()):
            return _state["reserve"] or "nothing reserved"
        libc = _libc()
        # the block must stay in the heap once freed: above the trim threshold, free would return it
        # (the top may already hold up to TRIM_THRESHOLD of free memory; the sum stays a C int)
        if libc.mallopt(_M_TRIM_THRESHOLD, min((1 << 31) - 1, nbytes + TRIM_THRESHOLD)) != 1:
            return "nothing reserved: mallopt refused the trim threshold"
        block = libc.malloc(nbytes)
        if not block:
            return f"nothing reserved: malloc refused {nbytes >> 20} MB"
        libc.free(block)  # back in the heap, at its top: the next allocations take it
        start = -(-block // _PAGE) * _PAGE
        length = (block + nbytes - start) // _PAGE * _PAGE
        _state["reserved"] = nbytes
        _state["reserve"] = f"{nbytes >> 20} MB of heap faulted in ahead, on a background thread"

        def populate():
            for at in range(start, start + length, _POPULATE_STEP):  # in steps: the lock is held per call
                if libc.madvise(at, min(_POPULATE_STEP, start + length - at), _MADV_POPULATE_WRITE) != 0:
                    break
            else:
                return
            err = ctypes.get_errno()
            why = ("the kernel has no MADV_POPULATE_WRITE (Linux < 5.14)" if err == errno.EINVAL
                   else f"madvise: {os.strerror(err)}")
            _state["reserve"] = f"{nbytes >> 20} MB of heap reserved, its pages not faulted in ahead ({why})"

        _state["thread"] = threading.Thread(target=populate, name="heap-reserve", daemon=True)
        _state["thread"].start()
        return _state["reserve"]


def wait_reserved(timeout: float | None = None) -> None:
    """Wait (at most ``timeout`` seconds) for :func:`reserve`'s background thread, if one runs."""
    thread = _state["thread"]
    if thread is not None:
        thread.join(timeout)
