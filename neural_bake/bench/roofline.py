"""This machine's roofline for SIREN work: peak GEMM and sine throughput, and a SIREN's cost in those units.

A SIREN's inference is GEMMs plus an element-wise ``sin`` per hidden unit, so its best possible time on a
machine is about ``flops / peak_gemm + transcendentals / sine_rate``. The benchmarks measure both rates in
the same run as the thing they compare (:func:`measure_roofline`), count a network's work
(:func:`siren_cost`), and report ``fraction = roofline time / measured time`` (1.0 = at the roofline)::

    roof = measure_roofline()
    cost = siren_cost(256, 3, n=262_144, grad="reverse")
    fraction = roofline_seconds(cost, roof) / measured_seconds

Counts are per point and exact for :mod:`neural_bake.nets.gemm` and :class:`~neural_bake.nets.siren.Siren`:
a multiply-add is 2 FLOPs, a bias add or an element-wise product 1 FLOP, ``sin`` and ``cos`` 1 transcendental.
"""

from __future__ import annotations

import math

import torch

from ..nets.siren import FORWARD_CHUNK_ELEMENTS, forward_chunk_size
from .common import timeit

__all__ = ["measure_roofline", "best_rates", "siren_cost", "roofline_seconds"]


def measure_roofline(
    *, dtype: torch.dtype = torch.float32, quick: bool = False, width: int = 256, repeat: int | None = None
) -> dict:
    """Peak GEMM FLOP rate and ``sin`` throughput of this CPU with torch's current thread count.

    Args:
        dtype: element type (float32: "sgemm").
        quick: fewer repetitions (noisier).
        width: inner size of the SIREN-shaped GEMM that is measured beside a large square one.
        repeat: timing repetitions (best of); default 10 (quick 4).

    Returns:
        ``{"gflops_sgemm", "gflops_square", "gflops_siren_shape", "gsin_per_s", "gsin_torch_per_s",
        "gsin_kernel_per_s", "gcos_per_s", "gmul_per_s", "threads", "dtype"}``: ``gflops_sgemm`` is the best
        of the square (1024³) and SIREN-shaped ((chunk, width) × (width, width), one chunk of the inference
        pass) products — the peak a SIREN layer can hope for; ``gsin_per_s`` is the faster of
        ``torch.sin`` (``gsin_torch_per_s``, written into a preallocated tensor) and, where it is in use,
        our C kernel's in-place sine (``gsin_kernel_per_s``, :func:`neural_bake.nets.fastmath.sin_`; else
        NaN), on one chunk's activation (:data:`~neural_bake.nets.siren.FORWARD_CHUNK_ELEMENTS` elements, in
        cache, as the SIREN passes run), in billions per second; ``gmul_per_s`` an element-wise product on
        the same size.
    """
    from ..nets import fastmath

    repeat = repeat or (4 if quick else 10)
    gen = torch.Generator().manual_seed(0)
    # element-wise passes first (right after a GEMM, the BLAS threads may still be spinning), ~1 ms each:
    # many tries, best of, so that a shared CPU's stalls do not count
    n_el = FORWARD_CHUNK_ELEMENTS  # the size of a chunk's activation: the passes a SIREN really makes
    s = torch.rand(n_el, generator=gen, dtype=dtype) * 20 - 10  # SIREN pre-activations are O(1..10)
    so = torch.empty_like(s)
    tries = {"repeat": max(repeat, 20), "min_time": 0.3}
    t_sin = timeit(lambda: torch.sin(s, out=so), **tries)
    t_sin_kernel = math.nan
    if dtype == torch.float32 and fastmath.sin_kernel_available():
        sk = s.clone()  # in place: the values settle in [-1, 1]; the kernel's cost does not depend on them
        t_sin_kernel = timeit(lambda: fastmath.sin_(sk), **tries)
    t_cos = timeit(lambda: torch.cos(s, out=so), **tries)
    s2 = torch.rand(n_el, generator=gen, dtype=dtype)
    t_mul = timeit(lambda: torch.mul(s, s2, out=so), **tries)  # not in place: repeated products would denormalise
    n_sq = 1024
    a = torch.rand(n_sq, n_sq, generator=gen, dtype=dtype)
    b = torch.rand(n_sq, n_sq, generator=gen, dtype=dtype)
    out = torch.empty(n_sq, n_sq, dtype=dtype)
    t_sq = timeit(lambda: torch.mm(a, b, out=out), repeat=repeat)
    gf_sq = 2 * n_sq**3 / t_sq / 1e9
    rows = forward_chunk_size(width)  # the products of one chunk
    x = torch.rand(rows, width, generator=gen, dtype=dtype)
    w = torch.rand(width, width, generator=gen, dtype=dtype)
    o2 = torch.empty(rows, width, dtype=dtype)
    t_sh = timeit(lambda: torch.mm(x, w.t(), out=o2), repeat=repeat)
    gf_sh = 2 * rows * width * width / t_sh / 1e9
    return {
        "gflops_sgemm": max(gf_sq, gf_sh),
        "gflops_square": gf_sq,
        "gflops_siren_shape": gf_sh,
        "gsin_per_s": n_el / min(t_sin, t_sin_kernel if t_sin_kernel == t_sin_kernel else math.inf) / 1e9,
        "gsin_torch_per_s": n_el / t_sin / 1e9,
        "gsin_kernel_per_s": n_el / t_sin_kernel / 1e9,
        "gcos_per_s": n_el / t_cos / 1e9,
        "gmul_per_s": n_el / t_mul / 1e9,
        "threads": torch.get_num_threads(),
        "dtype": str(dtype).replace("torch.", ""),
    }


