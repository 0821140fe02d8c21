"""Guaranteed range bounds of a SIREN over boxes: interval and affine arithmetic (Spelunking §3, App. A).

A *box* is ``x = c + Σ_k t_k v_k`` with ``t ∈ [-1, 1]^s``: a centre ``c`` (d,) and ``s`` half-axis vectors
``v_k`` (d,) — ``s = 1`` for a ray segment, ``s = d`` for a (possibly rotated) box. The axes are meant to be
orthogonal as in the paper, but nothing relies on it: the bound holds for the parallelotope they span.

Methods (names as in Sharp & Jacobson, "Spelunking the deep", §3.1–3.3 and Table 1):

- ``"interval"``: interval arithmetic (centre/radius form): cheapest, very pessimistic.
- ``"affine-fixed"``: affine arithmetic that keeps only the input noise symbols; every error a layer makes
  is condensed at once into the one distinguished symbol ε_∞ (the paper's x_∞). Cheap; the paper's choice
  for ray casting.
- ``"affine-full"``: no condensation: every ``sin`` neuron adds a fresh symbol (s + d + W·(D+1) symbols at the
  output, counting the d input-rounding symbols of item 2 below). Tightest; the paper's choice for volumetric queries; cost grows with width × depth.
- ``"affine-truncate"``: after each ``sin`` layer keep the ``keep`` largest new symbols (L1 norm of their
  coefficients over the layer's neurons) and condense the rest into ε_∞. The input symbols are always kept
  (they are the ones :func:`difference_bound` shares between two networks).

(Spelunking's "affine-append" variant, which its Table 1 found no better than fixed/full, is not provided.)

Representation (App. A): a layer's values are ``x0 + Σ_i X_i ε_i + x_∞ ⊙ ε_∞`` with ``x0`` (B, m),
``X`` (N, B, m) (symbol-major, so a linear layer is one GEMM written into a buffer that already has room for
the layer's new symbols) and ``x_∞`` (B, m) ≥ 0; the update rules are those of Table 2. The ``sin`` rule is Table 3's, written around the centre ``c`` of the pre-activation range
``[c - r, c + r]`` to stay accurate for tiny ``r``: with ``α = (min cos + max cos) / 2`` over the range and
``h(t) = sin(c + t) - sin(c) - α t = 2 cos(c + t/2) sin(t/2) - α t``, the extremes of ``h`` on ``[-r, r]`` are
at the ends or where ``cos(c + t) = α`` (found by modular arithmetic), giving
``|sin(c + t) - (sin c + mid h) - α t| <= (max h - min h) / 2``. For ``r >= π`` the best affine
approximation is the constant 0 with error 1 (|sin| <= 1).

Floating point (documented allowance; the paper ignores rounding):

1. The arithmetic runs in float64 (``compute_dtype``; float32 on devices without float64), whatever the
   input dtype, so that its own rounding is negligible (``compute_dtype=torch.float32`` is allowed and still
   sound, but its allowances, condensed into ε_∞, grow by the row sums of |W| at every layer: on a (256, 3)
   SIREN bounds get ~20× looser); every rounding it does is still covered by
   Higham's bound |fl(Σ a_i b_i) - Σ a_i b_i| <= γ_{n+1} Σ|a_i b_i| (γ_n = n u / (1 - n u), u the unit
   roundoff): a linear layer adds ``2 (n + 2) u (|W| M + |b|)`` to ε_∞, where ``M = |x0| + Σ|X| + x_∞``
   bounds the layer input; the ``sin`` rule adds ``8 u (1 + r (|c| + r + 4)) + δ²`` with
   ``δ = 8 u (|c| + 8)`` (argument rounding of ``c + t/2`` and a critical point located δ off, where h is flat
   to second order); sums of |coefficients| are inflated by ``(1 + 2 (N + 1) u)``; the final
   ``centre ± radius`` by ``4 u (|centre| + radius)``.
2. Sample points ``c + Σ t_k v_k`` computed in the *input* precision are off the exact box by at most
   ``(s + 1) u_in (|c| + Σ_k |v_k|)`` per coordinate: these become d extra input noise symbols (so they keep
   their correlations, and are shared by :func:`difference_bound`). When ``compute_dtype`` is less precise
   than the input, the rounding of converting ``c`` and ``v`` is added to them too.
3. When the network is evaluated in a lower precision than the bound is computed in (float32 model or
   float32 boxes), the evaluation's own rounding is covered by widening the result by
   ``E = 8 (D + 2) u_eval (1 + max(|lo|, |hi|))`` — an *empirical* allowance: the largest float32 forward
   error against float64 that we measured on random SIRENs (widths 16–256, depth 1–3, ω0 1–60) was under
   4 u (1 + |f|), i.e. E leaves a margin of at least 6×. For a strict guarantee of the exact function pass a
   float64 model and float64 boxes (then E = 0 and every allowance is a proven one).
4. The result is rounded outwards to the output dtype. Any non-finite intermediate (overflow) gives the
   trivial bound (-inf, inf), never NaN.
"""

