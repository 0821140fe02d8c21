"""Which CPU library runs the float32 GEMMs of a network: the BLAS torch links, or oneDNN.

torch sends a float32 ``mm``/``addmm`` on the CPU to its BLAS (MKL in the CPU wheels) unless oneDNN is
allowed to take it (``torch.backends.mkldnn.matmul.fp32_precision = "bf16"``). On some CPUs oneDNN's
kernels are the faster ones for a SIREN's (N, W) × (W, W) products; on CPUs with AMX it may round the
operands to bfloat16 on the way (that setting allows it), which would cost accuracy. So the route is a
measured decision, per width, made once per process and only for the CPU:

- :func:`measure_route` times a (4096, W) × (W, W) product both ways (best of a few, interleaved) and
  measures each result's error against float64;
- :func:`decide_route` takes oneDNN only when it was at least :data:`~neural_bake.constants.ONEDNN_MIN_SPEEDUP`
  times faster **and** its relative error stayed within :data:`~neural_bake.constants.FP32_GEMM_REL_TOL`
  (float32 accuracy: a bfloat16 rounding of the operands reads ~1e-3);
- :func:`gemm_route` is the context manager the inference paths and the training loop run in.

A measured decision is kept in ``gemm-route.json`` of the machine's cache folder
(:mod:`neural_bake.nets.machine`, beside the step rates), keyed by CPU model, torch version, setting, width and
threads, so that a later process on the same machine reads it instead of measuring again (about 0.3 s of each
command's start: oneDNN builds its kernels at its first product). Delete the file to measure again.

The environment variable ``NEURAL_BAKE_CPU_GEMM`` = ``blas`` | ``onednn`` | ``auto`` (default) overrides the
decision; ``onednn`` still refuses a route that fails the accuracy check. The switch is a torch setting of
the process, set and restored around the work (not thread-safe, as any torch backend setting).
"""

from __future__ import annotations

import contextlib
import os
import time
from typing import Callable, Iterator

import torch

from ..constants import FP32_GEMM_REL_TOL, ONEDNN_MIN_SPEEDUP
from ..errors import NeuralBakeError
from .machine import cpu_model, read_facts, write_fact

__all__ = ["ROUTES", "ENV_ROUTE", "measure_route", "decide_route", "gemm_route", "model_width", "route_in_use",
           "reroute"]

#: Values of ``NEURAL_BAKE_CPU_GEMM``.
ROUTES = ("auto", "blas", "onednn")
ENV_ROUTE = "NEURAL_BAKE_CPU_GEMM"

_decided: dict[tuple[str, int], tuple[str, str]] = {}


def _matmul_setting():
    """torch's oneDNN matmul settings object (``fp32_precision``), or None where this torch has none."""
    matmul = getattr(torch.backends.mkldnn, "matmul", None)
    return matmul if torch.backends.mkldnn.is_available() and hasattr(matmul, "fp32_precision") else None


def _onednn_setting_exists() -> bool:
    return _matmul_setting() is not None


@contextlib.contextmanager
def _onednn(on: bool) -> Iterator[None]:
    matmul = _matmul_setting()
    if matmul is None:
        yield
        return
    before = matmul.fp32_precision
    matmul.fp32_precision = "bf16" if on else "none"
    try:
        yield
    finally:
        matmul.fp32_precision = before


def route_in_use() -> str:
    """"onednn" when float32 CPU GEMMs may go to oneDNN right now, else "blas"."""
    matmul = _matmul_setting()
    if matmul is not None and matmul.fp32_precision == "bf16":
        return "onednn"
    return "blas"


def measure_route(width: int, repeats: int = 5,
                  clock: Callable[[], float] = time.perf_counter) -> dict[str, float]:
    """Both routes of a float32 (4096, width) × (width, width) product on the CPU: ``speedup`` (BLAS
    seconds ÷ oneDNN seconds, best of ``repeats`` each) and each route's error relative to the float64
    product (``blas_error``, ``onednn_error``: max |Δ| ÷ max |product|)."""
    gen = torch.Generator().manual_seed(0)
    a = torch.randn(4096, int(width), generator=gen)
    w = torch.randn(int(width), int(width), generator=gen) / max(1.0, float(width)) ** 0.5
    exact = a.double() @ w.double()
    scale = float(exact.abs().max()) or 1.0
    best = {"blas": float("inf"), "onednn": float("inf")}
    error = {}
    for _ in range(max(1, int(repeats))):
        for name in best:
            with _onednn(name == "onednn"):
                t0 = clock()
                out = torch.mm(a, w)
                best[name] = min(best[name], clock() - t0)
            error[name] = float((out.double() - exact).abs().max()) / scale
    return {"speedup": best["blas"] / max(best["onednn"], 1e-12),
            "blas_error": error["blas"], "onednn_error": error["onednn"]}


