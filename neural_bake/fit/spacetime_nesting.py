"""Nested sequences of space-time SDFs: coarse levels distilled from a space-time fit with one δ per level
that holds at every t (:func:`nest_spacetime`), the choice of δ (:func:`choose_deltas`) and the check at
fixed times (:func:`nesting_by_time`)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..errors import FitError, NeuralBakeWarning
from ..fields.spacetime import time_to_tau
from ..nets.timeslice import fix_last_input

if TYPE_CHECKING:
    from .nested import NestedFitConfig
    from .spacetime import SpaceTimeFit

__all__ = ["nest_spacetime", "choose_deltas", "nesting_by_time", "DELTA_POLICIES"]


#: How :func:`nest_spacetime` sets δ: from the certified bound (range analysis over space-time boxes, a
#: guarantee at every t) or from the sampled estimate (not guaranteed).
DELTA_POLICIES = ("certified", "estimated")


def nest_spacetime(fit: SpaceTimeFit, config: NestedFitConfig | None = None, *, check_times: int = 11,
                   delta: str = "certified", **overrides):
    """Coarse space-time levels distilled from ``fit``'s network, with one δ per level that holds for every t
    of the fitted range: :func:`~neural_bake.fit.nested.fit_nested` with ``config`` (a
    :class:`~neural_bake.fit.nested.NestedFitConfig`; default: one (64, 1) level) and ``overrides`` (its
    fields) over [-1, 1]⁴ (space × the time input, which covers τ ∈ [−E, E] for E ≤ 1), sup-norms estimated
    over space-time samples and certified by range analysis over space-time boxes (``certify``, default on;
    ``max_boxes`` bounds its cost, recorded in ``levels_info[i]["certify"]["seconds"]``).

    The sampled sup of each level is also taken at ``check_times`` evenly spaced fixed times
    (:func:`nesting_by_time`, ``n_estimate`` samples each) and the estimated δ rebuilt from the larger value.
    Then δ is chosen by :func:`choose_deltas` with ``delta``: "certified" (default) makes δ_i − δ_{i+1} the
    certified bound wherever the certification ran, so the nesting [|h_{i+1}(·, t)| ≤ δ_{i+1}] ⊂
    [|h_i(·, t)| ≤ δ_i] is guaranteed at every t (a looser δ than the estimate: affine bounds over boxes are
    pessimistic); "estimated" keeps the sampled estimate (tighter, not guaranteed).

    Returns a :class:`~neural_bake.fit.nested.NestedSequence` of 4-input networks whose ``metadata`` holds
    ``"spacetime": {"time_range", "time_extent", "kind", "method", "times"}``.

    Raises:
        FitError: ``fit.time_extent`` above 1 (the nesting samples τ in [-1, 1] only), an unknown ``delta``,
            and fit_nested's errors.
    """
    import warnings

    from .nested import NestedFitConfig, fit_nested

    if fit.time_extent > 1.0:
        raise FitError(f"nest_spacetime: time_extent {fit.time_extent:g} > 1: the space-time band is sampled for "
                       f"τ in [-1, 1] only; fit with time_extent <= 1")
    if delta not in DELTA_POLICIES:
        raise FitError(f"nest_spacetime: delta must be one of {', '.join(DELTA_POLICIES)}, got {delta!r}")
    if delta == "certified":  # fit_nested's choice (certified only near the estimate) is replaced below
        overrides.setdefault("warn_ratio", math.inf)
    cfg = config or NestedFitConfig(levels="64x1")
    with warnings.catch_warnings():
        if delta == "certified":
            warnings.filterwarnings("ignore", message=r".*above the band .* where \|h - g\| was measured")
        seq = fit_nested(fit.model, cfg, frame=fit.frame, **overrides)
    n_estimate, seed = int(overrides.get("n_estimate", cfg.n_estimate)), int(overrides.get("seed", cfg.seed))
    seq.metadata["spacetime"] = {"time_range": list(fit.time_range), "time_extent": fit.time_extent,
                                 "kind": fit.kind, "method": fit.method, "times": list(fit.times)}
    # the space-time estimate samples [-1, 1]^4 uniformly: sharpen it at fixed times (the ends of the range
    # included, where uniform samples are sparse)
    rows = nesting_by_time(seq, np.linspace(*fit.time_range, check_times), n=n_estimate, seed=seed + 991)
    infos = seq.levels_info
    for r in rows:
        info = infos[r["level"]]
        info["sup_by_time"] = max(info.get("sup_by_time", 0.0), r["sup"])
    for info in infos[:-1]:
        info["sup_estimated"] = max(info["sup_estimated"], info.get("sup_by_time", 0.0))
    choose_deltas(seq, delta)
    if delta == "certified":
        for i, info in enumerate(infos[:-1]):
            if not info["nesting_guaranteed"]:
                why = ("certification was off" if info.get("sup_certified") is None else
                       f"the finer level's δ {infos[i + 1]['delta']:.4g} is above the band Δ = {seq.band:g}")
                warnings.warn(f"nest_spacetime: level {i}: δ is the sampled estimate, not guaranteed at every t "
                              f"({why})", NeuralBakeWarning, stacklevel=2)
    return seq


def choose_deltas(seq, delta: str = "certified"):
    """Set each level's ``delta``, ``delta_estimated``, ``delta_source`` and ``nesting_guaranteed`` from its
    stored sup-norms (in place; returns ``seq``), fine to coarse: δ_k = ε, δ_i = δ_{i+1} + sup_i.

    ``delta`` "certified": sup_i is the certified bound (``delta_source`` "certified",
    ``nesting_guaranteed`` True) wherever the certification ran and δ_{i+1} ≤ Δ (the certificate covers the
    band |·| < Δ only); elsewhere the sampled estimate (``delta_source`` "estimated", ``nesting_guaranteed``
    False: fresh samples may exceed it). "estimated": the estimate everywhere.

    Raises:
        FitError: an unknown ``delta``.
    """
    if delta not in DELTA_POLICIES:
        raise FitError(f"choose_deltas: delta must be one of {', '.join(DELTA_POLICIES)}, got {delta!r}")
    infos = seq.levels_info
    d_est = d_used = seq.eps
    infos[-1]["nesting_guaranteed"] = True  # the fine level itself: nothing to nest
    for i in range(len(infos) - 2, -1, -1):
        info = infos[i]
        d_est += info["sup_estimated"]
        info["delta_estimated"] = d_est
        cert = info.get("sup_certified")
        certified = (delta == "certified" and cert is not None and math.isfinite(cert) and d_used <= seq.band)
        d_used += cert if certified else info["sup_estimated"]
        info["delta"] = d_used
        info["delta_source"] = "certified" if certified else "estimated"
        info["nesting_guaranteed"] = bool(certified)
    return seq


@torch.no_grad()
def nesting_by_time(seq, times, *, n: int = 20_000, seed: int = 0) -> list[dict]:
    """Check a space-time nested sequence at each of ``times``: per coarse level i, the sampled sup of
    |h_i(·, t) − h_{i+1}(·, t)| over the Δ-band at t against the level's share δ_i − δ_{i+1} (Prop. 1 needs
    sup ≤ δ_i − δ_{i+1}). Rows ``{"t", "level", "sup", "allowed", "holds"}``."""
    from .nested import estimate_sup_norm

    st = seq.metadata.get("spacetime") or {}
    time_range = tuple(st.get("time_range", (0.0, 1.0)))
    extent = float(st.get("time_extent", 1.0))
    deltas = seq.deltas
    rows = []
    for t in times:
        tau = float(time_to_tau(float(t), time_range, extent))
        sl = [fix_last_input(m, tau) for m in seq.levels]
        for i in range(len(sl) - 1):
            sup = estimate_sup_norm(sl[i], sl[i + 1], band=seq.band, n=n, seed=seed + i)
            allowed = deltas[i] - deltas[i + 1]
            rows.append({"t": float(t), "level": i, "sup": sup, "allowed": allowed, "holds": bool(sup <= allowed)})
    return rows
