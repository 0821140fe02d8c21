"""SDF constructions at one budget: the plain fit, or a fine level fitted as a residual on a coarse one.

The construction is a setting of the fit (:attr:`~neural_bake.fit.sdf_config.SdfFitConfig.construction`, a
preset's own or the caller's); :func:`~neural_bake.fit.sdf.fit_sdf` hands a construction of several levels to
:func:`fit_levels`.

- ``"plain"``: one SIREN of the config's width, fitted to the mesh.
- ``"residual"`` (nested-neighbourhoods §3, a fine level trained inside the coarse level's band): a coarse
  SIREN h (``coarse_width`` × the config's depth, ω0 ``coarse_omega_0``) is fitted for ``coarse_share`` of the
  budget, then a fine SIREN r (``width − coarse_width``, the config's ω0) for the rest so that h + r fits the
  mesh's SDF, supervised only on the points with |h| < δ, δ = ``band_factor`` × h's sampled distance error
  (max |h| at mesh surface samples); surface, normal, angle, eikonal and distance terms are all of the sum
  (``fit_sdf(base=h, band=δ)``). r starts with a zero output layer, so the sum starts as h. The fit's
  ``model`` is the sum as one SIREN of the config's width (:func:`~neural_bake.nets.siren_sum.siren_sum`):
  it saves, loads, nests, bakes and renders like any SDF, with GEMM normals, at a plain fit's cost.
  With a checkpoint, each level writes its own (the coarse level's beside the file, :func:`coarse_checkpoint`),
  and a resumed construction continues whichever level was running; the fine level's fingerprint holds h,
  the band and the audit, so it resumes only on the coarse level it was trained on.
  With ``audit_candidates``, the band audit (:func:`~neural_bake.fit.sdf_pools.band_audit`) runs between the
  levels: where h comes close to zero away from the mesh, r could grow a stray piece of surface the uniform
  pool is too sparse to see; points there, with their true distances, join r's uniform pool (and its sign
  mining), the audit's time taken from the fine level's share.
- ``"residual-warm"``: the same coarse h, then a network of the config's width initialised as h beside fresh
  units whose output weights are zero (the same function as h) and fitted plainly (every point, no band).
- ``"tiles"``: the same coarse h and band audit, then a tile level r (:func:`~neural_bake.fit.tiles.fit_tiles`:
  ``tile_grid``³ cells over the mesh's bounding cube and a ring around it, a ``tile_width`` × ``tile_depth``
  SIREN on every cell the surface reaches and where h has a stray piece of surface, blended across seams of
  ``tile_margin`` cells) fitted inside h's band for the rest of the
  budget. The ``model`` is a :class:`~neural_bake.nets.tiles.TiledSdf` (h and r in one file): it loads, bakes,
  marches and renders through the field layer with GEMM normals and range bounds. Checkpoints as
  ``residual``'s: the tile level's in the construction's file, the coarse level's beside it.

``steps``, ``history`` and ``sampling_seconds`` of the result are the fine level's, ``seconds`` the whole
construction's, ``budget`` the account of both levels (steps made and expected, summed, each level's own
under ``levels``). The sample pools are drawn once and shared by both levels (the first before either fit,
inside the budget). A budget of ``minutes`` is shared: the coarse level gets ``coarse_share`` of what is left
after the first pool, the fine level whatever is left after the coarse one (as the clock measures it); a
budget of ``steps`` without minutes is split in the same proportion; ``budget="steps"`` runs each level's own
reference steps (:data:`~neural_bake.fit.presets.REFERENCE_STEPS` under "PRESET/coarse" and "PRESET/fine").
Each level's time budget is accounted against its own step cost
(:data:`~neural_bake.fit.budget.STEP_COST`, same keys) where the preset's construction ran.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Callable

import torch

from ..errors import FitError
from ..nets.siren import Siren
from ..nets.siren_sum import siren_sum
from ..types import Mesh
from .sdf import SdfFit, fit_sdf, sampled_distance_error
from .sdf_config import _DTYPES, PRESETS, SdfFitConfig
from .sdf_pools import _Pools, band_audit

__all__ = ["CONSTRUCTIONS", "ResidualSdfFit", "coarse_checkpoint", "fit_levels", "fit_sdf_construction", "level_keys"]

#: The SDF constructions (:attr:`~neural_bake.fit.sdf_config.SdfFitConfig.construction`).
CONSTRUCTIONS = ("plain", "residual", "residual-warm", "tiles")


@dataclass
class ResidualSdfFit(SdfFit):
    """A construction's fit: ``model`` is the whole SDF (h + r as one SIREN, or the warm-started network),
    ``steps``/``history`` the fine level's, ``budget`` both levels'; the coarse level's own record beside them."""

    construction: str = "residual"
    """"residual", "residual-warm" or "tiles" (:data:`CONSTRUCTIONS`)."""
    coarse: SdfFit | None = None
    """The coarse level h's fit."""
    fine: Siren | None = None
    """The residual network r alone ("residual"; None for "residual-warm", whose network is ``model``, and for
    "tiles", whose tile level is ``tiles``)."""
    tiles: object | None = None
    """The tile level's fit ("tiles": a :class:`~neural_bake.fit.tiles.TileFit`)."""
    band: float | None = None
    """δ: the residual level's training band |h| < δ (unit frame; None for "residual-warm")."""
    fine_seconds: float | None = None
    """Seconds of the fine level's fit (``seconds`` is the whole construction's, the coarse level's included)."""
    fine_config: SdfFitConfig | None = None
    """The fine level's settings (``config`` is the construction's: its width is the whole network's)."""
    audit: dict | None = None
    """The band audit's account ("residual" with ``audit_candidates``): candidates, points kept, seconds."""

    @property
    def all_steps(self) -> int:
        """Adam steps of both levels (what the budget account counts)."""
        return self.steps + (self.coarse.steps if self.coarse is not None else 0)

    @property
    def label(self) -> str:
        """The networks in a row: "64x3+128x3" (residual: h + r) or "64x3→192x3" (warm start)."""
        if self.construction == "tiles":
            return str(self.model.label)
        c, f = self.coarse.config if self.coarse else None, self.fine_config or self.config
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


