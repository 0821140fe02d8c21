"""A fused float32 sin/cos kernel for the GEMM-normal and training paths, with a pure-torch fallback.

Reverse-mode normals need ``sin A`` (the activations) and ``cos A`` (the derivatives) of every hidden
pre-activation. torch computes them as two passes with two range reductions, and for narrow networks those
two passes are most of the cost (each costs about as much as a 64×64 GEMM of the same chunk). ``sincos.c``
computes both from one shared reduction in one vectorised pass, for about the cost of ``torch.sin`` alone.

The C file is compiled on first use and loaded with ctypes (:func:`neural_bake.nets.native.build`). On x86-64 with GCC it
carries an AVX-512 and an AVX2/FMA clone and a baseline one, chosen at run time. Where torch runs on GNU
OpenMP the kernel splits each call over torch's own OpenMP team (:func:`neural_bake.nets.native.torch_openmp`;
torch's thread count, in pieces of whole blocks, so the values are those of one thread): the workers torch's
GEMMs leave spinning take their share at once. (Split over a Python thread of its own instead, it was slower:
those workers spun on the second core beside it; docs/findings.md.) Elsewhere it runs on the calling thread.
Because torch's own parallel sin + cos may still be faster on some machines, the
first use times both on one (4,096, 64) chunk and keeps the faster (``NEURAL_BAKE_FAST_SINCOS=1`` forces the
kernel, ``=0`` turns it off); when no compiler is found or the build fails, torch's functions are used.
:func:`status` says which is in use and why.

The same file has a sin-only entry (:func:`sin_`, in place) for the inference forward pass: the same
reduction and polynomial without the cosine's stores, kept where its own first-use timing beats
``torch.sin``.

Only contiguous float32 CPU tensors take the kernel; everything else (float64, CUDA, strided views, code
being traced by ``torch.compile``) takes torch's functions. Accuracy: ≤ 2e-7 absolute against float64 sin/cos
(torch.sin: 4e-8), for any finite input; NaN for NaN and ±inf, as torch.
"""

from __future__ import annotations

import ctypes
import threading
import time
from pathlib import Path

import torch

from .compiled import env_switch
from .native import build, threads

__all__ = ["sincos", "sincos_", "sin_", "status", "sin_status", "kernel_available", "sin_kernel_available",
           "ENV_SWITCH"]

#: 0/off/false: torch.sin + torch.cos everywhere (A/B measurements, a misbehaving compiler); 1/on/true: the
#: kernel wherever it builds, without the first-use timing.
ENV_SWITCH = "NEURAL_BAKE_FAST_SINCOS"

_SOURCE = Path(__file__).with_name("sincos.c")
_FLAGS = ("-O3", "-fPIC", "-shared", "-fno-math-errno")
_lock = threading.Lock()
_state: dict = {"built": None, "fn": None, "status": None, "sin_fn": None, "sin_status": None}


def _build() -> tuple[tuple | None, str]:
    """The compiled (sincos, sin) entries, or None and why (the caller names the fallback)."""
    lib, msg = build(_SOURCE, switch=ENV_SWITCH, flags=_FLAGS, openmp=True)
    if lib is None:
        return None, msg
    try:
        mt, sin_mt = lib.nb_sincos_f32_mt, lib.nb_sin_f32_mt
    except AttributeError as exc:
        return None, f"the C kernel could not be built or loaded ({exc})"
    mt.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64]
    sin_mt.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64]
    mt.restype = sin_mt.restype = None

    def fn(a: int, s: int, c: int, n: int) -> None:
        mt(a, s, c, n, threads())

    def sin_fn(a: int, s: int, n: int) -> None:
        sin_mt(a, s, n, threads())

    return (fn, sin_fn), "fused " + msg


def _calibrate(kernel, reference) -> tuple[float, float]:
    """Best-of-5 seconds of ``kernel(a, s)`` and ``reference(a, s)`` on one (4,096, 64) chunk, interleaved."""
    a = torch.randn(4096, 64, generator=torch.Generator().manual_seed(0)) * 30
    s, b = torch.empty_like(a), torch.empty_like(a)
    times = {"kernel": [], "torch": []}
    for _ in range(5):
        for name, fn in (("kernel", kernel), ("torch", reference)):
            b.copy_(a)  # one buffer: a fresh one a round would time the machine's first touches of its pages
            t = time.perf_counter()
            fn(b, s)
            times[name].append(time.perf_counter() - t)
    return min(times["kernel"]), min(times["torch"])


