"""The SDF training loss (:func:`sdf_loss_terms`) and one step's forward and backward in micro-batches.

∇f is computed by :func:`~neural_bake.nets.gemm.gemm_gradient` with ``differentiable=True`` (the closed-form
GEMM gradient as one autograd node with a hand-written backward): the values and gradients of all the step's
points come from one pass, and the loss needs one ordinary ``backward()``, no double-backward.
"""

from __future__ import annotations

import torch

from ..constants import LOSS_GRAD_FLOOR, NORMAL_ANGLE_EPS
from ..nets.gemm import gemm_gradient, sin_cos
from ..nets.siren import Siren
from .sdf_config import SdfFitConfig

__all__ = ["mixed_gradient", "sdf_loss_terms", "loss_terms_of", "smooth_angle", "first_order_distance", "focused_squares",
           "sdf_step_backward", "FIRST_ORDER_MIN_SLOPE", "FOCUS_CAP"]


def mixed_gradient(model: Siren, points: torch.Tensor, gemm_dtype: torch.dtype = torch.bfloat16):
    """Values (N, 1) and gradients (N, 3) of ``model`` on the autograd graph, hidden GEMMs in ``gemm_dtype``.

    The reverse-mode GEMM gradient of :func:`~neural_bake.nets.gemm.gemm_gradient` (``differentiable=True``),
    with the D hidden W×W products of the forward pass and of the gradient stream computed on
    ``gemm_dtype`` operands (results converted back to the points' dtype); the first layer (3 → W), the
    output layer, sin/cos and the element-wise products stay in the points' dtype. Used by the training loss
    when ``SdfFitConfig.gemm_dtype == "bfloat16"``; checked against ``gemm_gradient`` in the tests.
    """
    layers = model.affine_layers()
    dtype = points.dtype
    w0, b0 = layers[0]
    h, c = sin_cos(torch.addmm(b0.to(dtype), points, w0.to(dtype).t()))
    derivs = [c]
    low = [(w.to(gemm_dtype), b.to(dtype)) for w, b in layers[1:-1]]
    for wl, b in low:
        h, c = sin_cos(torch.mm(h.to(gemm_dtype), wl.t()).to(dtype) + b)
        derivs.append(c)
    wn, bn = layers[-1]
    values = torch.addmm(bn.to(dtype), h, wn.to(dtype).t())
    g = derivs[-1] * wn.to(dtype)
    for i in range(len(derivs) - 1, 0, -1):
        g = torch.mm(g.to(gemm_dtype), low[i - 1][0]).to(dtype) * derivs[i - 1]
    return values, g @ w0.to(dtype)


def sdf_loss_terms(model: Siren, surf_p, surf_n, vol_p, vol_d, cfg: SdfFitConfig, *, low_precision: bool = False,
                   totals: tuple[int, int] | None = None, power_weight: float = 0.0,
                   power_scale: float = 1.0, base: tuple | None = None, vol_n: torch.Tensor | None = None) -> dict:
    """The loss terms of one step (scalar tensors) and their weighted sum ``"loss"``.

    Args:
        model: the Siren being trained.
        surf_p, surf_n: (S, 3) surface points and unit outward normals (unit frame).
        vol_p, vol_d: (V, 3) off-surface points and (V,) their ground-truth signed distances.
        cfg: weights ``w_surface``, ``w_normal``, ``w_angle``, ``w_eikonal``, ``w_sdf`` and the focus ``focus_tau``.
        low_precision: hidden GEMMs in bfloat16 (:func:`mixed_gradient`) instead of float32.
        totals: (S, V) of the whole step when these points are one micro-batch of it: each term is a sum
            over these points divided by the step's sizes, so the micro-batches' terms add up to the step's
            means (default: these points' own sizes, i.e. means).
        power_weight: if > 0, the term ``"power"`` = mean over the surface points of |r / power_scale|^p,
            r the first-order distance (:func:`first_order_distance`, p = ``cfg.polish_max_p``), is added to
            the loss with this weight (the polish's worst-distance term, linearised: :func:`_polish_loss`;
            the scale, e.g. the batch's largest |r|, keeps the p-th powers in float32's range).
        base: None, or a fixed field's values and gradients at these points, ``(surface values (S,),
            surface gradients (S, 3), off-surface values (V,), off-surface gradients (V, 3))``, added to the
            model's: every term is then of the sum (a residual level trained on a frozen coarse one).
        vol_n: None, or (V, 3) unit gradient targets at the off-surface points (zero rows: none), for the
            near-normal term (``cfg.w_near_normal``).

    ∇f of all S + V points comes from one differentiable GEMM pass (no double-backward).
    """
    s = surf_p.shape[0]
    n_s, n_v = totals if totals is not None else (s, vol_p.shape[0])
    pts = torch.cat([surf_p, vol_p], dim=0) if vol_p.shape[0] else surf_p
    if low_precision and model.depth > 0:
        values, grads = mixed_gradient(model, pts, torch.bfloat16)
    else:
        values, grads = gemm_gradient(model, pts, "reverse", differentiable=True)
    f = values[:, 0]
    if base is not None:
        f = f + torch.cat([base[0], base[2]])
        grads = grads + torch.cat([base[1], base[3]])
    return loss_terms_of(f, grads, surf_n, vol_d, cfg, totals=(n_s, n_v), power_weight=power_weight,
                         power_scale=power_scale, vol_n=vol_n)


