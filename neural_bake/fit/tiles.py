"""Fitting a residual level of tiles (:class:`~neural_bake.nets.tiles.TiledSiren`) on a frozen coarse SDF.

The fine level of a residual construction (nested-neighbourhoods §3), split in space: a grid of ``grid``³
cells over the mesh's bounding cube and a ring of cells around it (:func:`tile_grid_for`), a small SIREN on every
cell with at least ``min_surface`` of the first pool's surface samples in its cell or seams, and on every cell
holding ``min_errors`` of the coarse level's sign errors (a stray piece of its surface, which only a network there
can remove), each network trained on the pool points inside its own cell and seams as a residual r_t on the
coarse level h. The loss terms are those of
:func:`~neural_bake.fit.sdf_loss.sdf_loss_terms` (:func:`~neural_bake.fit.sdf_loss.loss_terms_of`: surface, normal,
angle, eikonal and SDF, with the SDF config's weights and focus; no mined batches), taken of h + r_t on the pool
points inside h's band |h| < ``band``, the off-surface ones out to ``shell`` bands
(:func:`~neural_bake.fit.sdf_pools.band_pools`); with the SDF config's ``sign_fraction``, that part of each
tile's off-surface draw comes from the pool's uniform points where h + r has the wrong sign, re-mined every
``hard_every`` steps (the residual level's sign mining, tile by tile), among all of the pool's uniform points
in the tiles' cells, the shell's and beyond it: where no point holds a tile, it can grow a surface. All tiles step
together: each step draws the same number of points for every tile and runs them as one batched product
(:meth:`TiledSiren.tile_values_and_gradients`).
The steps run in the fits' loop (:func:`~neural_bake.fit.training.train`): Adam with its cosine learning rate to
``lr_min_factor`` over the steps, or over the time budget when ``minutes`` is set (measured by ``clock``, so
tests drive it), divergence recovery, checkpoints and resume, the CPU threads chosen by measurement.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import torch

from ..constants import MAX_TILE_GRID
from ..errors import FitError
from ..nets.siren import Siren
from ..nets.tiles import TileGrid, TiledSiren, by_tile
from ..types import Mesh
from .sdf_config import SdfFitConfig
from .sdf_loss import loss_terms_of
from .sdf_pools import _Pools, _sign_errors, band_pools, remine_due

__all__ = ["TileFitConfig", "TileFit", "fit_tiles", "tile_grid_for"]


@dataclass
class TileFitConfig:
    """Settings of :func:`fit_tiles`."""

    grid: int = 6
    """Cells per axis over the mesh's bounding cube (the grid has a ring of cells more around it)."""
    margin: float = 0.08
    """Half-width of the seams between cells, in cells (0 < margin ≤ 0.25)."""
    width: int = 64
    """Hidden units of each tile's SIREN."""
    depth: int = 2
    """Hidden W×W matrices of each tile's SIREN."""
    omega_0: float = 30.0
    """ω of each tile's first layer (on its local coordinates, [−1, 1] across its cell and seams)."""
    hidden_omega: float = 30.0
    """ω of each tile's later sine layers."""
    shell: float = 2.0
    """Off-surface points are drawn out to ``shell`` × the band (:func:`~neural_bake.fit.sdf_pools.band_pools`):
    past the band's edge each tile is held to the true distances too (what it changed: docs/findings.md)."""
    min_surface: int = 1
    """Surface samples of the first pool a cell needs in its cell or seams to get a network (1: every cell
    whose seams a surface sample reaches, so the weights sum to 1 all over the surface)."""
    min_errors: int = 8
    """Errors of the coarse level a cell needs in its cell or seams to get a network beside the surface's cells
    (0: none): the first pool's uniform points at least :data:`~neural_bake.constants.SIGN_MINING_TOL` from the
    surface, of a sure sign, where h has the wrong one, and the band audit's points (h small, the mesh not near):
    a stray piece of h's surface, which only a network there can remove."""
    surface_points: int = 256
    """Surface points a tile a step."""
    volume_points: int = 320
    """Off-surface points (near and uniform, in the band) a tile a step."""
    lr: float = 3e-4
    """Adam's learning rate at the start."""
    lr_min_factor: float = 0.01
    """The cosine schedule's end, a fraction of ``lr``."""
    steps: int = 2000
    """Adam steps (the most, with ``minutes``)."""
    minutes: float | None = None
    """Time budget (None: ``steps`` alone)."""
    seed: int = 0
    """Initialisation and batch draws."""