def _built():
    """The compiled (sincos, sin) pair or None, with the build message; built once per process."""
    if _state["built"] is None:
        _state["built"] = _build()
    return _state["built"]


def _choose(key: int, kernel, reference, what: str):
    """The built entry ``key`` (0: sincos, 1: sin) and a status message: kept if forced on or measured
    faster than torch's ``reference`` (``what`` names it), else None."""
    fns, msg = _built()
    if fns is None:
        return None, f"{msg}: {what}"
    if env_switch(ENV_SWITCH) is True:
        return fns[key], msg
    t_kernel, t_torch = _calibrate(lambda a, s: kernel(fns[key], a, s), reference)
    if t_kernel >= t_torch:
        return None, (f"fused C kernel measured no faster than torch's {torch.get_num_threads()}-thread "
                      f"{what.replace('torch.', '')} here ({1e6 * t_kernel:.0f} vs {1e6 * t_torch:.0f} µs): {what}")
    return fns[key], msg + f", {1e6 * t_kernel:.0f} µs vs torch's {1e6 * t_torch:.0f} µs per (4096, 64) chunk"


def _kernel():
    if _state["status"] is None:
        with _lock:
            if _state["status"] is None:
                _state["fn"], _state["status"] = _choose(
                    0, lambda fn, a, s: fn(a.data_ptr(), s.data_ptr(), a.data_ptr(), a.numel()),
                    lambda a, s: (torch.sin(a, out=s), a.cos_()), "torch.sin + torch.cos")
    return _state["fn"]


def _sin_kernel():
    if _state["sin_status"] is None:
        with _lock:
            if _state["sin_status"] is None:
                _state["sin_fn"], _state["sin_status"] = _choose(
                    1, lambda fn, a, s: fn(a.data_ptr(), a.data_ptr(), a.numel()), lambda a, s: a.sin_(), "torch.sin")
    return _state["sin_fn"]


def status() -> str:
    """Which sin/cos implementation :func:`sincos_` uses here (builds the kernel on first call)."""
    _kernel()
    return _state["status"]


def sin_status() -> str:
    """Which sine :func:`sin_` uses here (the kernel's sin-only entry, or torch.sin)."""
    _sin_kernel()
    return _state["sin_status"]


def kernel_available() -> bool:
    """True when the fused C kernel is built, loaded and in use (measured faster than torch's, or forced)."""
    return _kernel() is not None


def sin_kernel_available() -> bool:
    """True when :func:`sin_` uses the kernel's sin-only entry (measured faster than ``torch.sin``, or forced)."""
    return _sin_kernel() is not None


def _takes_kernel(t: torch.Tensor) -> bool:
    return (t.dtype == torch.float32 and t.device.type == "cpu" and t.is_contiguous() and not t.requires_grad
            and not torch.compiler.is_compiling())


def sincos_(a: torch.Tensor, s: torch.Tensor) -> None:
    """Write ``sin a`` into ``s`` and ``cos a`` into ``a`` (in place), both the same shape.

    The fused kernel for contiguous float32 CPU tensors (see module docstring), else ``torch.sin(a, out=s)``
    then ``a.cos_()``. Not for tensors that require grad (use :func:`neural_bake.nets.gemm.sin_cos`)."""
    fn = _kernel() if _takes_kernel(a) and _takes_kernel(s) and a.shape == s.shape else None
    if fn is None:
        torch.sin(a, out=s)
        a.cos_()
    else:
        fn(a.data_ptr(), s.data_ptr(), a.data_ptr(), a.numel())


def sin_(a: torch.Tensor) -> torch.Tensor:
    """``sin a`` in place (returns ``a``): the kernel's sin-only entry for contiguous float32 CPU tensors
    where it measured faster than ``torch.sin`` on first use, else ``a.sin_()``. No autograd (inference)."""
    fn = _sin_kernel() if _takes_kernel(a) else None
    if fn is None:
        return a.sin_()
    fn(a.data_ptr(), a.data_ptr(), a.numel())
    return a


def sincos(a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(sin a, cos a)`` as new tensors (``a`` is left alone); the fused kernel where :func:`sincos_` uses it.
    No autograd: call it on detached tensors (the autograd node is :func:`neural_bake.nets.gemm.sin_cos`)."""
    fn = _kernel() if _takes_kernel(a) else None
    if fn is None:
        return torch.sin(a), torch.cos(a)
    s, c = torch.empty_like(a), torch.empty_like(a)
    fn(a.data_ptr(), s.data_ptr(), c.data_ptr(), a.numel())
    return s, c