from __future__ import annotations

import math
from typing import Sequence

import torch

from ..constants import RANGE_ROUNDING_MARGIN
from ..errors import NeuralBakeError

__all__ = [
    "METHODS",
    "range_bound",
    "difference_bound",
    "affine_sin",
    "interval_sin",
]

#: Range-analysis methods, cheapest first.
METHODS = ("interval", "affine-fixed", "affine-full", "affine-truncate")

#: Bytes the per-box coefficient tensors may take at once (boxes are processed in chunks under this).
MEMORY_BUDGET = 1 << 28

_TWO_PI = 2.0 * math.pi


def _unit_roundoff(dtype: torch.dtype) -> float:
    return torch.finfo(dtype).eps / 2.0


# --------------------------------------------------------------------------------------------------------------
# elementary rules
# --------------------------------------------------------------------------------------------------------------


def affine_sin(center: torch.Tensor, radius: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Affine enclosure of ``sin`` on ``[center - radius, center + radius]`` (Spelunking Table 3, stable form).

    Args:
        center: (...) float tensor, centre ``c`` of each range.
        radius: (...) float tensor ≥ 0 (same shape), half-width ``r``.

    Returns:
        ``(mid, alpha, gamma)``, each shaped like ``center``, such that for every ``|t| <= r``::

            |sin(c + t) - mid - alpha * t| <= gamma

        ``alpha`` is the mean of the smallest and largest ``cos`` on the range (Table 3); ``gamma`` includes the
        rounding allowance of the module docstring. For ``r >= π`` (or non-finite input) the result is the
        constant ``(0, 0, 1)``. Computed in the dtype of ``center``.
    """
    c = center
    u = _unit_roundoff(c.dtype)
    wide = ~(radius < math.pi) | ~torch.isfinite(c)
    r = torch.where(wide, torch.zeros_like(radius), radius)
    cf = torch.where(torch.isfinite(c), c, torch.zeros_like(c))
    lo_x, hi_x = cf - r, cf + r
    ca, cb = torch.cos(lo_x), torch.cos(hi_x)
    cmax, cmin = torch.maximum(ca, cb), torch.minimum(ca, cb)
    # interior extremes of cos: maxima at 2πk, minima at π + 2πk
    k_max = torch.ceil(lo_x / _TWO_PI) * _TWO_PI
    k_min = torch.ceil((lo_x - math.pi) / _TWO_PI) * _TWO_PI + math.pi
    cmax = torch.where(k_max <= hi_x, torch.ones_like(cmax), cmax)
    cmin = torch.where(k_min <= hi_x, -torch.ones_like(cmin), cmin)
    alpha = ((cmax + cmin) * 0.5).clamp(-1.0, 1.0)
    theta = torch.acos(alpha)

    def h(t):  # sin(c + t) - sin(c) - alpha t, without cancellation for small t
        return 2.0 * torch.cos(cf + 0.5 * t) * torch.sin(0.5 * t) - alpha * t

    cands = [-r, r]
    for e in (theta, -theta):
        # critical points c + t = e + 2πk; for r < π at most one per family lies in [-r, r]: the one nearest t = 0
        k = torch.round((cf - e) / _TWO_PI)
        t = e + _TWO_PI * k - cf
        cands.append(torch.minimum(torch.maximum(t, -r), r))
    hs = torch.stack([h(t) for t in cands])
    hu, hl = hs.amax(0), hs.amin(0)
    delta = 8.0 * u * (cf.abs() + 8.0)
    allowance = 8.0 * u * (1.0 + r * (cf.abs() + r + 4.0)) + delta * delta
    mid = torch.sin(cf) + 0.5 * (hu + hl)
    gamma = 0.5 * (hu - hl) + allowance
    zero, one = torch.zeros_like(mid), torch.ones_like(mid)
    mid = torch.where(wide, zero, mid)
    alpha = torch.where(wide, zero, alpha)
    gamma = torch.where(wide, one, gamma)
    return mid, alpha, gamma


def interval_sin(center: torch.Tensor, radius: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Interval enclosure of ``sin`` on ``[center - radius, center + radius]``.

    Args:
        center, radius: (...) float tensors of the same shape, ``radius >= 0``.

    Returns:
        ``(mid, rad)`` with ``sin(x) ∈ [mid - rad, mid + rad]`` for every x in the range: the exact range of
        ``sin`` (ends, plus ±1 when a peak π/2 + 2πk or a trough -π/2 + 2πk lies inside) widened by a rounding
        allowance ``8 u (1 + |c| + r)``; ``(0, 1)`` for ``r >= π`` or non-finite input.
    """
    c = center
    u = _unit_roundoff(c.dtype)
    wide = ~(radius < math.pi) | ~torch.isfinite(c)
    r = torch.where(wide, torch.zeros_like(radius), radius)
    cf = torch.where(torch.isfinite(c), c, torch.zeros_like(c))
    lo_x, hi_x = cf - r, cf + r
    sa, sb = torch.sin(lo_x), torch.sin(hi_x)
    smax, smin = torch.maximum(sa, sb), torch.minimum(sa, sb)
    peak = torch.ceil((lo_x - 0.5 * math.pi) / _TWO_PI) * _TWO_PI + 0.5 * math.pi
    trough = torch.ceil((lo_x + 0.5 * math.pi) / _TWO_PI) * _TWO_PI - 0.5 * math.pi
    smax = torch.where(peak <= hi_x, torch.ones_like(smax), smax)
    smin = torch.where(trough <= hi_x, -torch.ones_like(smin), smin)
    delta = 8.0 * u * (cf.abs() + 8.0)
    mid = 0.5 * (smax + smin)
    rad = 0.5 * (smax - smin) + 8.0 * u * (1.0 + cf.abs() + r) + delta * delta
    mid = torch.where(wide, torch.zeros_like(mid), mid)
    rad = torch.where(wide, torch.ones_like(rad), rad)
    return mid, rad


# --------------------------------------------------------------------------------------------------------------
# propagation through the network
# --------------------------------------------------------------------------------------------------------------


def _abs_sum(t: torch.Tensor, dim: int, u: float) -> torch.Tensor:
    """Σ|t| along ``dim``, inflated to cover the rounding of the sum (an upper bound)."""
    n = t.shape[dim]
    if n == 0:
        return t.new_zeros(t.shape[:dim] + t.shape[dim + 1:])
    # vector_norm is fused (no |t| temporary) but slow along a leading, strided dimension
    total = torch.linalg.vector_norm(t, 1, dim=dim) if dim in (-1, t.dim() - 1) else t.abs().sum(dim)
    return total * (1.0 + 2.0 * (n + 1) * u)


def _propagate(layers, x0, X, xinf, method: str, keep: int, n_in: int, u: float):
    """Push an affine form through the network (Table 2 for linear layers, Table 3 for ``sin``).

    The form is ``x0`` (B, d) + Σ_i ``X[i]`` ε_i + ``xinf`` (B, d) ⊙ ε_∞ with ``X`` (N, B, d): symbol-major, so a
    linear layer is one (N·B, m) × (m, o) GEMM written straight into a buffer that already has room for the
    layer's new symbols (no concatenation). The first ``n_in`` symbols are the input ones.

    Returns ``(z0 (B,), z_in (B, n_in), rest (B,), n_sym)``: the output's centre, the coefficients of the input
    symbols, and an upper bound of Σ|other coefficients| + z_∞ (the part shared with nothing).
    """
    last = len(layers) - 1
    keep_new = method in ("affine-full", "affine-truncate")
    xabs = _abs_sum(X, 0, u)  # upper bound of Σ_i |X[i]|, (B, d)
    for i, (w, b) in enumerate(layers):
        nsym, bsz, m = X.shape
        o = w.shape[0]
        extra = o if keep_new and i < last else 0
        buf = X.new_empty((nsym + extra, bsz, o))
        if nsym:
            torch.mm(X.reshape(nsym * bsz, m), w.t(), out=buf[:nsym].view(nsym * bsz, o))
        wa = w.abs()
        z0 = torch.addmm(b, x0, w.t())
        # Higham: every computed dot product is within γ_{m+1} Σ|terms| of the exact one; the terms are bounded
        # by |W| (|x0| + Σ|X| + x_∞) + |b|. The new error joins ε_∞ (with the carried |W| x_∞, Table 2).
        zinf = xinf @ wa.t() + 2.0 * (m + 2) * u * ((x0.abs() + xabs + xinf) @ wa.t() + b.abs())
        X, x0, xinf = buf, z0, zinf
        if i == last:
            break
        Z = buf[:nsym]
        if method == "interval":
            x0, xinf = interval_sin(z0, zinf)
            xabs = torch.zeros_like(x0)
            continue
        zabs = _abs_sum(Z, 0, u)
        mid, alpha, gamma = affine_sin(z0, zinf + zabs)
        Z.mul_(alpha)
        a = alpha.abs()
        x0, xinf, xabs = mid, a * zinf, a * zabs * (1.0 + 2.0 * u)
        if not keep_new:  # affine-fixed: condense the new error into ε_∞ at once
            xinf = xinf + gamma
            continue
        new_block = buf[nsym:]  # (o, B, o): one fresh symbol per neuron, coefficient γ on its own neuron
        new_block.zero_()
        new_block.diagonal(dim1=0, dim2=2).copy_(gamma)
        xabs = xabs + gamma
        n_new = X.shape[0] - n_in
        if method == "affine-truncate" and n_new > keep:
            new = X[n_in:]
            mags = torch.linalg.vector_norm(new, 1, dim=2)  # (n_new, B): size of each symbol's contribution
            idx = torch.topk(mags, keep, dim=0, sorted=False).indices
            drop = torch.ones_like(mags, dtype=torch.bool).scatter_(0, idx, False)
            xinf = xinf + _abs_sum(new * drop[..., None], 0, u)
            kept = torch.gather(new, 0, idx[..., None].expand(-1, -1, o))
            X = torch.cat([X[:n_in], kept], dim=0)
    z0 = x0[:, 0]
    z_in = X[:n_in, :, 0].t()
    rest = xinf[:, 0] + _abs_sum(X[n_in:, :, 0], 0, u)
    return z0, z_in, rest, X.shape[0]


# --------------------------------------------------------------------------------------------------------------
# input checks and set-up
# --------------------------------------------------------------------------------------------------------------


def _layers_of(fn: str, model, arg: str):
    if not hasattr(model, "affine_layers"):
        raise NeuralBakeError(f"{fn}: {arg} must be a Siren (a model with affine_layers()), got {type(model).__name__}")
    layers = model.affine_layers()
    if layers[-1][0].shape[0] != 1:
        raise NeuralBakeError(
            f"{fn}: {arg} must have a scalar output (out_dim 1), got out_dim {layers[-1][0].shape[0]}")
    return layers


def _check_boxes(fn: str, center, axes, d: int):
    center = torch.as_tensor(center)
    axes = torch.as_tensor(axes)
    if center.dim() != 2 or center.shape[1] != d:
        raise NeuralBakeError(f"{fn}: center must have shape (B, {d}), got {tuple(center.shape)}")
    bsz = center.shape[0]
    if axes.dim() != 3 or axes.shape[0] != bsz or axes.shape[2] != d:
        raise NeuralBakeError(f"{fn}: axes must have shape ({bsz}, s, {d}), got {tuple(axes.shape)}")
    for name, t in (("center", center), ("axes", axes)):
        if not t.is_floating_point():
            raise NeuralBakeError(f"{fn}: {name} must be a floating-point tensor, got {t.dtype}")
        if not bool(torch.isfinite(t).all()):
            raise NeuralBakeError(f"{fn}: {name} has non-finite values")
    if center.device != axes.device:
        raise NeuralBakeError(f"{fn}: center and axes are on different devices ({center.device}, {axes.device})")
    return center, axes


def _check_method(fn: str, method: str, keep: int, chunk):
    if method not in METHODS:
        raise NeuralBakeError(f"{fn}: unknown method {method!r} (expected one of {', '.join(METHODS)})")
    if int(keep) != keep or keep < 1:
        raise NeuralBakeError(f"{fn}: keep must be a positive integer, got {keep!r}")
    if chunk is not None and (int(chunk) != chunk or chunk < 1):
        raise NeuralBakeError(f"{fn}: chunk must be a positive integer or None, got {chunk!r}")


def _compute_dtype(device: torch.device, requested) -> torch.dtype:
    if requested is not None:
        return requested
    return torch.float32 if device.type == "mps" else torch.float64


def _input_form(center: torch.Tensor, axes: torch.Tensor, u_in: float, cdtype: torch.dtype, method: str):
    """The input affine form: s axis symbols + d rounding symbols (or, for interval, radii in x_∞)."""
    c = center.to(cdtype)
    v = axes.to(cdtype)
    s = v.shape[1]
    # rounding of sample points computed in the input precision, per coordinate; plus, when the arithmetic is
    # less precise than the input, the rounding of this conversion of c and v
    u_c = _unit_roundoff(cdtype)
    rel = (s + 1) * u_in + (2.0 * (s + 1) * u_c if u_c > u_in else 0.0)
    rho = rel * (c.abs() + v.abs().sum(1)) * (1.0 + RANGE_ROUNDING_MARGIN)
    if method == "interval":
        rad = _abs_sum(v, 1, u_c) + rho
        return c, c.new_zeros((0, c.shape[0], c.shape[1])), rad
    X = torch.cat([v.transpose(0, 1), torch.diag_embed(rho).permute(1, 0, 2)], dim=0)  # (s + d, B, d)
    return c, X, torch.zeros_like(c)


def _chunk_size(layers_list: Sequence, n_in: int, method: str, keep: int, itemsize: int) -> int:
    width = max(max(w.shape[0], w.shape[1]) for layers in layers_list for w, _ in layers)
    n_hidden = max(len(layers) - 1 for layers in layers_list)
    if method == "interval":
        nsym = 1
    elif method == "affine-fixed":
        nsym = n_in
    elif method == "affine-full":
        nsym = n_in + width * n_hidden
    else:
        nsym = n_in + min(keep, width * n_hidden) + width
    # the coefficient tensor and its temporaries, plus the ~30 (B, width) temporaries of the sin rule
    per_box = (6 * nsym + 32) * width * itemsize
    return max(1, MEMORY_BUDGET // per_box)


def _eval_allowance(layers_list, in_dtype, param_dtypes, cdtype) -> float:
    """Relative allowance E / (1 + max|bound|) for evaluating the network in a lower precision (item 3)."""
    u_eval = max(_unit_roundoff(dt) for dt in [in_dtype, *param_dtypes])
    if u_eval <= _unit_roundoff(cdtype):
        return 0.0
    depth = max(len(layers) - 2 for layers in layers_list)  # D: hidden W×W matrices
    return 8.0 * (depth + 2) * u_eval


def _round_out(lo: torch.Tensor, hi: torch.Tensor, dtype: torch.dtype):
    """Round a (lo, hi) pair outwards to ``dtype``; non-finite or NaN bounds become (-inf, inf)."""
    bad = ~(torch.isfinite(lo) & torch.isfinite(hi))
    lo = torch.where(bad, torch.full_like(lo, -math.inf), lo)
    hi = torch.where(bad, torch.full_like(hi, math.inf), hi)
    if dtype == lo.dtype:
        return lo, hi
    lo_d, hi_d = lo.to(dtype), hi.to(dtype)
    lo_d = torch.where(lo_d.to(lo.dtype) > lo, torch.nextafter(lo_d, torch.full_like(lo_d, -math.inf)), lo_d)
    hi_d = torch.where(hi_d.to(hi.dtype) < hi, torch.nextafter(hi_d, torch.full_like(hi_d, math.inf)), hi_d)
    return lo_d, hi_d


def _prepare(fn, models, center, axes, method, keep, chunk, compute_dtype):
    _check_method(fn, method, keep, chunk)
    names = ("model",) if len(models) == 1 else ("h", "f")
    layers_list = [_layers_of(fn, m, n) for m, n in zip(models, names)]
    d = layers_list[0][0][0].shape[1]
    if len(layers_list) == 2 and layers_list[1][0][0].shape[1] != d:
        raise NeuralBakeError(
            f"{fn}: h and f take inputs of different dimension ({d} and {layers_list[1][0][0].shape[1]})")
    center, axes = _check_boxes(fn, center, axes, d)
    out_dtype = torch.promote_types(center.dtype, axes.dtype)
    cdtype = _compute_dtype(center.device, compute_dtype)
    param_dtypes = [layers[0][0].dtype for layers in layers_list]
    with torch.no_grad():
        layers_list = [[(w.detach().to(center.device, cdtype), b.detach().to(center.device, cdtype))
                        for w, b in layers] for layers in layers_list]
    u_in = _unit_roundoff(out_dtype)
    n_in = 0 if method == "interval" else axes.shape[1] + d
    if chunk is None:
        chunk = _chunk_size(layers_list, n_in, method, keep, torch.finfo(cdtype).bits // 8)
    e_rel = _eval_allowance(layers_list, out_dtype, param_dtypes, cdtype)
    return layers_list, center, axes, out_dtype, cdtype, u_in, n_in, int(chunk), e_rel


# --------------------------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------------------------


def range_bound(
    model,
    center: torch.Tensor,
    axes: torch.Tensor,
    method: str = "affine-fixed",
    *,
    keep: int = 64,
    chunk: int | None = None,
    compute_dtype: torch.dtype | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Guaranteed bounds of a scalar SIREN over a batch of boxes (Spelunking Procedure 1, without the sign test).

    Args:
        model: a :class:`~neural_bake.nets.siren.Siren` with ``out_dim == 1`` (any ``in_dim`` = d).
        center: (B, d) float tensor, box centres (in the model's input frame, e.g. the unit frame).
        axes: (B, s, d) float tensor, ``s`` half-axis vectors per box (s = 1 ray segment, s = d box; s = 0 a
            point); the box is ``{center + Σ_k t_k axes[:, k] : t ∈ [-1, 1]^s}``.
        method: one of :data:`METHODS` (see the module docstring).
        keep: for ``"affine-truncate"``, how many non-input noise symbols to keep after each layer.
        chunk: boxes per batch (default: as many as fit :data:`MEMORY_BUDGET`).
        compute_dtype: dtype of the arithmetic (default float64; float32 on MPS).

    Returns:
        ``(lo, hi)``, two (B,) tensors on ``center``'s device in the dtype of the inputs, with
        ``lo <= f(x) <= hi`` for every x in each box (including the rounding allowances of the module docstring).

    Raises:
        NeuralBakeError (a ValueError): bad shapes (the message gives the expected shape), non-finite boxes,
        an unknown method, a model with more than one output.
    """
    fn = "range_bound"
    if getattr(model, "composite", False):  # a field of several networks (nets.tiles.TiledSdf) bounds its parts
        return model.range_bound(torch.as_tensor(center), torch.as_tensor(axes), method)
    layers_list, center, axes, out_dtype, cdtype, u_in, n_in, chunk, e_rel = _prepare(
        fn, [model], center, axes, method, keep, chunk, compute_dtype)
    (layers,) = layers_list
    u = _unit_roundoff(cdtype)
    los, his = [], []
    with torch.no_grad():
        for start in range(0, center.shape[0], chunk):
            c, v = center[start:start + chunk], axes[start:start + chunk]
            x0, X, xinf = _input_form(c, v, u_in, cdtype, method)
            z0, z_in, rest, nsym = _propagate(layers, x0, X, xinf, method, keep, n_in, u)
            rad = rest + (_abs_sum(z_in, 1, u) if z_in.shape[1] else 0.0)
            margin = 4.0 * u * (z0.abs() + rad)
            lo, hi = z0 - rad - margin, z0 + rad + margin
            if e_rel:
                e = e_rel * (1.0 + torch.maximum(lo.abs(), hi.abs()))
                lo, hi = lo - e, hi + e
            los.append(lo)
            his.append(hi)
    if not los:
        empty = center.new_zeros((0,), dtype=out_dtype)
        return empty, empty.clone()
    return _round_out(torch.cat(los), torch.cat(his), out_dtype)


def add_bounds(lo: torch.Tensor, hi: torch.Tensor, lo_b: torch.Tensor, hi_b: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """Bounds of the sum of two bounded terms: (lo + lo_b, hi + hi_b), each sum rounded outward by one ulp."""
    inf = torch.tensor(math.inf, dtype=lo.dtype, device=lo.device)
    return torch.nextafter(lo + lo_b, -inf), torch.nextafter(hi + hi_b, inf)


def _composite_difference(h, f, center, axes, method, **kwargs) -> tuple[torch.Tensor, torch.Tensor]:
    """Bounds of h − f where h or f is a tiled SDF c + r: the difference of the SIRENs (h − c or c − f) with
    shared noise symbols, minus (or plus) r's range bound over the box."""
    center, axes = torch.as_tensor(center), torch.as_tensor(axes)
    if getattr(f, "composite", False):  # h − (c + r) = (h − c) − r
        lo, hi = difference_bound(h, f.coarse, center, axes, method, **kwargs)
        r_lo, r_hi = f.tiles.range_bound(center.to(lo.dtype), axes.to(lo.dtype), method)
        return add_bounds(lo, hi, -r_hi, -r_lo)
    lo, hi = difference_bound(h.coarse, f, center, axes, method, **kwargs)  # (c + r) − f = (c − f) + r
    return add_bounds(lo, hi, *h.tiles.range_bound(center.to(lo.dtype), axes.to(lo.dtype), method))


def difference_bound(
    h,
    f,
    center: torch.Tensor,
    axes: torch.Tensor,
    method: str = "affine-fixed",
    *,
    keep: int = 64,
    chunk: int | None = None,
    compute_dtype: torch.dtype | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Guaranteed bounds of ``h(x) - f(x)`` over a batch of boxes, with h and f sharing the input noise symbols.

    Both networks are pushed through affine arithmetic from the *same* input form, so the part of their
    variation that comes from the position inside the box cancels in the difference (only the errors each
    network's nonlinearities add stay separate). Where h ≈ f this is far tighter than subtracting two
    :func:`range_bound` results; it certifies nesting thresholds (Nested Neighborhoods, Prop. 1):
    ``|h - f| <= max(-lo, hi)`` on each box. With ``method="interval"`` nothing is shared (interval
    arithmetic has no symbols) and the result is the difference of the two ranges.

    Args:
        h, f: Sirens with ``out_dim == 1`` and the same ``in_dim`` = d, or a tiled SDF
            (:class:`~neural_bake.nets.tiles.TiledSdf`) of 3 inputs: its coarse SIREN shares the symbols, its tiles'
            range bound is added.
        center, axes, method, keep, chunk, compute_dtype: as in :func:`range_bound`.

    Returns:
        ``(lo, hi)``, (B,) tensors in the inputs' dtype with ``lo <= h(x) - f(x) <= hi`` on every box.
    """
    fn = "difference_bound"
    if getattr(f, "composite", False) or getattr(h, "composite", False):  # a tiled SDF (nets.tiles.TiledSdf):
        return _composite_difference(h, f, center, axes, method, keep=keep, chunk=chunk,  # its coarse SIREN
                                     compute_dtype=compute_dtype)  # shares the symbols, its tiles are bounded
    layers_list, center, axes, out_dtype, cdtype, u_in, n_in, chunk, e_rel = _prepare(
        fn, [h, f], center, axes, method, keep, chunk, compute_dtype)
    u = _unit_roundoff(cdtype)
    los, his = [], []
    with torch.no_grad():
        for start in range(0, center.shape[0], chunk):
            c, v = center[start:start + chunk], axes[start:start + chunk]
            outs = []
            for layers in layers_list:
                x0, X, xinf = _input_form(c, v, u_in, cdtype, method)
                outs.append(_propagate(layers, x0, X, xinf, method, keep, n_in, u))
            (h0, h_in, h_rest, _), (f0, f_in, f_rest, _) = outs
            d0 = h0 - f0
            rad = h_rest + f_rest
            if n_in:
                rad = rad + _abs_sum(h_in - f_in, 1, u) + 2.0 * u * (_abs_sum(h_in, 1, u) + _abs_sum(f_in, 1, u))
            margin = 4.0 * u * (h0.abs() + f0.abs() + rad)
            lo, hi = d0 - rad - margin, d0 + rad + margin
            if e_rel:
                # each network's evaluation error, relative to its own magnitude
                mag_h = h0.abs() + h_rest + (_abs_sum(h_in, 1, u) if n_in else 0.0)
                mag_f = f0.abs() + f_rest + (_abs_sum(f_in, 1, u) if n_in else 0.0)
                e = e_rel * (2.0 + mag_h + mag_f)
                lo, hi = lo - e, hi + e
            los.append(lo)
            his.append(hi)
    if not los:
        empty = center.new_zeros((0,), dtype=out_dtype)
        return empty, empty.clone()
    return _round_out(torch.cat(los), torch.cat(his), out_dtype)