def loss_terms_of(f: torch.Tensor, grads: torch.Tensor, surf_n: torch.Tensor, vol_d: torch.Tensor,
                  cfg: SdfFitConfig, *, totals: tuple[int, int] | None = None, power_weight: float = 0.0,
                  power_scale: float = 1.0, vol_n: torch.Tensor | None = None) -> dict:
    """The terms of :func:`sdf_loss_terms` from a field's values ``f`` (S + V,) and gradients (S + V, 3) at the
    step's points, the S surface points first (``surf_n`` (S, 3) their normals, ``vol_d`` (V,) the others'
    distances; ``vol_n`` (V, 3) or None their gradient targets): for a network evaluated by other means (a tile
    level's batched product, :mod:`.tiles`)."""
    s = surf_n.shape[0]
    n_s, n_v = totals if totals is not None else (s, vol_d.shape[0])
    gnorm = torch.linalg.vector_norm(grads, dim=1)
    sq_surf = focused_squares(f[:s] ** 2, cfg.focus_tau)
    sq_vol = focused_squares((f[s:] - vol_d) ** 2, cfg.focus_tau)
    near_n = vol_n if cfg.w_near_normal > 0 else None
    # the targets of the normal terms: the surface points' normals and, for the near-normal term, the
    # off-surface points' gradient targets (zero rows: none), in one pass (a term's every op costs a dispatch
    # per micro-batch, forward and backward)
    targets, g, slope = (surf_n, grads[:s], gnorm[:s]) if near_n is None else (torch.cat([surf_n, near_n]), grads, gnorm)
    misses = 1.0 - (g * targets).sum(dim=1) / slope.clamp_min(LOSS_GRAD_FLOOR)
    miss = misses[:s]
    terms = {
        "surface": sq_surf.sum() / max(n_s, 1),
        "normal": miss.sum() / max(n_s, 1),
        "eikonal": ((1.0 - gnorm) ** 2).sum() / max(n_s + n_v, 1),
    }
    terms["sdf"] = sq_vol.sum() / max(n_v, 1) if vol_d.shape[0] else f.new_zeros(())
    terms["loss"] = (cfg.w_surface * terms["surface"] + cfg.w_normal * terms["normal"]
                     + cfg.w_eikonal * terms["eikonal"] + cfg.w_sdf * terms["sdf"])
    chords = smooth_angle(misses) if cfg.w_angle > 0 or near_n is not None else None
    if chords is not None and cfg.w_angle > 0:
        terms["angle"] = chords[:s].sum() / max(n_s, 1)
        terms["loss"] = terms["loss"] + cfg.w_angle * terms["angle"]
    if chords is not None and near_n is not None:  # a row without a target (miss 1) is weighed 0
        terms["near_angle"] = (chords[s:] * (near_n * near_n).sum(dim=1)).sum() / max(n_v, 1)
        terms["loss"] = terms["loss"] + cfg.w_near_normal * terms["near_angle"]
    if power_weight > 0:
        r = f[:s] / (gnorm[:s].clamp_min(FIRST_ORDER_MIN_SLOPE) * power_scale)
        terms["power"] = r.abs().pow(cfg.polish_max_p).sum() / max(n_s, 1)
        terms["loss"] = terms["loss"] + power_weight * terms["power"]
    return terms


