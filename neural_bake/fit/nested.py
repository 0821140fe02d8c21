"""Nested sequences of neural SDFs h_1, …, h_k, f with thresholds δ (paper §3.2–3.3, Prop. 1).

Coarser levels are distilled from finer ones: the finest coarse level h_k learns f, h_{k−1} learns h_k,
and so on (each teacher is the next finer level). Training minimises the mean squared difference on points
in a band around the teacher's zero level set (plus uniform points, so that h stays a usable distance
bound away from the surface) and keeps the training step whose estimated sup-norm |h − teacher| is smallest.

Thresholds (Prop. 1: |h − g|∞ < ε ⇒ [|h| < δ] ⊂ [|g| < ε + δ]). With the sequence h_1, …, h_k, h_{k+1} = f:

- ``sup_i`` = |h_i − h_{i+1}|∞ over the Δ-band ``{x ∈ [-1, 1]³ : |h_i(x)| < Δ or |h_{i+1}(x)| < Δ}``;
- δ_{k+1} = ``eps`` (the fine surface itself, with a margin), and δ_i = sup_i + δ_{i+1} (+ ``eps`` through
  δ_{k+1}), so that [|h_{i+1}| ≤ δ_{i+1}] ⊂ [|h_i| ≤ δ_i]: sphere tracing h_i to its δ_i level set never
  steps over the finer band. This holds where δ_i ≤ Δ (the sup is only measured in the band); a δ above Δ
  is reported with a warning.

The sup-norm is
- **estimated** by sampling (paper Table 5): ``n_estimate`` points uniform in [-1, 1]³ kept when inside the
  Δ-band; the estimate's stability over sample sizes and Δ is recorded in ``NestedSequence.stability``;
- **certified** by range analysis (:func:`~neural_bake.nets.range_analysis.difference_bound`, affine
  arithmetic with shared input noise symbols) over boxes covering the band: boxes are pruned when the range
  of both networks over them misses [-Δ, Δ] and subdivided (largest bound first) until every box's bound is
  within ``certify_rel_tol`` of the estimate or the box budget is spent. The certified value is the largest
  box bound: a guaranteed upper bound of |h − g| on the band. A :class:`NeuralBakeWarning` is issued when
  it exceeds the estimate by more than ``warn_ratio``.

Space-time fields (``in_dim`` 4: x and the time input τ ∈ [-1, 1]) nest the same way over [-1, 1]⁴: the
samples and the boxes cover space × time, so one δ per level holds at every t
(:func:`neural_bake.fit.spacetime.nest_spacetime`).

The sequence itself (the asset, its file) is :class:`neural_bake.fields.NestedSequence`, re-exported here.

Both δ are stored per level (``delta_estimated``, ``delta_certified``); :attr:`NestedSequence.deltas` (what
a renderer uses) takes a level's certified sup-norm only where its certification met the target, else the
estimate: affine bounds over boxes of a ω0 = 30 network are loose until the boxes are tiny, and a
guaranteed but huge δ would make the coarse levels useless.
"""

from __future__ import annotations

import heapq
import math
import time
import warnings
from dataclasses import dataclass

import torch

from .. import __version__
from ..constants import CERTIFY_MIN_TARGET, DIRECTION_EPS
from ..errors import FitError, NeuralBakeWarning
from ..fields.nested import NESTED_FORMAT, NestedSequence
from ..nets.siren import Siren
from ..types import Frame, Mesh
from .training import LoopConfig, train

__all__ = ["NestedSequence", "NestedFitConfig", "PRESETS", "nested_config", "fit_nested", "band_samples", "estimate_sup_norm", "certify_sup_norm",
           "parse_levels", "NESTED_FORMAT"]


