"""SDF constructions at one budget: the plain fit, or a fine level fitted as a residual on a coarse one.

- ``"plain"``: :func:`~neural_bake.fit.sdf.fit_sdf` as it is.
- ``"residual"`` (nested-neighbourhoods §3, a fine level trained inside the coarse level's band): a coarse
  SIREN h (``coarse_width`` × the fine network's depth, ω0 ``coarse_omega_0``) is fitted for ``coarse_share``
  of the budget, then a fine SIREN r (the config's network) for the rest so that h + r fits the mesh's SDF,
  supervised only on the points with |h| < δ, δ = ``band_factor`` × h's sampled distance error (max |h| at
  mesh surface samples); surface, normal, angle, eikonal and distance terms are all of the sum
  (``fit_sdf(base=h, band=δ)``). r starts with a zero output layer, so the sum starts as h. The fit's
  ``model`` is the sum as one SIREN (:func:`~neural_bake.nets.siren_sum.siren_sum`, width ``coarse_width`` +
  the fine width): it saves, loads and bakes like any SDF, with GEMM normals.
- ``"residual-warm"``: the same coarse h, then the config's network initialised as h beside fresh units whose
  output weights are zero (the same function as h) and fitted plainly (every point, no band) for the rest.

``steps``, ``history``, ``budget`` and ``sampling_seconds`` of the result are the fine level's, ``seconds``
the whole construction's. The sample pools are drawn once and shared by both levels (the first before either
fit, inside the budget). A budget of ``minutes`` is shared: the coarse level gets ``coarse_share`` of what is
left after the first pool, the fine level whatever is left after the coarse one (as the clock measures it);
a budget of ``steps`` is split in the same proportion.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Callable

import torch

from ..errors import FitError
from ..nets.siren import Siren
from ..nets.siren_sum import siren_sum
from ..types import Mesh
from .sdf import SdfFit, fit_sdf, sampled_distance_error
from .sdf_config import _DTYPES, config_from
from .sdf_pools import _Pools

__all__ = ["CONSTRUCTIONS", "COARSE_SHARE", "BAND_FACTOR", "COARSE_WIDTH", "COARSE_OMEGA_0", "ResidualSdfFit",
           "fit_sdf_construction"]

#: The SDF constructions :func:`fit_sdf_construction` runs.
CONSTRUCTIONS = ("plain", "residual", "residual-warm")

#: Part of the budget the coarse level of a residual construction is fitted for (docs/findings.md).
COARSE_SHARE = 0.25

#: The residual level's band δ in multiples of the coarse level's sampled distance error (docs/findings.md).
BAND_FACTOR = 4.0

#: Hidden width of the coarse level (its depth is the fine network's, so that the two add up to one SIREN).
COARSE_WIDTH = 64

#: ω0 of the coarse level: a smooth approximation, as the nested sequences' coarse levels (docs/findings.md).
COARSE_OMEGA_0 = 15.0


@dataclass
class ResidualSdfFit(SdfFit):
    """A residual construction's fit: ``model`` is the whole SDF (h + r as one SIREN, or the warm-started
    network), ``steps``/``history``/``budget`` the fine level's; the coarse level's own record beside them."""

    construction: str = "residual"
    """"residual" or "residual-warm" (:data:`CONSTRUCTIONS`)."""
    coarse: SdfFit | None = None
    """The coarse level h's fit."""
    fine: Siren | None = None
    """The residual network r alone ("residual"; None for "residual-warm", whose network is ``model``)."""
    band: float | None = None
    """δ: the residual level's training band |h| < δ (unit frame; None for "residual-warm")."""
    fine_seconds: float | None = None
    """Seconds of the fine level's fit (``seconds`` is the whole construction's, the coarse level's included)."""

    @property
    def label(self) -> str:
        """The networks in a row: "64x3+192x3" (residual: h + r) or "64x3→192x3" (warm start)."""
        c, f = self.coarse.config if self.coarse else None, self.config
        head = f"{c.width}x{c.depth}" if c is not None else "?"
        return f"{head}{'+' if self.construction == 'residual' else '→'}{f.width}x{f.depth}"


def _pool_threads(cfg, device, dtype) -> None:
    """Set torch's CPU threads for drawing the first pool outside a training loop (whose thread tuner sets them
    inside one): ``NEURAL_BAKE_THREADS`` where it is fixed, else the fastest count for a forward pass of the
    fine network (:func:`~neural_bake.nets.threads.choose_threads`): all cores while another program holds
    one would slow the pool's winding numbers many times."""
    from ..nets.threads import choose_threads

    probe = Siren(cfg.width, cfg.depth, omega_0=cfg.omega_0).to(device=device, dtype=dtype)
    x = torch.rand(4096, 3, generator=torch.Generator().manual_seed(0)).to(device=device, dtype=dtype)

    def work():
        with torch.no_grad():
            probe(x)

    choose_threads(work, device=device)