def smooth_angle(miss: torch.Tensor) -> torch.Tensor:
    """The angle term's √(2 ``miss`` + ε²) − ε of ``miss`` = 1 − cos θ: the chord 2 sin(θ/2) ≈ θ, smoothed
    below ε = :data:`~neural_bake.constants.NORMAL_ANGLE_EPS` (``SdfFitConfig.w_angle``)."""
    eps = NORMAL_ANGLE_EPS
    return torch.sqrt(2.0 * miss.clamp_min(0.0) + eps * eps) - eps


#: The slope below which :func:`first_order_distance` stops dividing (|∇f| of a trained SDF is ~1 on its
#: surface; where it sags to 0 the first-order distance would blow up).
FIRST_ORDER_MIN_SLOPE = 0.1


def first_order_distance(model: Siren, points: torch.Tensor, chunks: int = 1) -> torch.Tensor:
    """f / max(|∇f|, 0.1) at ``points`` (N,), no graph: Taubin's first-order estimate of the distance from
    each point to the zero set of f (GEMM gradients, in ``chunks`` parts)."""
    out = []
    with torch.no_grad():
        for part in torch.tensor_split(points, max(1, min(int(chunks), points.shape[0]))):
            values, grads = gemm_gradient(model, part, "reverse")
            out.append(values[:, 0] / torch.linalg.vector_norm(grads, dim=1).clamp_min(FIRST_ORDER_MIN_SLOPE))
    return torch.cat(out) if out else points.new_zeros(0)


#: Cap of the focus weight's (r / τ)² (see ``SdfFitConfig.focus_tau``): early in a run, when residuals are
#: many τ, the worst points would otherwise swamp the step.
FOCUS_CAP = 16.0


def focused_squares(sq: torch.Tensor, tau: float) -> torch.Tensor:
    """Squared residuals ``sq`` weighted by 1 + min(sq / τ², :data:`FOCUS_CAP`), the weights constants of the
    step (no gradient flows through them); ``sq`` itself when τ ≤ 0 (the focus off)."""
    if tau <= 0:
        return sq
    return sq * (1.0 + (sq.detach() / (tau * tau)).clamp_max(FOCUS_CAP))


def sdf_step_backward(loss_fn, model: Siren, surf_p, surf_n, vol_p, vol_d, cfg: SdfFitConfig, *,
                      micro_batches: int = 1, low_precision: bool = False, base: tuple | None = None,
                      vol_n: torch.Tensor | None = None) -> dict:
    """Forward and backward of one training step in ``micro_batches`` parts; the detached loss terms.

    Each part (a slice of the surface points and one of the off-surface points) runs ``loss_fn``
    (:func:`sdf_loss_terms` or its compiled form) with the step's totals and is back-propagated at once,
    so its graph is freed before the next part is built; the parameters' ``.grad`` add up to the whole
    step's. ``base``: a fixed field's values and gradients at the points (:func:`sdf_loss_terms`), split
    with them; ``vol_n``: the off-surface points' gradient targets (:func:`sdf_loss_terms`), likewise. Returns
    the terms summed over the parts (the whole step's, detached).
    """
    totals = (surf_p.shape[0], vol_p.shape[0])
    k = max(1, min(int(micro_batches), totals[0] + totals[1]))
    out: dict = {}
    split = (*(base or ()), *(() if vol_n is None else (vol_n,)))
    parts = zip(*(torch.tensor_split(t, k) for t in (surf_p, surf_n, vol_p, vol_d, *split)))
    for sp, sn, vp, vd, *more in parts:
        if sp.shape[0] + vp.shape[0] == 0:
            continue
        extra: dict = {"base": tuple(more[: len(base)])} if base is not None else {}
        if vol_n is not None:
            extra["vol_n"] = more[-1]
        terms = loss_fn(model, sp, sn, vp, vd, cfg, low_precision=low_precision, totals=totals, **extra)
        terms["loss"].backward()
        for key, val in terms.items():
            out[key] = out[key] + val.detach() if key in out else val.detach()
    return out