@dataclass
class NestedFitConfig:
    """Settings of a nested fit (the `fit nested` verb and the batch's nested stage); one line per field."""

    levels: str = "64x1,256x1"
    """Coarse levels WIDTHxDEPTH, coarse to fine, comma-separated ("" or "none" in a batch: no nested stage)."""
    steps: int = 2000
    """Distillation steps per level."""
    minutes: float | None = None
    """Wall-clock budget per level in minutes (None: none)."""
    band: float = 0.1
    """Δ: half-width (unit frame) of the band around the zero level sets where |h - f| is measured."""
    eps: float = 1e-3
    """ε of Prop. 1 added to the sup-norms."""
    certify: bool = True
    """Certify the sup-norms by range analysis."""
    max_boxes: int = 20_000
    """Box budget of the certification."""
    seed: int = 0
    """Seed of weights and samples."""
    device: str | None = None
    """Torch device of the distillation ("cpu", "cuda", …; None: the fine model's)."""
    lr: float = 1e-3
    """Adam learning rate of the distillation."""
    batch: int = 4096
    """Training points per step."""
    pool: int = 200_000
    """Training points per level (band points around the teacher's zero set, uniform points, surface samples)."""
    omega_0: float | None = 15.0
    """ω0 of the coarse levels (None: the fine model's); a coarse level is a smooth approximation."""
    eval_every: int = 100
    """Steps between the sup-norm evaluations that choose the kept step."""
    eval_samples: int = 20_000
    """Band points of each such evaluation."""
    n_estimate: int = 100_000
    """Band points of the final sup-norm estimate."""
    stability_samples: tuple[int, ...] = (1_000, 10_000, 100_000)
    """Sample sizes of the stability table (sizes × ``stability_bands``; empty: no table)."""
    stability_bands: tuple[float, ...] = (0.1, 0.2, 0.3)
    """Bands Δ of the stability table."""
    certify_rel_tol: float = 0.25
    """The certification subdivides a box until its bound is within this fraction of the estimate."""
    warn_ratio: float = 2.0
    """Warn when the certified sup-norm is above this many times the sampled estimate."""
    progress: bool = True
    """Show progress bars."""


#: Nested-fit presets (fields over the defaults), the names of :mod:`neural_bake.fit.presets`; what they cost:
#: BENCHMARKS.md.
PRESETS: dict[str, dict] = {
    "quick": {"levels": "32x1", "steps": 300, "certify": False},
    "default": {"levels": "64x1", "steps": 2000},
    "high": {"levels": "64x1,256x1", "steps": 4000},
}


def nested_config(preset: str | None = None, **overrides) -> NestedFitConfig:
    """A NestedFitConfig from a preset name (:data:`PRESETS`) and field overrides; FitError for an unknown
    preset or field."""
    from ..configs import preset_config

    return preset_config(NestedFitConfig, PRESETS, preset, overrides, what="fit_nested", error=FitError)


# ----------------------------------------------------------------------------------------------- band & sup
def parse_levels(text: str) -> list[tuple[int, int]]:
    """"64x1,256x1" → [(64, 1), (256, 1)]; FitError naming the bad item."""
    out = []
    for item in str(text).split(","):
        item = item.strip().lower()
        try:
            w, d = item.split("x")
            w, d = int(w), int(d)
            if w < 1 or d < 0:
                raise ValueError
        except ValueError:
            raise FitError(f"levels: {item!r} is not WIDTHxDEPTH (e.g. 64x1)", parameter="levels") from None
        out.append((w, d))
    if not out:
        raise FitError("levels: give at least one level, e.g. 64x1,256x1", parameter="levels")
    return out


@torch.no_grad()
def _eval(model, x: torch.Tensor, chunk: int = 65536) -> torch.Tensor:
    p = next(model.parameters())
    x = x.to(p.device, p.dtype)
    return torch.cat([model(x[s:s + chunk])[:, 0] for s in range(0, x.shape[0], chunk)]) if x.shape[0] else x[:, 0]


@torch.no_grad()
def band_samples(models, n: int, band: float, *, seed: int = 0, max_tries: int = 200) -> torch.Tensor:
    """``n`` points uniform in [-1, 1]^d restricted to ``{x : min_m |m(x)| < band}`` (rejection sampling).

    ``models``: one network or a list (union of their bands), d = their ``in_dim`` (3; 4 for space-time
    fields, whose time input spans [-1, 1] too). Returns (n, d) in the first model's dtype; fewer than ``n``
    rows only if ``max_tries`` batches found too few (a network with no zero set nearby).
    """
    models = models if isinstance(models, (list, tuple)) else [models]
    p = next(models[0].parameters())
    dim = int(getattr(models[0], "in_dim", 3))
    gen = torch.Generator().manual_seed(int(seed))
    got, total = [], 0
    batch = max(4 * n, 65536)
    for _ in range(max_tries):
        x = (torch.rand(batch, dim, generator=gen, dtype=torch.float64) * 2 - 1).to(p.dtype)
        keep = torch.zeros(batch, dtype=torch.bool)
        for m in models:
            keep |= (_eval(m, x).abs() < band).cpu()
        got.append(x[keep])
        total += int(keep.sum())
        if total >= n:
            break
    out = torch.cat(got)[:n] if got else torch.zeros(0, dim, dtype=p.dtype)
    return out.to(p.device)