def fit_sdf_construction(mesh: Mesh, construction: str = "plain", *, preset: str | None = None,
                         coarse_share: float = COARSE_SHARE, band_factor: float = BAND_FACTOR,
                         coarse_width: int = COARSE_WIDTH, coarse_omega_0: float | None = COARSE_OMEGA_0,
                         clock: Callable[[], float] | None = None,
                         **overrides) -> SdfFit:
    """Fit ``mesh``'s SDF by ``construction`` (:data:`CONSTRUCTIONS`) at the budget of ``preset`` and
    ``overrides`` (:func:`~neural_bake.fit.sdf.fit_sdf`'s); "plain" returns fit_sdf's :class:`SdfFit`, the
    others a :class:`ResidualSdfFit`. ``coarse_omega_0``: the coarse level's ω0 (None: the config's). FitError
    for an unknown construction or bad split settings."""
    if construction not in CONSTRUCTIONS:
        raise FitError(f"unknown SDF construction {construction!r}; choose one of {', '.join(CONSTRUCTIONS)}")
    if construction == "plain":
        return fit_sdf(mesh, preset=preset, clock=clock, **overrides)
    if not (0.0 < coarse_share < 1.0):
        raise FitError(f"fit_sdf_construction: coarse_share must be in (0, 1), got {coarse_share!r}")
    if not (math.isfinite(band_factor) and band_factor > 0):
        raise FitError(f"fit_sdf_construction: band_factor must be positive, got {band_factor!r}")
    cfg = config_from(None, preset=preset, **overrides)
    if cfg.budget != "time":
        raise FitError(f"fit_sdf_construction: the {construction} construction runs a time or step budget, not "
                       f"budget={cfg.budget!r} (the reference steps are the plain fit's)")
    if construction == "residual-warm" and not 0 < int(coarse_width) < cfg.width:
        raise FitError(f"fit_sdf_construction: a warm start needs coarse_width below the width {cfg.width}, "
                       f"got {coarse_width!r}")
    now = clock or time.perf_counter
    t0 = now()
    # the sample pools are drawn once for both levels: the first one now, inside the budget, and the split
    # is of the training time that is left (on a large open mesh the first pool takes a good part of it)
    cache: dict = {}
    device, dtype = torch.device(cfg.device or "cpu"), _DTYPES[cfg.dtype]
    _pool_threads(cfg, device, dtype)
    _Pools(mesh, cfg, device, dtype, cache=cache).get(0)
    if cfg.minutes:
        coarse_budget = {"minutes": coarse_share * max(cfg.minutes - (now() - t0) / 60.0, 0.0)}
    else:
        coarse_budget = {"steps": max(1, round(coarse_share * cfg.steps))}
    # the coarse level: the config's settings at its own width (no polish, no checkpoint of its own)
    omega = {} if coarse_omega_0 is None else {"omega_0": float(coarse_omega_0)}
    coarse = fit_sdf(mesh, replace(cfg, width=int(coarse_width), budget="time", polish_evals=0, checkpoint=None,
                                   **coarse_budget, **omega), clock=clock, pool_cache=cache)
    h = coarse.model
    fine_cfg = replace(cfg, budget="time")
    if cfg.minutes:  # whatever is left of the budget (the coarse fit's sampling included)
        left = 60.0 * cfg.minutes - (now() - t0)
        fine_cfg = replace(fine_cfg, minutes=max(left, 0.05 * 60.0 * cfg.minutes) / 60.0)
    else:
        fine_cfg = replace(fine_cfg, steps=max(1, cfg.steps - coarse_budget["steps"]))
    if construction == "residual":
        band = band_factor * float(coarse.distance_error or 0.0)
        if not band > 0:
            raise FitError(f"{mesh.name}: the coarse level's distance error is {coarse.distance_error!r}: no band")
        fine_fit = fit_sdf(mesh, replace(fine_cfg, hard_fraction=0.0, zero_fraction=0.0, error_sampling=0.0,
                                         polish_evals=0), clock=clock, base=h, band=band, pool_cache=cache)
        model: Siren = siren_sum(h, fine_fit.model).eval()
        fine: Siren | None = fine_fit.model
    else:
        band = None
        p = next(h.parameters())
        fresh = Siren(cfg.width - int(coarse_width), cfg.depth, omega_0=cfg.omega_0,
                      generator=torch.Generator().manual_seed(int(cfg.seed) + 1)).to(device=p.device, dtype=p.dtype)
        with torch.no_grad():
            fresh.layers[-1].weight.zero_()
            fresh.layers[-1].bias.zero_()
        fine_fit = fit_sdf(mesh, fine_cfg, clock=clock, init=siren_sum(h, fresh), pool_cache=cache)
        model, fine = fine_fit.model, None
    return ResidualSdfFit(
        model=model, frame=mesh.frame, history=fine_fit.history, steps=fine_fit.steps, seconds=now() - t0,
        config=fine_fit.config, stopped_reason=fine_fit.stopped_reason, restarts=coarse.restarts + fine_fit.restarts,
        micro_batch_tuning=fine_fit.micro_batch_tuning, budget=fine_fit.budget, threads=fine_fit.threads,
        sampling_seconds=fine_fit.sampling_seconds, fine_seconds=fine_fit.seconds, distance_error=sampled_distance_error(model, mesh, seed=int(cfg.seed)),
        construction=construction, coarse=coarse, fine=fine, band=band)