@dataclass
class TileFit:
    """A fitted tile level: ``model`` (the residual r; the field is h + r), the steps made, their seconds, and
    the loss every ``log_every`` steps."""

    model: TiledSiren
    steps: int
    seconds: float
    history: list[dict] = field(default_factory=list)
    stopped_reason: str = "steps"
    """"steps" (all of ``config.steps`` made), "time budget" or "resumed finished run"."""
    config: TileFitConfig | None = None
    """The settings the level was fitted with."""
    budget: dict | None = None
    """The level's account (:func:`~neural_bake.fit.budget.fit_budget` for a time budget: the steps made beside
    those this machine makes for this many tiles and this mesh's new pools, timed on the fit's clock; a
    ``reference_work`` run's steps and their estimated seconds);
    None for a run of a number of steps."""
    restarts: int = 0
    """Divergence recoveries (each halved the learning rate)."""
    threads: dict = field(default_factory=dict)
    """The CPU threads the steps ran with (:meth:`~neural_bake.nets.threads.ThreadTuner.summary`)."""


def _check(cfg: TileFitConfig) -> None:
    for name in ("grid", "width", "min_surface", "surface_points", "volume_points", "steps"):
        v = getattr(cfg, name)
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise FitError(f"fit_tiles: {name} must be a positive integer, got {v!r}")
    if cfg.grid > MAX_TILE_GRID - 2:
        raise FitError(f"fit_tiles: grid must be at most {MAX_TILE_GRID - 2} (a ring of cells more around it), "
                       f"got {cfg.grid!r}")
    if isinstance(cfg.min_errors, bool) or int(cfg.min_errors) != cfg.min_errors or cfg.min_errors < 0:
        raise FitError(f"fit_tiles: min_errors must be a non-negative integer, got {cfg.min_errors!r}")
    if isinstance(cfg.depth, bool) or int(cfg.depth) != cfg.depth or cfg.depth < 0:
        raise FitError(f"fit_tiles: depth must be a non-negative integer, got {cfg.depth!r}")
    if not (math.isfinite(cfg.shell) and cfg.shell >= 1.0):
        raise FitError(f"fit_tiles: shell must be a number of at least 1 (bands), got {cfg.shell!r}")
    if not (0 < cfg.margin <= 0.25):
        raise FitError(f"fit_tiles: margin must be in (0, 0.25] cells, got {cfg.margin!r}")
    if not (math.isfinite(cfg.lr) and cfg.lr > 0 and 0 < cfg.lr_min_factor <= 1):
        raise FitError(f"fit_tiles: lr must be positive and lr_min_factor in (0, 1], got {cfg.lr!r}, "
                       f"{cfg.lr_min_factor!r}")
    if cfg.minutes is not None and not (math.isfinite(cfg.minutes) and cfg.minutes > 0):
        raise FitError(f"fit_tiles: minutes must be a positive number, got {cfg.minutes!r}")