@torch.no_grad()
def estimate_sup_norm(h, g, *, band: float = 0.1, n: int = 100_000, seed: int = 0) -> float:
    """max |h − g| over ``n`` uniform samples of the Δ-band ``{|h| < band or |g| < band}`` (paper Table 5).

    Raises FitError when the band holds no sample (neither network has a zero level set in [-1, 1]³).
    """
    x = band_samples([h, g], n, band, seed=seed)
    if x.shape[0] == 0:
        raise FitError(f"sup-norm estimate: no point of [-1, 1]^{x.shape[1]} lies within {band} of either zero "
                       f"level set")
    return float((_eval(h, x).double() - _eval(g, x).double()).abs().max())


def _box_ranges(models, center, axes, method):
    """Guaranteed ``(lo, hi)`` of each model over each box ``center`` (B, 3) + axes (B, 3, 3) · [-1, 1]³."""
    from ..nets.range_analysis import range_bound

    return [range_bound(m, center, axes, method=method) for m in models]


def certify_sup_norm(h, g, *, band: float = 0.1, estimate: float | None = None, rel_tol: float = 0.25,
                     max_boxes: int = 20_000, min_half: float = 1.0 / 256, initial: int = 8,
                     method: str = "affine-fixed", batch: int = 2048) -> dict:
    """A guaranteed upper bound of |h − g| on the band ``{|h| < band or |g| < band}`` ∩ [-1, 1]^d.

    d is the networks' ``in_dim`` (3; 4 for space-time fields: boxes of space × time, so the bound holds at
    every t of the range). Boxes (axis-aligned cubes) start as an ``initial``^d grid of [-1, 1]^d; a box is
    dropped when the
    guaranteed ranges of h and g over it both miss [-band, band]; otherwise its bound is
    ``max(|lo|, |hi|)`` of :func:`~neural_bake.nets.range_analysis.difference_bound`. The box with the largest
    bound is split into 2^d while that bound exceeds ``max(estimate × (1 + rel_tol), CERTIFY_MIN_TARGET)``, the box
    is larger than ``min_half`` and fewer than ``max_boxes`` boxes have been bounded.

    Returns ``{"sup_certified", "boxes_bounded", "boxes_final", "complete"}`` where ``complete`` says every
    final box met the target (False: the budget or the minimum size stopped the refinement first).
    """
    from ..nets.range_analysis import difference_bound

    p = next(h.parameters())
    dtype, device = p.dtype, p.device
    target = max((estimate or 0.0) * (1.0 + rel_tol), CERTIFY_MIN_TARGET)
    dim = int(h.in_dim)
    k = int(initial)
    axis = (torch.arange(k, dtype=dtype) * 2 + 1) / k - 1
    grids = torch.meshgrid(*([axis] * dim), indexing="ij")
    centers = torch.stack([c.reshape(-1) for c in grids], 1).to(device)
    halves = torch.full((centers.shape[0],), 1.0 / k, dtype=dtype, device=device)
    heap: list[tuple[float, int, tuple, float]] = []  # (-bound, id, center, half)
    counter, bounded = 0, 0

    def bound_boxes(c: torch.Tensor, hf: torch.Tensor) -> None:
        nonlocal counter, bounded
        for s in range(0, c.shape[0], batch):
            cc, hh = c[s:s + batch], hf[s:s + batch]
            axes = torch.diag_embed(hh[:, None].expand(-1, dim))
            with torch.no_grad():
                in_band = torch.zeros(cc.shape[0], dtype=torch.bool, device=device)
                for lo, hi in _box_ranges([h, g], cc, axes, method):
                    in_band |= (lo <= band) & (hi >= -band)
                if not bool(in_band.any()):
                    bounded += cc.shape[0]
                    continue
                cc, hh, axes = cc[in_band], hh[in_band], axes[in_band]
                lo, hi = difference_bound(h, g, cc, axes, method=method)
            bounded += int(in_band.numel())
            b = torch.maximum(lo.abs(), hi.abs()).reshape(-1).double().cpu().numpy()
            for i in range(cc.shape[0]):
                counter += 1
                heapq.heappush(heap, (-float(b[i]), counter, tuple(cc[i].tolist()), float(hh[i])))

    bound_boxes(centers, halves)
    unit = torch.cartesian_prod(*([torch.tensor([-1.0, 1.0], dtype=dtype)] * dim)).reshape(-1, dim).to(device)
    children = unit.shape[0]
    while heap:
        split = []  # the worst boxes that still miss the target, up to 32 per batch of range analysis
        while (heap and len(split) < 32 and -heap[0][0] > target and heap[0][3] > min_half
               and bounded + children * (len(split) + 1) <= max_boxes):
            split.append(heapq.heappop(heap))
        if not split:
            break
        cs = torch.tensor([e[2] for e in split], dtype=dtype, device=device)
        qs = torch.tensor([e[3] / 2 for e in split], dtype=dtype, device=device)
        bound_boxes((cs[:, None, :] + unit[None] * qs[:, None, None]).reshape(-1, dim), qs.repeat_interleave(children))
    worst = -heap[0][0] if heap else 0.0
    complete = worst <= target
    return {"sup_certified": float(worst), "boxes_bounded": int(bounded), "boxes_final": len(heap),
            "complete": bool(complete), "target": float(target)}


