"""Inference precision: float32 everywhere, or bfloat16 hidden GEMMs where the device runs them faster.

``precision`` settings: ``"fp32"`` (every product in float32), ``"bf16"`` (the hidden W×W products on
bfloat16 operands, accumulated in float32 by the BLAS; first and last layers, sin/cos and the gradient
stream's element-wise work stay float32) or ``"auto"``: bf16 only where it is supported for the network
(float32 weights, at least one hidden W×W matrix, a device whose BLAS has bf16 GEMMs) and a quick measured
check on this device says a (4096, W) × (W, W) product with the conversion runs at least
:data:`~neural_bake.constants.BF16_MIN_SPEEDUP` times faster than in float32; otherwise fp32.

:func:`resolve_precision` makes the decision (cached per device and width; the check's timer can be injected;
on the CPU a measured decision is kept in ``bf16-speedup.json`` of the machine's cache folder, as the float32
GEMM route is (:mod:`neural_bake.nets.cpu_gemm`), so a later process reads it instead of measuring again),
:func:`gemm_dtype` turns a resolved precision into the ``gemm_dtype`` argument of
:func:`~neural_bake.nets.gemm.gemm_gradient` and :func:`~neural_bake.nets.siren.siren_forward_inference`,
the one inference path that the baker (through the fields) and the preview renderer share.
"""

from __future__ import annotations

import copy
import time
from typing import Callable, TypeVar

import torch

from ..constants import BF16_MIN_SPEEDUP
from ..errors import NeuralBakeError
from .cpu_gemm import gemm_route
from .machine import cpu_model, read_facts, write_fact

__all__ = ["PRECISIONS", "resolve_precision", "gemm_dtype", "measure_bf16_speedup", "bf16_supported", "reduced_copy"]

#: The ``precision`` settings.
PRECISIONS = ("fp32", "bf16", "auto")

_decided: dict[tuple, tuple[str, str]] = {}
_F = TypeVar("_F")


def bf16_supported(device: torch.device | str = "cpu") -> tuple[bool, str]:
    """Can this device multiply bfloat16 matrices into float32 results here? (answer, reason)."""
    device = torch.device(device)
    try:
        a = torch.ones(8, 8, device=device, dtype=torch.bfloat16)
        out = torch.mm(a, a).float()
    except (RuntimeError, TypeError) as exc:  # no bf16 GEMM on this device / build
        return False, f"no bfloat16 GEMM on {device.type} ({str(exc).splitlines()[0][:80]})"
    if not bool((out == 8).all()):
        return False, f"bfloat16 GEMM on {device.type} gave wrong results"
    if device.type == "cpu" and not torch.backends.mkldnn.is_available():
        return False, "torch was built without oneDNN: bfloat16 GEMMs would be emulated"
    return True, "bfloat16 GEMMs available"


#: The file (in :func:`~neural_bake.nets.machine.machine_cache_dir`) the measured CPU decisions are kept in.
_DISK_FILE = "bf16-speedup.json"


def measure_bf16_speedup(width: int, device: torch.device | str = "cpu", repeats: int = 5,
                         clock: Callable[[], float] = time.perf_counter) -> float:
    """Seconds of a float32 (4096, width) × (width, width) product (on the CPU, on the route
    :mod:`neural_bake.nets.cpu_gemm` picks) ÷ seconds of the same with the operand converted to bfloat16 and
    the result back to float32 (best of ``repeats`` each, interleaved). A bfloat16 product slower than the
    float32 one by more than 2× ends the measurement (a CPU without bfloat16 units emulates them: each such
    product then costs a hundred float32 ones, and more rounds would not change the answer)."""
    device = torch.device(device)
    gen = torch.Generator().manual_seed(0)
    a = torch.rand(4096, int(width), generator=gen).to(device)
    w = torch.rand(int(width), int(width), generator=gen).to(device)
    wb = w.to(torch.bfloat16)
    best = {"fp32": float("inf"), "bf16": float("inf")}
    with gemm_route(int(width), device):  # float32 on the route its products take (nets.cpu_gemm)
        for _ in range(int(repeats)):
            for name, fn in (("fp32", lambda: torch.mm(a, w)),
                             ("bf16", lambda: torch.mm(a.to(torch.bfloat16), wb).float())):
                t0 = clock()
                fn().sum().item()  # .item(): waits for an asynchronous device
                best[name] = min(best[name], clock() - t0)
            if best["bf16"] > 2.0 * best["fp32"]:
                break
    return best["fp32"] / max(best["bf16"], 1e-12)