def tile_grid_for(surface: torch.Tensor, grid: int, margin: float, min_surface: int = 1,
                  errors: torch.Tensor | None = None, min_errors: int = 1) -> TileGrid:
    """The grid of ``grid``³ cells around the bounding cube of ``surface`` (N, 3) points (widened by a
    thousandth of its side, a seam wider on every side so that no point lies in an outer seam) and a ring of
    cells around those (``grid`` + 2 per axis in all). Its active cells: those with at least ``min_surface`` of
    the points in their cell or seams (at 1, the weights around every one of the points sum to 1: no surface
    point sits in a seam towards a cell without a network), and those with at least ``min_errors`` (≥ 1) of the
    ``errors`` (M, 3) points (a coarse level's sign errors, in the ring too)."""
    lo = surface.min(dim=0).values.double()
    hi = surface.max(dim=0).values.double()
    side = float((hi - lo).max()) * 1.002 + 1e-9
    cell = side / (grid - 2.0 * margin)
    n = grid + 2
    origin = 0.5 * (lo + hi) - 0.5 * n * cell
    every = TileGrid(origin, cell, n, margin, torch.arange(n ** 3))

    def counts(points: torch.Tensor) -> torch.Tensor:
        tiles, weights, _ = every.covering(points.double())
        return torch.bincount(tiles[weights > 0], minlength=n ** 3)

    on_surface = counts(surface)
    active = on_surface >= min_surface
    if not bool(active.any()):
        active = on_surface > 0
    if errors is not None and errors.shape[0]:
        active |= counts(errors) >= max(1, int(min_errors))
    return TileGrid(origin, cell, n, margin, torch.nonzero(active).reshape(-1))