def decide_route(width: int, *, measure: Callable[[int], dict] | None = None,
                 env: str | None = None) -> tuple[str, str]:
    """``(route, reason)`` for float32 CPU GEMMs of a ``width``-wide network: "blas" or "onednn".

    ``measure(width)`` returns :func:`measure_route`'s dict (default: that function; decisions are cached per
    setting, width and thread count unless a ``measure`` is given). ``env``: the override (default: ``NEURAL_BAKE_CPU_GEMM``); an
    unknown value raises :class:`NeuralBakeError` naming the variable.
    """
    value = (os.environ.get(ENV_ROUTE, "") if env is None else env).strip().lower() or "auto"
    if value not in ROUTES:
        raise NeuralBakeError(f"{ENV_ROUTE}={value!r}: must be one of {', '.join(ROUTES)}", parameter=ENV_ROUTE)
    if value == "blas":
        return "blas", f"{ENV_ROUTE}=blas"
    if not _onednn_setting_exists():
        return "blas", "this torch cannot send float32 GEMMs to oneDNN"
    width = int(width)
    key = (value, width, torch.get_num_threads())  # the route is measured with the threads that will run it
    if measure is None and key in _decided:  # gemm_route asks at every call: measure once
        return _decided[key]
    if measure is None:
        kept = read_facts(_DISK_FILE).get(_disk_key(key))
        if isinstance(kept, list) and len(kept) == 2 and kept[0] in ("blas", "onednn"):
            _decided[key] = (kept[0], f"{kept[1]} (measured on this machine before: {_DISK_FILE})")
            return _decided[key]
    m = (measure or measure_route)(width)
    if m["onednn_error"] > FP32_GEMM_REL_TOL:
        out = ("blas", f"oneDNN's float32 GEMM was not float32-accurate here (relative error "
                       f"{m['onednn_error']:.1e} > {FP32_GEMM_REL_TOL:.0e})")
    elif value == "onednn":
        out = ("onednn", f"{ENV_ROUTE}=onednn")
    elif m["speedup"] >= ONEDNN_MIN_SPEEDUP:
        out = ("onednn", f"oneDNN's float32 GEMM measured {m['speedup']:.2f}× the BLAS's here (width {width})")
    else:
        out = ("blas", f"oneDNN's float32 GEMM measured {m['speedup']:.2f}× (< {ONEDNN_MIN_SPEEDUP}×) the "
                       f"BLAS's here (width {width})")
    if measure is None:
        _decided[key] = out
        write_fact(_DISK_FILE, _disk_key(key), list(out))
    return out


#: The file (in :func:`~neural_bake.nets.machine.machine_cache_dir`) the measured decisions are kept in.
_DISK_FILE = "gemm-route.json"


def _disk_key(key: tuple[str, int, int]) -> str:
    return f"{cpu_model()} | torch {torch.__version__} | {key[0]} | width {key[1]} | {key[2]} threads"


def model_width(model) -> int | None:
    """A network's hidden width: its ``width`` attribute, else the largest dimension of its matrices
    (None when it has none)."""
    width = getattr(model, "width", None)
    if width:
        return int(width)
    dims = [max(p.shape) for p in getattr(model, "parameters", lambda: [])() if p.dim() == 2]
    return max(dims) if dims else None


def reroute(width: int | None, device: torch.device | str = "cpu") -> str:
    """Inside :func:`gemm_route`, after the thread count changed: set the route :func:`decide_route` picks for
    ``width`` with the threads now in force (the enclosing context restores torch's setting at its end)."""
    if torch.device(device).type != "cpu" or not width or not _onednn_setting_exists():
        return "blas" if torch.device(device).type == "cpu" else torch.device(device).type
    route, _ = decide_route(int(width))
    matmul = _matmul_setting()
    if matmul is not None:
        matmul.fp32_precision = "bf16" if route == "onednn" else "none"
    return route


@contextlib.contextmanager
def gemm_route(width: int | None, device: torch.device | str = "cpu", *,
               measure: Callable[[int], dict] | None = None) -> Iterator[str]:
    """Run the block with float32 CPU GEMMs on the route :func:`decide_route` picks for ``width``; yields the
    route. A non-CPU ``device`` or a ``width`` of None leaves torch's settings alone (yields "blas" on the
    CPU, the device type elsewhere)."""
    device = torch.device(device)
    if device.type != "cpu" or not width:
        yield "blas" if device.type == "cpu" else device.type
        return
    route, _ = decide_route(int(width), measure=measure)
    with _onednn(route == "onednn"):
        yield route