def resolve_precision(precision: str, model=None, *, device: torch.device | str | None = None,
                      dtype: torch.dtype | None = None,
                      measure: Callable[[int, torch.device], float] | None = None) -> tuple[str, str]:
    """The precision to run ``model`` in: ``("fp32" or "bf16", reason)``.

    - ``precision``: "fp32", "bf16" or "auto" (module docstring).
    - ``model``: a :class:`~neural_bake.nets.siren.Siren` (width, depth, parameters' dtype and device), or
      None for an analytic field (always fp32).
    - ``device``, ``dtype``: override the model's.
    - ``measure``: ``(width, device) -> speed-up`` of bf16 over fp32 (default :func:`measure_bf16_speedup`);
      auto decisions are cached per (device, width) unless a ``measure`` is given.

    "bf16" is refused (:class:`NeuralBakeError` naming ``precision``) where it is not supported; "auto" then
    falls back to fp32 and says why.
    """
    if precision not in PRECISIONS:
        raise NeuralBakeError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}",
                              parameter="precision")
    if precision == "fp32":
        return "fp32", "float32 asked for"
    if model is None or not hasattr(model, "parameters"):
        why = "an analytic field has no GEMMs"
        if precision == "bf16":
            raise NeuralBakeError(f"precision bf16: {why}", parameter="precision")
        return "fp32", why
    if getattr(model, "composite", False):  # nets.tiles.TiledSdf: many small networks, one precision
        why = "a tiled SDF's networks run in float32"
        if precision == "bf16":
            raise NeuralBakeError(f"precision bf16: {why}", parameter="precision")
        return "fp32", why
    p = next(model.parameters())
    device = torch.device(device) if device is not None else p.device
    dtype = dtype or p.dtype
    width, depth = int(getattr(model, "width", 0)), int(getattr(model, "depth", 0))
    why = None
    if dtype != torch.float32:
        why = f"the network runs in {str(dtype).replace('torch.', '')}, not float32"
    elif depth < 1:
        why = "the network has no hidden W×W matrix"
    else:
        ok, reason = bf16_supported(device)
        if not ok:
            why = reason
    if why is not None:
        if precision == "bf16":
            raise NeuralBakeError(f"precision bf16: {why}", parameter="precision")
        return "fp32", why
    if precision == "bf16":
        return "bf16", "bfloat16 asked for"
    key = (str(device), width)
    if measure is None and key in _decided:
        return _decided[key]
    disk = _disk_key(device, width) if measure is None and device.type == "cpu" else None
    if disk is not None:
        kept = read_facts(_DISK_FILE).get(disk)
        if isinstance(kept, list) and len(kept) == 2 and kept[0] in ("fp32", "bf16"):
            _decided[key] = (kept[0], f"{kept[1]} (measured on this machine before: {_DISK_FILE})")
            return _decided[key]
    speedup = float((measure or measure_bf16_speedup)(width, device))
    if speedup >= BF16_MIN_SPEEDUP:
        out = ("bf16", f"bfloat16 GEMMs measured {speedup:.2f}× faster here (width {width})")
    else:
        out = ("fp32", f"bfloat16 GEMMs measured {speedup:.2f}× (< {BF16_MIN_SPEEDUP}×) here (width {width})")
    if measure is None:
        _decided[key] = out
    if disk is not None:
        write_fact(_DISK_FILE, disk, list(out))
    return out


def _disk_key(device: torch.device, width: int) -> str:
    """The key of a CPU decision in :data:`_DISK_FILE`: CPU model, torch version, width and thread count (the
    measurement runs on the threads in force)."""
    return f"{cpu_model()} | torch {torch.__version__} | {device.type} | width {width} | " \
           f"{torch.get_num_threads()} threads"


def gemm_dtype(precision: str) -> torch.dtype | None:
    """The ``gemm_dtype`` argument of the inference functions for a resolved precision ("fp32" or "bf16")."""
    if precision == "bf16":
        return torch.bfloat16
    if precision == "fp32":
        return None
    raise NeuralBakeError(f"precision must be resolved to fp32 or bf16, got {precision!r}", parameter="precision")


def reduced_copy(field: _F, precision: str, *, measure=None) -> tuple[_F, str, str]:
    """``(field', resolved, reason)``: a shallow copy of a field (anything with ``model`` and ``gemm_dtype``)
    whose hidden GEMMs run at the resolved ``precision``, or ``field`` itself when that is fp32."""
    resolved, reason = resolve_precision(precision, getattr(field, "model", None), measure=measure)
    if resolved == "fp32":
        return field, resolved, reason
    out = copy.copy(field)
    setattr(out, "gemm_dtype", gemm_dtype(resolved))
    return out, resolved, reason