def coarse_checkpoint(path: str | None) -> str | None:
    """The coarse level's checkpoint file of a construction checkpointed at ``path`` (the fine level's):
    ``run.ckpt`` → ``run.coarse.ckpt``; None without a checkpoint."""
    if not path:
        return None
    from pathlib import Path

    p = Path(path)
    return str(p.with_name(f"{p.stem}.coarse{p.suffix}"))


def level_keys(key: str | None, cfg: SdfFitConfig) -> tuple[str | None, str | None]:
    """The :data:`~neural_bake.fit.budget.STEP_COST` keys of a construction's coarse and fine levels: "KEY/coarse"
    and "KEY/fine" when ``cfg`` is preset ``key``'s own construction (its construction and coarse width) and
    both keys are known; (None, None) otherwise (no reference: no expected steps)."""
    from .budget import STEP_COST

    if key is None or key not in PRESETS:
        return None, None
    ref = replace(SdfFitConfig(), **PRESETS[key])
    keys = (f"{key}/coarse", f"{key}/fine")
    if (cfg.construction, cfg.coarse_width) != (ref.construction, ref.coarse_width) or not all(
            k in STEP_COST for k in keys):
        return None, None
    return keys


def _levels_budget(cfg: SdfFitConfig, key: str | None, coarse: SdfFit, fine: SdfFit) -> dict | None:
    """The account of a construction's two levels: steps made and expected (sums; None when a level has no
    reference), budget seconds, the levels' warnings joined, the fine level's stop, each level's own account
    under ``levels``; None when neither level has an account."""
    levels = {"coarse": coarse.budget, "fine": fine.budget}
    if not any(levels.values()):
        return None
    accounts = [b or {} for b in levels.values()]
    expected = [b.get("expected_steps") for b in accounts]
    total = None if None in expected else int(sum(expected))
    steps = coarse.steps + fine.steps
    out = {"budget": accounts[1].get("budget", "time"), "preset": key, "construction": cfg.construction,
           "steps": steps, "expected_steps": total, "ratio": None if not total else steps / total,
           "budget_seconds": sum(float(b.get("budget_seconds") or 0.0) for b in accounts),
           "warning": "; ".join(b["warning"] for b in accounts if b.get("warning")) or None,
           "note": "; ".join(b["note"] for b in accounts if b.get("note")) or None,
           "stopped": accounts[1].get("stopped"), "levels": levels}
    if out["budget"] == "steps":
        out["reference_steps"] = total
        out["estimated_seconds"] = sum(float(b.get("estimated_seconds") or 0.0) for b in accounts)
    return out


