"""Guaranteed ray casting by range analysis (Spelunking the deep, §4.2, Procedure 2), batched over rays.

Each ray marches with a step σ: if the range bound of f over the segment [t, t + σ] excludes 0, the step is
safe (taken, σ ← σ η₊); else σ ← σ η₋ and only the tolerance δ is taken. Before each step the sign of f at
t + δ is compared with its sign at the start: a change is a hit at t (within δ). Because a step is only
taken where f provably has no root, the caster cannot step over a surface even when f is not a true SDF
(|∇f| > 1, the networks sphere tracing can overshoot). Parameters are Spelunking's: σ₀ = t_max / 10,
η₋ = 0.5, η₊ = 1.5.

Rays in the unit frame; every live ray costs one point evaluation and one box bound per iteration.
"""

from __future__ import annotations

import math

import torch

from ..constants import GUARANTEED_TOLERANCE
from .asset import RenderError, TraceLevel
from .stats import EvalCounter
from .trace import box_interval

__all__ = ["cast_guaranteed", "ETA_MINUS", "ETA_PLUS"]

#: Procedure 2's step-size factors (Spelunking's suggestion).
ETA_MINUS, ETA_PLUS = 0.5, 1.5


def cast_guaranteed(
    level: TraceLevel,
    origins: torch.Tensor,
    dirs: torch.Tensor,
    counter: EvalCounter,
    *,
    bound: float = 1.0,
    tolerance: float = GUARANTEED_TOLERANCE,
    t_near: torch.Tensor | None = None,
    t_far: torch.Tensor | None = None,
    max_iterations: int = 100_000,
    effect: str = "guaranteed",
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """First roots of ``level`` (its zero set; δ is not subtracted) along rays (N, 3) inside the cube.

    Returns ``(hit (N,) bool, t (N,) (inf where no hit), iterations (N,) int32)``; ``t`` is the middle of
    the δ-interval the sign changed in. Raises RenderError when the level has no range bound.
    """
    if level.bound is None:
        raise RenderError(f"guaranteed casting: level {level.name} has no range bound (an analytic field "
                          "needs a Lipschitz constant)")
    n = origins.shape[0]
    dev, dt = origins.device, origins.dtype
    t_in, t_out = box_interval(origins, dirs, bound)
    if t_near is not None:
        t_in = torch.maximum(t_in, t_near)
    if t_far is not None:
        t_out = torch.minimum(t_out, t_far)
    hit = torch.zeros(n, dtype=torch.bool, device=dev)
    t_hit = torch.full((n,), math.inf, dtype=dt, device=dev)
    iters = torch.zeros(n, dtype=torch.int32, device=dev)
    live = (t_out > t_in).nonzero().squeeze(1)
    if live.numel() == 0:
        return hit, t_hit, iters
    o, d = origins[live], dirs[live]
    t = t_in[live].clone()
    t_max = t_out[live]
    f0 = counter.value(level, effect, o + t[:, None] * d)
    sign0 = f0 >= 0
    sigma = ((t_max - t) / 10).clamp_min(tolerance)
    active = torch.ones(live.numel(), dtype=torch.bool, device=dev)
    for _ in range(max_iterations):
        a = active.nonzero().squeeze(1)
        if a.numel() == 0:
            break
        iters[live[a]] += 1
        ta, da, oa = t[a], d[a], o[a]
        fc = counter.value(level, effect, oa + (ta + tolerance)[:, None] * da)
        found = (fc >= 0) != sign0[a]
        hit[live[a[found]]] = True
        t_hit[live[a[found]]] = ta[found] + tolerance / 2
        active[a[found]] = False
        a, ta, da, oa = a[~found], ta[~found], da[~found], oa[~found]
        s = torch.minimum(sigma[a], (t_max[a] - ta).clamp_min(tolerance))
        centers = oa + (ta + s / 2)[:, None] * da
        axes = (s / 2)[:, None, None] * da[:, None, :]
        lo, hi = counter.bound(level, effect, centers, axes)
        safe = (lo > 0) | (hi < 0)
        step = torch.where(safe, s, torch.zeros_like(s)).clamp_min(tolerance)
        sigma[a] = torch.where(safe, s * ETA_PLUS, s * ETA_MINUS)
        t[a] = ta + step
        active[a[t[a] >= t_max[a]]] = False
    return hit, t_hit, iters