def best_rates(readings: list[dict]) -> dict:
    """The best of each rate over several :func:`measure_roofline` readings (other work on the machine only
    ever slows a reading down); the non-rate fields of the first reading."""
    def best(k):
        vals = [r[k] for r in readings if r[k] == r[k]]  # NaN: a rate not measured in that reading
        return max(vals) if vals else math.nan

    return {k: best(k) if isinstance(v, float) else v for k, v in readings[0].items()}


def siren_cost(
    width: int, depth: int, n: int, grad: str | None = None, *, in_dim: int = 3, out_dim: int = 1
) -> dict:
    """FLOPs and transcendentals of a (width, depth) SIREN on ``n`` points.

    Args:
        width, depth: the papers' (W, D): D hidden W×W matrices, D + 1 sine layers.
        n: number of points.
        grad: None (values only), ``"reverse"`` or ``"forward"`` (GEMM normals of that mode, values
            included), or ``"fd"`` (central finite differences: 2·in_dim + 1 forward passes).
        in_dim, out_dim: input and output sizes.

    Returns:
        ``{"flops": float, "sines": float, "gemm_flops": float}``; ``sines`` counts sin and cos.
    """
    w, d, k = int(width), int(depth), int(out_dim)
    layers = d + 1  # sine layers
    gemm = 2.0 * n * (in_dim * w + d * w * w + w * k)
    bias = float(n) * (layers * w + k)
    sines = float(n) * layers * w
    if grad is None:
        return {"flops": gemm + bias, "sines": sines, "gemm_flops": gemm}
    if grad == "fd":
        passes = 2 * in_dim + 1
        return {"flops": passes * (gemm + bias), "sines": passes * sines, "gemm_flops": passes * gemm}
    if grad == "reverse":  # k streams back: W_n ⊙ cos A_D, then D W×W GEMMs and a W×in one, ⊙ cos per layer
        extra_gemm = 2.0 * n * k * (d * w * w + w * in_dim)
        extra_mul = float(n) * k * layers * w
    elif grad == "forward":  # in_dim streams: W_0[:, j] ⊙ cos A_0, then D W×W GEMMs and a W×k one
        extra_gemm = 2.0 * n * in_dim * (d * w * w + w * k)
        extra_mul = float(n) * in_dim * layers * w
    else:
        raise ValueError(f"siren_cost: grad must be None, 'reverse', 'forward' or 'fd', got {grad!r}")
    return {
        "flops": gemm + bias + extra_gemm + extra_mul,
        "sines": 2 * sines,  # sin and cos of every pre-activation
        "gemm_flops": gemm + extra_gemm,
    }


def roofline_seconds(cost: dict, roof: dict) -> float:
    """Best possible time of ``cost`` (from :func:`siren_cost`) on the machine ``roof`` describes.

    GEMM FLOPs at the peak GEMM rate, transcendentals at the ``sin`` rate, the other FLOPs (bias adds,
    element-wise products: memory-bound passes) at the in-place multiply rate.
    """
    other = cost["flops"] - cost["gemm_flops"]
    return (
        cost["gemm_flops"] / (roof["gflops_sgemm"] * 1e9)
        + cost["sines"] / (roof["gsin_per_s"] * 1e9)
        + other / (roof["gmul_per_s"] * 1e9)
    )
