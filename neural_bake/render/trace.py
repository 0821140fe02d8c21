"""Multiscale sphere tracing (Nested Neighborhoods, Algorithm 1) over live rays only.

A nested sequence h_1, …, h_k, f is traced level by level: a coarse level j marches the ray to the level
set h_j = δ_j (the outer boundary of the band that holds every finer surface), the last level marches to
f = 0. Levels with zero iterations are skipped (``(64,1) ▷ (256,3)`` at ``(40, 0)`` traces h_1 only and
maps f's normals onto it). Two modes:

- ``"fixed"`` (the paper's): level j takes exactly ``iterations[j]`` steps ``t ← t + g_j(p)``; a ray whose
  step fell under :data:`~neural_bake.constants.TRACE_STILL_STEP` stops moving and leaves the batch.
- ``"threshold"``: level j steps while ``|g_j(p)| > epsilon``, at most ``iterations[j]`` times.

Only live rays are evaluated (with ``compact``, the default): rays that left the bounding cube, converged or
stepped to a non-finite value leave the batch, so each evaluation is one GEMM over the rays still tracing.
Rays are processed in chunks. A ray that ends with ``|g| ≤ hit_tolerance`` (or that starts inside the
surface) hits. Steps never go behind the ray's start: a ray whose start is inside a level's band passes to
the next level at once, and one that starts inside f reports a hit at its start (``inside``).

LOD (NGLOD §3.4, continuous LOD): with ``lod`` given, after the coarsest level each ray gets a continuous
level L̃ from its pixel footprint (``pixel_angle · t``) and then traces the blend ``(1 − α) g_L + α g_{L+1}``
of its two adjacent levels (L = ⌊L̃⌋, α = L̃ − L); a level with zero weight is not evaluated for that ray.

All in the asset's unit frame; rays (N, 3) origins and unit directions; dtype/device follow the origins.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..constants import (FLOAT32_FLOOR, MAX_TRACE_CHUNK, MAX_TRACE_ITERATIONS, TRACE_BOUND, TRACE_EPSILON,
                         TRACE_HIT_TOLERANCE, TRACE_STILL_STEP)
from .asset import RenderError, TraceLevel
from .stats import EvalCounter

__all__ = ["TRACE_MODES", "TraceSettings", "TraceResult", "trace_rays", "box_interval", "default_iterations"]

#: Sphere-tracing modes (see the module docstring).
TRACE_MODES = ("fixed", "threshold")


def default_iterations(n_levels: int, mode: str) -> tuple[int, ...]:
    """Iterations per level when none are given: the paper's (30, …, 30) fixed; caps of 100 per level
    in threshold mode (a converged ray stops long before)."""
    return tuple([30 if mode == "fixed" else 100] * n_levels)


@dataclass(frozen=True)
class TraceSettings:
    """How rays are traced (unit-frame lengths)."""

    mode: str = "threshold"
    """"fixed" (exact iterations per level, the paper's) or "threshold" (stop at ``epsilon``, capped)."""
    iterations: tuple[int, ...] | None = None
    """Per level, coarse to fine: steps (fixed) or the cap (threshold); 0 skips a level. None: defaults."""
    epsilon: float = TRACE_EPSILON
    """Threshold mode: a level stops where |value| ≤ this."""
    hit_tolerance: float = TRACE_HIT_TOLERANCE
    """A ray whose last |value| is at most this hit the surface."""
    compact: bool = True
    """Evaluate only live rays (False: every ray of the chunk at every step, masked — for measuring)."""
    chunk: int = 1 << 16
    """Rays per batch."""
    bound: float = TRACE_BOUND
    """Half-side of the cube rays are clipped to."""
    lod: tuple[float, float] | None = None
    """(finest footprint, coarsest footprint): pixel footprints at or under the first use the finest level,
    at or over the second the coarsest; log-linear and blended between (None: no LOD, Algorithm 1)."""

    def __post_init__(self):
        if self.mode not in TRACE_MODES:
            raise RenderError(f"trace mode {self.mode!r}: expected one of {', '.join(TRACE_MODES)}")
        if self.iterations is not None:
            its = tuple(self.iterations)
            if not its or any(isinstance(i, bool) or int(i) != i or i < 0 for i in its):
                raise RenderError(f"trace iterations: expected whole numbers ≥ 0 per level, got {self.iterations!r}")
            if sum(its) == 0:
                raise RenderError("trace iterations: at least one level needs iterations > 0")
            if max(its) > MAX_TRACE_ITERATIONS:
                raise RenderError(f"trace iterations: at most {MAX_TRACE_ITERATIONS} per level, got {max(its)}")
            object.__setattr__(self, "iterations", tuple(int(i) for i in its))
        for name in ("epsilon", "hit_tolerance", "bound"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise RenderError(f"trace {name}: expected a finite number > 0, got {v!r}")
        if isinstance(self.chunk, bool) or int(self.chunk) != self.chunk or not 1 <= self.chunk <= MAX_TRACE_CHUNK:
            raise RenderError(f"trace chunk: expected a whole number in 1..{MAX_TRACE_CHUNK} (rays per batch), "
                              f"got {self.chunk!r}")
        if self.lod is not None:
            lo, hi = (float(v) for v in self.lod)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
                raise RenderError(f"trace lod: expected (finest, coarsest) footprints with 0 < finest < coarsest, "
                                  f"got {self.lod!r}")

    def iterations_for(self, n_levels: int) -> tuple[int, ...]:
        its = self.iterations or default_iterations(n_levels, self.mode)
        if len(its) != n_levels:
            raise RenderError(f"trace iterations: {len(its)} values for {n_levels} levels")
        return its


@dataclass
class TraceResult:
    """Per ray (N,): ``hit`` bool, ``t`` distance along the unit direction (unit frame; inf where missed),
    ``iterations`` int32 evaluations made for the ray, ``inside`` bool (started inside f), ``lod`` the
    continuous level (float; the last traced level without LOD), ``value`` the last traced value."""

    hit: torch.Tensor
    t: torch.Tensor
    iterations: torch.Tensor
    inside: torch.Tensor
    lod: torch.Tensor
    value: torch.Tensor


def box_interval(origins: torch.Tensor, dirs: torch.Tensor, bound: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Entry and exit distances (N,) of rays through the cube [-bound, bound]³ (slab method), entry clamped
    at 0; exit < entry where a ray misses the cube. Axis-parallel rays are handled without NaN."""
    big = torch.finfo(dirs.dtype).max / 16
    inv = torch.where(dirs.abs() > 0, 1.0 / torch.where(dirs == 0, torch.ones_like(dirs), dirs),
                      torch.full_like(dirs, big))
    t1 = (-bound - origins) * inv
    t2 = (bound - origins) * inv
    # a ray parallel to a slab: inside it → (−big, big); outside → empty
    par = dirs == 0
    inside_slab = origins.abs() <= bound
    lo = torch.where(par, torch.where(inside_slab, torch.full_like(t1, -big), torch.full_like(t1, big)),
                     torch.minimum(t1, t2))
    hi = torch.where(par, torch.where(inside_slab, torch.full_like(t1, big), torch.full_like(t1, -big)),
                     torch.maximum(t1, t2))
    t_in = lo.max(dim=1).values.clamp_min(0)
    t_out = hi.min(dim=1).values
    return t_in, t_out


class _Traced:
    """A traced function: level j alone (``g_j = h_j − δ_j``, ``f`` for the last), or a per-ray blend."""

    def __init__(self, levels: list[TraceLevel], last: int, counter: EvalCounter, effect: str,
                 weights: torch.Tensor | None = None, single: int | None = None):
        self.levels, self.last, self.counter, self.effect = levels, last, counter, effect
        self.weights, self.single = weights, single

    def _offset(self, j: int) -> float:
        return 0.0 if j == self.last else self.levels[j].delta

    def __call__(self, idx: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        if self.single is not None:
            j = self.single
            return self.counter.value(self.levels[j], self.effect, points) - self._offset(j)
        w = self.weights[idx]
        out = points.new_zeros(points.shape[0])
        for j in range(w.shape[1]):
            sel = w[:, j] > 0
            if bool(sel.any()):
                sel_idx = sel.nonzero().squeeze(1)
                v = self.counter.value(self.levels[j], self.effect, points[sel_idx]) - self._offset(j)
                out.index_add_(0, sel_idx, w[sel_idx, j] * v)
        return out


def _march(fn: _Traced, o, d, t, t_lo, t_hi, alive, inside, last_v, iters, n_iter: int, *, mode: str,
           eps: float, compact: bool, is_last: bool) -> None:
    """Steps of one traced function for the rays flagged ``alive`` (in place on t, alive, inside, last_v,
    iters). A ray leaves this level when it converged (threshold: |v| ≤ eps; fixed: step under the still
    step), started inside (clamped at its start), left [t_lo, t_hi] (missed: alive False) or went
    non-finite (missed).

    With ``compact`` the live rays' state is kept in packed arrays that shrink whenever rays leave, so every
    step touches (and evaluates) the live rays only; without it every ray of the chunk is evaluated at every
    step while any ray is live (masked updates: the cost a batch tracer without compaction pays)."""
    still = eps if mode == "threshold" else TRACE_STILL_STEP
    idx = alive.nonzero().squeeze(1)
    if idx.numel() == 0 or n_iter == 0:
        return
    o_a, d_a, t_a, lo_a, hi_a = o[idx], d[idx], t[idx], t_lo[idx], t_hi[idx]
    v = None
    all_idx = torch.arange(t.shape[0], device=t.device) if not compact else None
    for k in range(n_iter):
        p = torch.addcmul(o_a, t_a[:, None], d_a)
        if compact:
            v = fn(idx, p)
        else:  # evaluate the whole chunk, keep the live rays' values
            full = torch.addcmul(o, t[:, None], d)
            full[idx] = p
            v = fn(all_idx, full)[idx]
        bad = ~torch.isfinite(v)
        conv = v.abs() <= still
        t_new = t_a + v
        behind = t_new < lo_a
        t_a = torch.where(behind | conv | bad, torch.where(behind, lo_a, t_a), t_new)
        out = t_a > hi_a
        leave = bad | conv | behind | out
        if not compact:
            t[idx] = t_a
        if bool(leave.any()) or k == n_iter - 1:
            gone = leave if k < n_iter - 1 else torch.ones_like(leave)
            g_idx = idx[gone]
            t[g_idx] = t_a[gone]
            last_v[g_idx] = v[gone]
            iters[g_idx] += k + 1  # every ray of this level was live from its first step
            missed = g_idx[(bad | out)[gone]]
            alive[missed] = False
            if is_last:
                inside[g_idx[(behind & ~bad)[gone]]] = True
            keep = ~gone
            if k < n_iter - 1:
                idx, o_a, d_a, t_a, lo_a, hi_a = idx[keep], o_a[keep], d_a[keep], t_a[keep], lo_a[keep], hi_a[keep]
                if idx.numel() == 0:
                    return


def trace_rays(
    levels: list[TraceLevel],
    origins: torch.Tensor,
    dirs: torch.Tensor,
    settings: TraceSettings,
    counter: EvalCounter,
    *,
    t_near: torch.Tensor | None = None,
    t_far: torch.Tensor | None = None,
    pixel_angle: float | None = None,
    effect: str = "trace",
) -> TraceResult:
    """Trace rays (unit frame) through ``levels`` (coarse → fine) per ``settings``; see the module docstring.

    ``t_near``/``t_far`` (N,) restrict each ray to [t_near, t_far] (e.g. the empty-space skipping interval
    or a far plane; default the bounding cube); a ray with ``t_far < t_near`` misses without any evaluation.
    ``pixel_angle``: the angle a pixel subtends (radians), needed with ``settings.lod``.
    """
    if origins.shape != dirs.shape or origins.dim() != 2 or origins.shape[1] != 3:
        raise RenderError(f"trace: origins and directions must both be (N, 3), got {tuple(origins.shape)} and "
                          f"{tuple(dirs.shape)}")
    n = origins.shape[0]
    its = settings.iterations_for(len(levels))
    traced = [j for j, k in enumerate(its) if k > 0]
    last = traced[-1]
    if settings.lod is not None and pixel_angle is None:
        raise RenderError("trace: LOD needs the pixel angle of the camera")
    box_in, box_out = box_interval(origins, dirs, settings.bound)
    lo = box_in if t_near is None else torch.maximum(box_in, t_near)
    hi = box_out if t_far is None else torch.minimum(box_out, t_far)
    dev, dt = origins.device, origins.dtype
    hit = torch.zeros(n, dtype=torch.bool, device=dev)
    t_all = torch.full((n,), math.inf, dtype=dt, device=dev)
    iters = torch.zeros(n, dtype=torch.int32, device=dev)
    inside = torch.zeros(n, dtype=torch.bool, device=dev)
    lod_all = torch.full((n,), float(last), dtype=dt, device=dev)
    value = torch.full((n,), math.inf, dtype=dt, device=dev)
    for s in range(0, n, settings.chunk):
        e = min(n, s + settings.chunk)
        o, d = origins[s:e], dirs[s:e]
        t_lo, t_hi = lo[s:e], hi[s:e]
        t = t_lo.clone()
        alive = t_hi >= t_lo
        ins = torch.zeros_like(alive)
        last_v = torch.full_like(t, math.inf)
        it = torch.zeros(e - s, dtype=torch.int32, device=dev)
        kw = dict(mode=settings.mode, eps=settings.epsilon, compact=settings.compact)
        if settings.lod is None or len(levels) == 1:
            for j in traced:
                fn = _Traced(levels, last, counter, effect, single=j)
                _march(fn, o, d, t, t_lo, t_hi, alive, ins, last_v, it, its[j], is_last=j == last, **kw)
        else:
            lod = _lod_trace(levels, its, counter, effect, settings, o, d, t, t_lo, t_hi, alive, ins, last_v, it,
                             pixel_angle, kw)
            lod_all[s:e] = lod
        h = alive & ((last_v.abs() <= settings.hit_tolerance) | ins)
        hit[s:e] = h
        t_all[s:e] = torch.where(h, t, torch.full_like(t, math.inf))
        iters[s:e] = it
        inside[s:e] = ins & h
        value[s:e] = last_v
    return TraceResult(hit, t_all, iters, inside, lod_all, value)


def lod_weights(lod: torch.Tensor, n_levels: int) -> torch.Tensor:
    """(N, K) blend weights of continuous levels ``lod`` (N,) in [0, K − 1]: ``max(0, 1 − |L̃ − j|)``."""
    j = torch.arange(n_levels, device=lod.device, dtype=lod.dtype)
    return (1 - (lod[:, None] - j[None, :]).abs()).clamp_min(0)


def continuous_lod(footprint: torch.Tensor, lod: tuple[float, float], n_levels: int) -> torch.Tensor:
    """L̃ (N,) in [0, K − 1] from pixel footprints (N,): K − 1 at or under ``lod[0]``, 0 at or over
    ``lod[1]``, linear in log footprint between."""
    fine, coarse = (math.log(v) for v in lod)
    x = (math.log(lod[1]) - torch.log(footprint.clamp_min(FLOAT32_FLOOR))) / (coarse - fine)
    return (x.clamp(0, 1) * (n_levels - 1)).to(footprint.dtype)


def _lod_trace(levels, its, counter, effect, settings, o, d, t, t_lo, t_hi, alive, ins, last_v, it, pixel_angle, kw):
    """Coarsest level first (Algorithm 1's first stage), then each ray traces the blend of the two levels its
    footprint selects, capped by the last level's iterations. Returns L̃ (N,)."""
    k = len(levels)
    if its[0] > 0:
        fn = _Traced(levels, k - 1, counter, effect, single=0)
        _march(fn, o, d, t, t_lo, t_hi, alive, ins, last_v, it, its[0], is_last=False, **kw)
    lod = continuous_lod(pixel_angle * t.clamp_min(0), settings.lod, k)
    ins.zero_()
    last_v.fill_(math.inf)
    fn = _Traced(levels, k - 1, counter, effect, weights=lod_weights(lod, k))
    _march(fn, o, d, t, t_lo, t_hi, alive, ins, last_v, it, max(its[1:]) if k > 1 else its[0], is_last=True, **kw)
    return lod