def fit_levels(mesh: Mesh, cfg: SdfFitConfig, key: str | None = None, *,
               clock: Callable[[], float] | None = None, pool_cache: dict | None = None) -> "ResidualSdfFit":
    """Fit ``mesh``'s SDF by ``cfg``'s construction of two levels ("residual" or "residual-warm"; the module
    docstring) and return a :class:`ResidualSdfFit`. ``key``: the preset whose budget the run has (its levels'
    step costs: :func:`level_keys`). With ``cfg.checkpoint`` each level is checkpointed (the coarse level
    in :func:`coarse_checkpoint`'s file) and ``cfg.resume`` continues both. FitError for a ``budget="steps"``
    run without the levels' reference steps."""
    if cfg.construction not in CONSTRUCTIONS[1:]:
        raise FitError(f"fit_levels: {cfg.construction!r} is not a construction of several levels")
    coarse_key, fine_key = level_keys(key, cfg)
    if cfg.budget == "steps" and fine_key is None:
        raise FitError(f"fit_sdf: budget='steps' runs the reference steps of a preset's own construction; the "
                       f"{cfg.construction} construction of preset {key!r} with these settings has none")
    if cfg.budget == "steps":  # each level's reference steps, no time stop
        cfg = replace(cfg, minutes=None)
    now = clock or time.perf_counter
    t0 = now()
    # the sample pools are drawn once for both levels: the first one now, inside the budget, and the split
    # is of the training time that is left (on a large open mesh the first pool takes a good part of it)
    cache: dict = {} if pool_cache is None else pool_cache
    device, dtype = torch.device(cfg.device or "cpu"), _DTYPES[cfg.dtype]
    _pool_threads(cfg, device, dtype)
    _Pools(mesh, cfg, device, dtype, cache=cache).get(0)
    plain = replace(cfg, construction="plain", polish_evals=0)
    if cfg.budget == "steps":
        coarse_budget: dict = {"budget": "steps"}
    elif cfg.minutes:
        coarse_budget = {"minutes": cfg.coarse_share * max(cfg.minutes - (now() - t0) / 60.0, 0.05 * cfg.minutes)}
    else:
        coarse_budget = {"steps": max(1, round(cfg.coarse_share * cfg.steps))}
    # the coarse level: the config's settings at its own width and ω0 (no polish), checkpointed beside the
    # fine level's file (:func:`coarse_checkpoint`)
    t_coarse = now()
    coarse = fit_sdf(mesh, replace(plain, width=int(cfg.coarse_width), omega_0=float(cfg.coarse_omega_0),
                                   checkpoint=coarse_checkpoint(cfg.checkpoint), **coarse_budget),
                     clock=clock, pool_cache=cache, budget_key=coarse_key)
    # a resumed coarse level's time was spent by an earlier run: the fine level gets what that run left it
    earlier = max(0.0, coarse.seconds - (now() - t_coarse))
    h = coarse.model
    band = cfg.band_factor * float(coarse.distance_error or 0.0)
    audit, audit_record = None, None
    if cfg.construction in ("residual", "tiles") and cfg.audit_candidates and band > 0:  # before the fine level's share
        t_audit = now()
        audit = band_audit(h, mesh, band, float(coarse.distance_error or 0.0), cfg.audit_candidates,
                           seed=int(cfg.seed) * 7_919 + 5)
        kept = 0 if audit is None else int(audit[1].shape[0])
        audit_record = {"candidates": int(cfg.audit_candidates), "kept": kept, "seconds": round(now() - t_audit, 3)}
    fine_cfg = plain  # budget="steps": the fine level's own reference steps
    if cfg.budget != "steps" and cfg.minutes:  # whatever is left of the budget (the coarse fit's sampling included)
        left = 60.0 * cfg.minutes - (now() - t0) - earlier
        fine_cfg = replace(fine_cfg, minutes=max(left, 0.05 * 60.0 * cfg.minutes) / 60.0)
    elif cfg.budget != "steps":
        fine_cfg = replace(fine_cfg, steps=max(1, cfg.steps - coarse_budget["steps"]))
    if cfg.construction == "tiles":
        return _fit_tile_level(mesh, cfg, key, fine_cfg, coarse, band, audit, audit_record, clock, cache,
                               lambda: now() - t0)
    if cfg.construction == "residual":
        if not band > 0:
            raise FitError(f"{mesh.name}: the coarse level's distance error is {coarse.distance_error!r}: no band")
        fine_fit = fit_sdf(mesh, replace(fine_cfg, width=cfg.width - int(cfg.coarse_width), hard_fraction=0.0,
                                         zero_fraction=0.0, error_sampling=0.0),
                           clock=clock, base=h, band=band, pool_cache=cache, budget_key=fine_key, audit=audit)
        model: Siren = siren_sum(h, fine_fit.model).eval()
        fine: Siren | None = fine_fit.model
    else:
        p = next(h.parameters())
        fresh = Siren(cfg.width - int(cfg.coarse_width), cfg.depth, omega_0=cfg.omega_0,
                      generator=torch.Generator().manual_seed(int(cfg.seed) + 1)).to(device=p.device, dtype=p.dtype)
        with torch.no_grad():
            fresh.layers[-1].weight.zero_()
            fresh.layers[-1].bias.zero_()
        fine_fit = fit_sdf(mesh, fine_cfg, clock=clock, init=siren_sum(h, fresh), pool_cache=cache,
                           budget_key=fine_key)
        model, fine = fine_fit.model, None
    return ResidualSdfFit(
        model=model, frame=mesh.frame, history=fine_fit.history, steps=fine_fit.steps, seconds=now() - t0,
        config=cfg, stopped_reason=fine_fit.stopped_reason, restarts=coarse.restarts + fine_fit.restarts,
        micro_batch_tuning=fine_fit.micro_batch_tuning, budget=_levels_budget(cfg, key, coarse, fine_fit),
        threads=fine_fit.threads, sampling_seconds=fine_fit.sampling_seconds, fine_seconds=fine_fit.seconds,
        distance_error=sampled_distance_error(model, mesh, seed=int(cfg.seed)), construction=cfg.construction,
        coarse=coarse, fine=fine, band=band if cfg.construction == "residual" else None, fine_config=fine_fit.config,
        audit=audit_record)