def _by_tile(grid: TileGrid, points: torch.Tensor, rows: torch.Tensor | None = None
             ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The indices of ``points`` inside each active tile's cell and seams, tile after tile: ``(indices, start,
    count)``, tile t's being ``indices[start[t]:start[t] + count[t]]``. ``rows``: the points are these rows of a
    pool (``points`` = its ``[rows]``), and the indices are those rows."""
    pairs, bounds = by_tile(grid.covering(points)[0], grid.active.numel())
    b = torch.as_tensor(bounds, device=points.device)
    return pairs // 8 if rows is None else rows[pairs // 8], b[:-1], b[1:] - b[:-1]


def _draw(buckets: tuple[torch.Tensor, torch.Tensor, torch.Tensor], n: int, gen: torch.Generator
          ) -> tuple[torch.Tensor, torch.Tensor]:
    """(K, n) indices drawn uniformly with replacement from each tile's bucket (:func:`_by_tile`), all tiles in
    one draw, and (K,) whether each had any (an empty bucket's row is index 0, unused)."""
    rows, start, count = buckets
    has = count > 0
    if rows.numel() == 0:
        return torch.zeros(count.shape[0], n, dtype=torch.long, device=rows.device), has
    u = torch.rand(count.shape[0], n, generator=gen, device=gen.device).to(rows.device)
    offset = torch.minimum((u * count[:, None]).long(), (count - 1).clamp_min(0)[:, None])
    return rows[(start[:, None] + offset).clamp(max=rows.numel() - 1)] * has[:, None], has


def fit_tiles(mesh: Mesh, base: Siren, band: float, sdf_config: SdfFitConfig, config: TileFitConfig | None = None,
              *, clock: Callable[[], float] = time.perf_counter, log_every: int = 100, pool_cache: dict | None = None,
              audit: tuple | None = None, reference_work: float | None = None,
              budget_key: str | None = None) -> TileFit:
    """Fit a tile level r on the frozen coarse SDF ``base`` (unit frame) inside its band |base| < ``band``.

    ``sdf_config`` gives the pools (sizes, refreshes, sampling), the loss weights, the device and dtype, the
    progress bar and the checkpoint (``checkpoint``, ``checkpoint_every``, ``resume``: the run resumes only on
    the same mesh, settings, base, band and audit); ``config`` the tiles and the schedule
    (:class:`TileFitConfig`). The steps run in the fits' loop (:func:`~neural_bake.fit.training.train`: Adam,
    the cosine learning rate, divergence recovery, the CPU threads chosen by measurement). ``pool_cache``: the
    pools a construction's levels share (:class:`~neural_bake.fit.sdf_pools._Pools`); ``audit``: (points,
    true distances) of the coarse level's band audit (:func:`~neural_bake.fit.sdf_pools.band_audit`), added
    to every pool's uniform points. A time budget (``minutes``) counts the band's pool and the grid too.
    ``reference_work``: run instead the steps that make this much work, in reference steps (a
    ``budget="steps"`` construction: the work its fine level has on the quiet reference machine), each step's
    by :func:`~neural_bake.fit.budget.tile_level_cost` (it grows with the number of tiles); no time stop.
    ``budget_key``: the name the level's account gives its preset (a construction's "PRESET/fine"). Returns a
    :class:`TileFit` whose ``model`` starts from zero output layers (r = 0) and is in eval mode.
    Raises FitError for bad settings, a band without surface points, divergence that learning-rate halvings
    did not cure, or reference work for tiles without a reference step cost.
    """
    from .budget import fit_budget, steps_budget, tile_level_cost
    from .sdf import _fingerprint
    from .sdf_config import _DTYPES
    from .training import LoopConfig, train

    start = clock()
    cfg = config or TileFitConfig()
    _check(cfg)
    if not (math.isfinite(band) and band > 0):
        raise FitError(f"fit_tiles: band must be a positive distance, got {band!r}")
    dtype, device = _DTYPES[sdf_config.dtype], torch.device(sdf_config.device or "cpu")
    base = base.to(device=device, dtype=dtype).eval()
    for p in base.parameters():
        p.requires_grad_(False)
    pools = _Pools(mesh, sdf_config, device, dtype, cache=pool_cache,
                   prepare=band_pools(base, band, audit=audit, shell=cfg.shell, far=True))
    data = pools.get(0)
    errors = None  # the coarse level's sign errors in the first pool (h alone: r = 0) and its band audit's points
    if cfg.min_errors > 0:
        wrong = _sign_errors(lambda p: p.new_zeros(p.shape[0], 1), data)
        found = [] if wrong is None else [data["vol_p"][wrong]]
        if audit is not None:
            found.append(audit[0].to(data["vol_p"]))
        errors = torch.cat(found) if found else None
    grid = tile_grid_for(data["surf_p"], cfg.grid, cfg.margin, cfg.min_surface, errors, cfg.min_errors)
    model = TiledSiren(grid, cfg.width, cfg.depth, cfg.omega_0, cfg.hidden_omega, zero_output=True,
                       generator=torch.Generator().manual_seed(int(cfg.seed))).to(device=device, dtype=dtype)
    cost = tile_level_cost(model.tiles, cfg.width, cfg.depth, cfg.surface_points + cfg.volume_points)
    if reference_work is not None:  # the reference machine's steps for this many tiles, no time stop
        if cost is None:
            raise FitError(f"fit_tiles: tiles of {cfg.width}x{cfg.depth} with {cfg.surface_points} + "
                           f"{cfg.volume_points} points have no reference step cost; give steps or minutes")
        cfg = replace(cfg, steps=max(1, int(reference_work / cost)), minutes=None)
    centres = grid.centres(dtype=dtype, device=device)
    s, v = cfg.surface_points, cfg.volume_points
    n_sign = min(v, int(round(float(sdf_config.sign_fraction) * v)))  # the tail of each off-surface draw
    sorted_pool: dict = {"index": None}
    mined: dict = {"index": None, "buckets": None}  # h + r's sign errors, sorted by tile
    sampling = {"seconds": 0.0, "steps": 0}  # the asset's own work in the steps: new pools, their band, sorting

    def step_fn(step: int, gen: torch.Generator) -> dict:
        t_sample = clock()
        data = pools.get(step)
        if sorted_pool["index"] is None or pools.index != sorted_pool["index"]:  # a new pool: sorted by tile once
            shell = torch.nonzero(~data["vol_far"]).reshape(-1)  # the far points are for sign mining alone
            sorted_pool.update(index=pools.index, surface=_by_tile(grid, data["surf_p"]),
                               volume=_by_tile(grid, data["vol_p"][shell], shell))
        if n_sign and remine_due(sdf_config, step, mined["index"] != pools.index):
            wrong = _sign_errors(lambda p: model.value(p)[:, None], data)
            mined.update(index=pools.index,
                         buckets=None if wrong is None else _by_tile(grid, data["vol_p"][wrong], wrong))
        sampling["seconds"] += clock() - t_sample
        sampling["steps"] += 1
        si, s_has = _draw(sorted_pool["surface"], s, gen)
        vi, v_has = _draw(sorted_pool["volume"], v, gen)
        if mined["buckets"] is not None:  # the draw's tail from the tile's sign errors (all of it without others)
            mi, m_has = _draw(mined["buckets"], v, gen)
            tail = torch.arange(v, device=vi.device) >= v - n_sign
            vi = torch.where(m_has[:, None] & (tail[None, :] | ~v_has[:, None]), mi, vi)
            v_has = v_has | m_has
        x = torch.cat([data["surf_p"][si], data["vol_p"][vi]], dim=1)
        h = torch.cat([data["surf_base"][si], data["vol_base"][vi]], dim=1)
        hg = torch.cat([data["surf_base_grad"][si], data["vol_base_grad"][vi]], dim=1)
        r, rg = model.tile_values_and_gradients((x - centres[:, None, :]) / grid.half)
        f, g = h + r, hg + rg
        # the SDF loss's terms of the rows of the tiles that have points (surface rows first): means over all
        # rows, each tile's share a mean over its own points; a tile's loss reaches only its own network, so
        # their sum (the means × the tiles with surface points) steps them all at once
        terms = loss_terms_of(torch.cat([f[s_has, :s].reshape(-1), f[v_has, s:].reshape(-1)]),
                              torch.cat([g[s_has, :s].reshape(-1, 3), g[v_has, s:].reshape(-1, 3)]),
                              data["surf_n"][si[s_has]].reshape(-1, 3), data["vol_d"][vi[v_has]].reshape(-1),
                              sdf_config)
        terms["loss"] = terms["loss"] * float(max(1, int(s_has.sum())))
        return terms

    minutes = None if cfg.minutes is None else max(cfg.minutes - (clock() - start) / 60.0, 0.05 * cfg.minutes)
    loop = LoopConfig(steps=int(cfg.steps), minutes=minutes, lr=float(cfg.lr), lr_schedule="cosine",
                      lr_min_factor=float(cfg.lr_min_factor), seed=int(cfg.seed), progress=sdf_config.progress,
                      log_every=int(log_every), checkpoint=sdf_config.checkpoint,
                      checkpoint_every=sdf_config.checkpoint_every, resume=sdf_config.resume,
                      desc=f"fit sdf tiles {model.tiles}x({cfg.width}x{cfg.depth})")
    fingerprint = _fingerprint(mesh, sdf_config, networks=(base,), arrays=tuple(audit or ()),
                               values=(band, cfg.shell, cfg.grid, cfg.margin, cfg.width, cfg.depth, cfg.omega_0,
                                       cfg.hidden_omega, cfg.min_surface, cfg.min_errors, s, v, cfg.lr,
                                       cfg.lr_min_factor, cfg.seed))
    res = train(model, step_fn, loop, fingerprint=fingerprint, metadata={"mesh": mesh.name, "tiles": model.tiles},
                clock=clock)
    model.eval()
    for p in model.parameters():
        p.requires_grad_(False)
    seconds = clock() - start
    asset = sampling["seconds"] / sampling["steps"] if sampling["steps"] else None
    account = fit_budget(budget_key, steps=res.steps, seconds=seconds, minutes=cfg.minutes, step_cap=cfg.steps,
                         stopped_reason=res.stopped_reason, cost=cost, what=f"tile level ({model.tiles} tiles)",
                         asset_seconds=asset, sampling_share=None if not res.seconds else sampling["seconds"] /
                         res.seconds)
    if reference_work is not None and cost is not None:
        account = steps_budget(budget_key, steps=res.steps, seconds=seconds, cost=cost, reference=cfg.steps)
    return TileFit(model=model, steps=res.steps, seconds=seconds, history=res.history,
                   stopped_reason=res.stopped_reason, config=cfg, budget=account, restarts=res.restarts,
                   threads=res.threads)