# ----------------------------------------------------------------------------------------------- fitting
def _distill(student: Siren, teacher, *, steps, minutes, lr, seed, band, batch, pool, eval_n, eval_every,
             progress, desc, surface_points=None) -> tuple[dict, object]:
    p = next(student.parameters())
    dtype, device = p.dtype, p.device
    n_band = int(pool * 0.8)
    xb = band_samples(teacher, n_band, 2 * band, seed=seed * 31 + 1)
    gen = torch.Generator().manual_seed(seed * 31 + 2)
    dim = int(student.in_dim)
    xu = (torch.rand(pool - xb.shape[0], dim, generator=gen, dtype=torch.float64) * 2 - 1).to(device, dtype)
    parts = [xb.to(device, dtype), xu]
    if surface_points is not None and len(surface_points):
        parts.append(torch.as_tensor(surface_points, dtype=dtype, device=device))
    x = torch.cat(parts)
    y = _eval(teacher, x).to(dtype)
    # validation: teacher-band points plus uniform points, so that spurious near-zero regions of the student
    # (its own band) are seen too; the sup is taken over {|teacher| < band or |student| < band}
    gv = torch.Generator().manual_seed(seed * 31 + 4)
    xv = torch.cat([band_samples(teacher, eval_n, band, seed=seed * 31 + 3).to(device, dtype),
                    (torch.rand(eval_n, dim, generator=gv, dtype=torch.float64) * 2 - 1).to(device, dtype)])
    yv = _eval(teacher, xv).to(dtype)

    def step_fn(step, g):
        idx = torch.randint(0, x.shape[0], (batch,), generator=g).to(device)
        d = student(x[idx])[:, 0] - y[idx]
        mse = (d * d).mean()
        return {"loss": mse, "mse": mse}

    def evaluate():
        hv = _eval(student, xv)
        mask = (yv.abs() < band) | (hv.abs() < band)
        return float((hv - yv)[mask].abs().max()) if bool(mask.any()) else float("inf")

    cost = _distill_cost(student, x, y, batch, seed) if minutes else None
    cfg = LoopConfig(steps=steps, minutes=minutes, lr=lr, seed=seed, progress=progress, eval_every=eval_every,
                     log_every=max(1, min(100, steps // 10 or 1)), desc=desc)
    res = train(student, step_fn, cfg, evaluate=evaluate)
    budget = None if cost is None else _level_budget(res, cost, minutes, steps, desc)
    return {"steps": res.steps, "best_step": res.best_step, "best_eval_sup": res.best_value,
            "seconds": round(res.seconds, 3), "stopped_reason": res.stopped_reason, "restarts": res.restarts,
            "final_mse": res.history[-1]["mse"] if res.history else None, "budget": budget,
            "history": _thin(res.history)}, res


def _thin(history: list[dict], keep: int = 200) -> list[dict]:
    """At most ``keep`` rows of a loss history, evenly spaced, the last kept (the curve a report draws)."""
    if len(history) <= keep:
        return list(history)
    idx = sorted({round(i * (len(history) - 1) / (keep - 1)) for i in range(keep)})
    return [history[i] for i in idx]


def _distill_cost(student: Siren, x: torch.Tensor, y: torch.Tensor, batch: int, seed: int) -> float:
    """Reference steps in one distillation step of ``student`` (forward and backward of a batch;
    :func:`~neural_bake.fit.budget.step_cost`); the student's weights are left as they are."""
    from .budget import step_cost

    gen = torch.Generator().manual_seed(seed * 31 + 5)

    def step() -> None:
        student.zero_grad(set_to_none=True)
        idx = torch.randint(0, x.shape[0], (batch,), generator=gen).to(x.device)
        d = student(x[idx])[:, 0] - y[idx]
        (d * d).mean().backward()

    try:
        return step_cost(step)
    finally:
        student.zero_grad(set_to_none=True)


def _level_budget(res, cost: float, minutes: float, step_cap: int, desc: str) -> dict:
    """The budget account of one level's time-budgeted distillation (as
    :func:`~neural_bake.fit.budget.fit_budget` keeps a preset's, with the step cost measured here); its
    warning issued as a NeuralBakeWarning when fewer than half the expected steps were made."""
    from .budget import _full_rate, budget_record, stop_note

    span = 60.0 * minutes
    rate = _full_rate()  # the machine's speed at its full thread count, as fit_budget takes it
    rec = budget_record(res.steps, int(span * rate / cost), seconds=span, rate=rate,
                        stopped_reason=res.stopped_reason, what=desc)
    rec.update(step_cost=cost, stopped=stop_note(res.stopped_reason, res.steps, res.seconds, minutes, step_cap))
    if rec["warning"]:
        warnings.warn(rec["warning"], NeuralBakeWarning, stacklevel=3)
    return rec


def fit_nested(fine_model, config: NestedFitConfig | None = None, *, mesh: Mesh | None = None,
               frame: Frame | None = None, **overrides) -> NestedSequence:
    """Distil coarser Sirens from ``fine_model`` and set their nesting thresholds δ (module docstring).

    Args:
        fine_model: the fine SDF f — a :class:`Siren`, a :class:`~neural_bake.nets.tiles.TiledSdf` (coarse levels
            then take its coarse SIREN's ω0 unless ``omega_0`` is set) or an :class:`~neural_bake.fit.sdf.SdfFit`
            (its frame is then used).
        config: the settings (default :class:`NestedFitConfig`): the coarse ``levels`` (W, D), coarse to fine,
            steps or a time budget (``minutes``) per level — a budgeted level's info holds its account
            (``budget``: steps made beside the steps this machine makes in the budget, and a warning below half
            of them) — the band Δ and ε, the sup-norm samples and the certification.
        mesh: optional source mesh; its surface samples join the training points and its frame is used.
        frame: the frame to store (default: the SdfFit's or the mesh's, else identity).
        **overrides: any :class:`NestedFitConfig` field, e.g. ``levels=[(8, 0)], steps=200``
            (``levels`` as text or (W, D) pairs).

    Returns:
        A :class:`NestedSequence` ``[h_1, …, h_k, f]``; each level's info holds its loss history
        (``history``, at most 200 rows), and the metadata the fine fit's (``fine_training``) when
        ``fine_model`` is an SdfFit.

    Raises:
        FitError: bad levels or settings, a network without a zero level set in [-1, 1]³, divergence.
    """
    from dataclasses import replace

    from .sdf import SdfFit

    unknown = sorted(set(overrides) - set(NestedFitConfig.__dataclass_fields__))
    if unknown:
        raise FitError(f"fit_nested: unknown setting(s) {', '.join(unknown)}")
    cfg = replace(config or NestedFitConfig(), **overrides)
    levels = cfg.levels
    fine_training = None
    if isinstance(fine_model, SdfFit):
        frame = frame or fine_model.frame
        fine_training = {"steps": int(fine_model.steps), "seconds": round(float(fine_model.seconds), 3),
                         "history": _thin(fine_model.history), "budget": fine_model.budget}
        fine_model = fine_model.model
    tiled = getattr(fine_model, "composite", False)  # a tiled SDF (nets.tiles.TiledSdf): distilled like a SIREN
    if not isinstance(fine_model, Siren) and not tiled:
        raise FitError(f"fit_nested: fine_model must be a Siren, a TiledSdf or an SdfFit, got "
                       f"{type(fine_model).__name__}")
    if fine_model.in_dim not in (3, 4) or fine_model.out_dim != 1:
        raise FitError(f"fit_nested: the fine model must map R^3 (or space-time R^4) to R (got "
                       f"R^{fine_model.in_dim} -> R^{fine_model.out_dim})")
    if mesh is not None and fine_model.in_dim != 3:
        raise FitError("fit_nested: mesh is for a static fine model; a space-time model takes no mesh")
    if isinstance(levels, str) and not levels.strip():
        raise FitError("fit_nested: give at least one coarse level")
    levels = parse_levels(levels) if isinstance(levels, str) else [tuple(lv) for lv in levels]
    for lv in levels:
        if len(lv) != 2 or int(lv[0]) != lv[0] or int(lv[1]) != lv[1] or lv[0] < 1 or lv[1] < 0:
            raise FitError(f"fit_nested: level {lv!r} is not (width >= 1, depth >= 0)")
    if not levels:
        raise FitError("fit_nested: give at least one coarse level")
    if not (math.isfinite(cfg.band) and cfg.band > 0):
        raise FitError(f"fit_nested: band must be positive, got {cfg.band!r}")
    if not (math.isfinite(cfg.eps) and cfg.eps >= 0):
        raise FitError(f"fit_nested: eps must be non-negative, got {cfg.eps!r}")
    for name, v in (("steps", cfg.steps), ("batch", cfg.batch), ("pool", cfg.pool), ("n_estimate", cfg.n_estimate),
                    ("eval_samples", cfg.eval_samples)):
        if int(v) != v or v < 1:
            raise FitError(f"fit_nested: {name} must be a positive integer, got {v!r}")
    if mesh is not None:
        frame = frame or mesh.frame
    frame = frame or Frame()
    fine_model.eval()
    p = next(fine_model.parameters())
    if band_samples(fine_model, 64, cfg.band, seed=int(cfg.seed), max_tries=16).shape[0] == 0:
        raise FitError(f"fit_nested: the fine model has no point of [-1, 1]^{fine_model.in_dim} within {cfg.band} of "
                       f"its zero level set (is it an SDF of a surface in the unit frame?)")
    surface = None
    if mesh is not None:
        from .sampling import sample_surface

        surface = sample_surface(mesh, min(cfg.pool // 10, 50_000), seed=cfg.seed).points

    coarse: list[Siren | None] = [None] * len(levels)
    infos: list[dict] = [{} for _ in levels]
    teacher = fine_model
    for i in range(len(levels) - 1, -1, -1):
        w, d = levels[i]
        gen = torch.Generator().manual_seed(int(cfg.seed) * 101 + i)
        omega_0 = cfg.omega_0 or (fine_model.coarse.omega_0 if tiled else fine_model.omega_0)
        student = Siren(int(w), int(d), in_dim=fine_model.in_dim, omega_0=omega_0,
                        generator=gen).to(p.device, p.dtype)
        info, _ = _distill(student, teacher, steps=int(cfg.steps), minutes=cfg.minutes, lr=cfg.lr,
                           seed=int(cfg.seed) * 101 + i,
                           band=cfg.band, batch=int(cfg.batch), pool=int(cfg.pool), eval_n=int(cfg.eval_samples),
                           eval_every=int(cfg.eval_every), progress=cfg.progress, desc=f"nested level {w}x{d}",
                           surface_points=surface)
        student.eval()
        info.update(width=int(w), depth=int(d))
        coarse[i], infos[i] = student, info
        teacher = student

    seq_levels = [m for m in coarse if m is not None] + [fine_model]
    stability: list[list[dict]] = []
    for i in range(len(levels)):
        h, g = seq_levels[i], seq_levels[i + 1]
        t_est = time.perf_counter()
        est = estimate_sup_norm(h, g, band=cfg.band, n=int(cfg.n_estimate), seed=int(cfg.seed) + 17 * i)
        infos[i]["sup_estimated"] = est
        infos[i]["estimate_seconds"] = round(time.perf_counter() - t_est, 3)
        rows = []
        for s in cfg.stability_samples:
            for b in cfg.stability_bands:
                rows.append({"samples": int(s), "band": float(b),
                             "sup": estimate_sup_norm(h, g, band=float(b), n=int(s), seed=int(cfg.seed) + 1000 + i)})
        stability.append(rows)
        infos[i]["sup_certified"] = None
        infos[i]["certify"] = None
        if cfg.certify:
            try:
                t_cert = time.perf_counter()
                cert = certify_sup_norm(h, g, band=cfg.band, estimate=est, rel_tol=cfg.certify_rel_tol,
                                        max_boxes=int(cfg.max_boxes))
                cert["seconds"] = round(time.perf_counter() - t_cert, 3)
            except ImportError:
                warnings.warn("fit_nested: range analysis (neural_bake.nets.range_analysis) is not available; "
                              "δ is estimated only", NeuralBakeWarning, stacklevel=2)
                cert = None
            if cert is not None:
                # a sampled value is a lower bound of the sup: the certified bound can never be below it
                cert["sup_certified"] = max(cert["sup_certified"], est)
                infos[i]["sup_certified"] = cert["sup_certified"]
                infos[i]["certify"] = cert
                if cert["sup_certified"] > cfg.warn_ratio * max(est, DIRECTION_EPS):
                    warnings.warn(
                        f"fit_nested: level {i} ({levels[i][0]}x{levels[i][1]}): certified |h - g| bound "
                        f"{cert['sup_certified']:.4g} is "
                        f"{cert['sup_certified'] / max(est, DIRECTION_EPS):.1f}x the sampled "
                        f"estimate {est:.4g} (range analysis over {cert['boxes_bounded']} boxes"
                        f"{'' if cert['complete'] else ', budget reached'}); "
                        f"{'the certified δ is used' if cert['complete'] else 'δ uses the estimate, both are stored'}",
                        NeuralBakeWarning, stacklevel=2)

    # thresholds, fine to coarse (Prop. 1)
    arch = fine_model.coarse if tiled else fine_model  # a tiled f: its coarse SIREN's size, and its label
    fine_info = {"width": arch.width, "depth": arch.depth, "steps": 0, "delta_estimated": cfg.eps,
                 "delta_certified": (cfg.eps if cfg.certify and all(i["sup_certified"] is not None for i in infos)
                                     else None)}
    fine_info.update(delta=cfg.eps, delta_source="eps")
    if tiled:
        fine_info["network"] = str(fine_model.label)
    d_est, d_cert, d_used = cfg.eps, fine_info["delta_certified"], cfg.eps
    for i in range(len(levels) - 1, -1, -1):
        d_est = infos[i]["sup_estimated"] + d_est
        infos[i]["delta_estimated"] = d_est
        if d_cert is not None and infos[i]["sup_certified"] is not None:
            d_cert = infos[i]["sup_certified"] + d_cert
        else:
            d_cert = None
        infos[i]["delta_certified"] = d_cert
        cert = infos[i]["certify"]
        tight = cert is not None and cert["complete"]
        d_used += infos[i]["sup_certified"] if tight else infos[i]["sup_estimated"]
        infos[i]["delta"] = d_used
        infos[i]["delta_source"] = "certified" if tight else "estimated"
        if d_used > cfg.band:
            warnings.warn(f"fit_nested: level {i} ({levels[i][0]}x{levels[i][1]}) has δ = {d_used:.4g} above the "
                          f"band Δ = {cfg.band} where |h - g| was measured; rerun with a larger band or more steps",
                          NeuralBakeWarning, stacklevel=2)
    metadata = {"package_version": __version__, "seed": int(cfg.seed), "steps": int(cfg.steps),
                "minutes": cfg.minutes, "lr": cfg.lr, "batch": int(cfg.batch), "pool": int(cfg.pool), "n_estimate": int(cfg.n_estimate)}
    if fine_training is not None:  # the fine level's own fit, so a report of the sequence draws every curve
        metadata["fine_training"] = fine_training
    return NestedSequence(levels=seq_levels, frame=frame, levels_info=infos + [fine_info], band=float(cfg.band),
                          eps=float(cfg.eps), stability=stability, metadata=metadata)