def _fit_tile_level(mesh: Mesh, cfg: SdfFitConfig, key: str | None, fine_cfg: SdfFitConfig, coarse: SdfFit,
                    band: float, audit, audit_record, clock, cache: dict, elapsed: Callable[[], float]
                    ) -> "ResidualSdfFit":
    """The "tiles" construction's second level on the fitted ``coarse`` one: :func:`~neural_bake.fit.tiles.fit_tiles`
    for ``fine_cfg``'s budget (minutes, else steps), and the construction's record; ``elapsed()``: the
    construction's seconds so far."""
    from ..nets.tiles import TiledSdf
    from .tiles import TileFitConfig, fit_tiles

    if not band > 0:
        raise FitError(f"{mesh.name}: the coarse level's distance error is {coarse.distance_error!r}: no band")
    tile_cfg = TileFitConfig(grid=int(cfg.tile_grid), margin=float(cfg.tile_margin), width=int(cfg.tile_width),
                             depth=int(cfg.tile_depth), seed=int(cfg.seed) + 1, steps=int(fine_cfg.steps),
                             minutes=fine_cfg.minutes)
    work, fine_key = None, level_keys(key, cfg)[1]
    if cfg.budget == "steps":  # the work the preset's fine level has on the reference machine, in tile steps
        from .budget import STEP_COST, reference_steps

        work = float(reference_steps(fine_key) or 0) * STEP_COST[str(fine_key)]
    tiles = fit_tiles(mesh, coarse.model, band, fine_cfg, tile_cfg, clock=clock or time.perf_counter,
                      pool_cache=cache, audit=audit, reference_work=work, budget_key=fine_key,
                      log_every=int(cfg.log_every))
    h = coarse.model
    model = TiledSdf(h, tiles.model.to(next(h.parameters()))).eval()
    budget = _levels_budget(cfg, key, coarse, tiles)
    return ResidualSdfFit(
        model=model, frame=mesh.frame, history=tiles.history, steps=tiles.steps, seconds=elapsed(),
        config=cfg, stopped_reason=tiles.stopped_reason, restarts=coarse.restarts + tiles.restarts, budget=budget,
        threads=tiles.threads, fine_seconds=tiles.seconds,
        distance_error=sampled_distance_error(model, mesh, seed=int(cfg.seed)), construction="tiles",
        coarse=coarse, band=band, audit=audit_record, tiles=tiles)


def fit_sdf_construction(mesh: Mesh, construction: str | None = None, *, preset: str | None = None,
                         clock: Callable[[], float] | None = None, **overrides) -> SdfFit:
    """Fit ``mesh``'s SDF by ``construction`` (:data:`CONSTRUCTIONS`; None: the preset's or the overrides'
    own) at the budget of ``preset`` and ``overrides`` (:func:`~neural_bake.fit.sdf.fit_sdf`'s): "plain"
    gives fit_sdf's :class:`SdfFit`, the others a :class:`ResidualSdfFit`. FitError for an unknown
    construction or bad settings."""
    if construction is not None:
        if construction not in CONSTRUCTIONS:
            raise FitError(f"unknown SDF construction {construction!r}; choose one of {', '.join(CONSTRUCTIONS)}")
        overrides["construction"] = construction
    return fit_sdf(mesh, preset=preset, clock=clock, **overrides)
