"""Fitting a residual level of tiles (:class:`~neural_bake.nets.tiles.TiledSiren`) on a frozen coarse SDF.

The fine level of a residual construction (nested-neighbourhoods §3), split in space: a grid of ``grid``³
cells around the mesh's bounding cube (:func:`tile_grid_for`), a small SIREN on every cell with at least
``min_surface`` of the first pool's surface samples in its cell or seams, each network trained on the pool
points inside its own cell and seams as a residual r_t on the coarse level h. The loss terms are those of
:func:`~neural_bake.fit.sdf_loss.sdf_loss_terms` (:func:`~neural_bake.fit.sdf_loss.loss_terms_of`: surface, normal,
angle, eikonal and SDF, with the SDF config's weights and focus; no mined batches), taken of h + r_t on the pool
points inside h's band |h| < ``band`` (:func:`~neural_bake.fit.sdf_pools.band_pools`). All tiles step
together: each step draws the same number of points for every tile and runs them as one batched product
(:meth:`TiledSiren.tile_values_and_gradients`).
The learning rate follows the fits' cosine (:func:`~neural_bake.fit.training.cosine_lr`) to ``lr_min_factor``
over the steps, or over the time budget when ``minutes`` is set (measured by ``clock``, so tests drive it).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from ..errors import FitError
from ..nets.siren import Siren
from ..nets.tiles import TileGrid, TiledSiren, by_tile
from ..types import Mesh
from .sdf_config import SdfFitConfig
from .sdf_loss import loss_terms_of
from .training import cosine_lr
from .sdf_pools import _Pools, band_pools

__all__ = ["TileFitConfig", "TileFit", "fit_tiles", "tile_grid_for"]


@dataclass
class TileFitConfig:
    """Settings of :func:`fit_tiles`."""

    grid: int = 6
    """Cells per axis over the mesh's bounding cube."""
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
    min_surface: int = 1
    """Surface samples of the first pool a cell needs in its cell or seams to get a network (1: every cell
    whose seams a surface sample reaches, so the weights sum to 1 all over the surface)."""
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
    """"steps" (all of ``config.steps`` made) or "time" (the budget ran out)."""
    config: TileFitConfig | None = None
    """The settings the level was fitted with."""

    @property
    def budget(self) -> dict | None:
        """A time-budgeted level's account as a construction records it (steps made, no reference steps to
        expect); None for a run of a number of steps."""
        minutes = None if self.config is None else self.config.minutes
        if not minutes:
            return None
        return {"budget": "time", "steps": self.steps, "expected_steps": None,
                "ratio": None, "budget_seconds": 60.0 * minutes, "warning": None,
                "note": None, "stopped": self.stopped_reason}


def _check(cfg: TileFitConfig) -> None:
    for name in ("grid", "width", "min_surface", "surface_points", "volume_points", "steps"):
        v = getattr(cfg, name)
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise FitError(f"fit_tiles: {name} must be a positive integer, got {v!r}")
    if isinstance(cfg.depth, bool) or int(cfg.depth) != cfg.depth or cfg.depth < 0:
        raise FitError(f"fit_tiles: depth must be a non-negative integer, got {cfg.depth!r}")
    if not (0 < cfg.margin <= 0.25):
        raise FitError(f"fit_tiles: margin must be in (0, 0.25] cells, got {cfg.margin!r}")
    if not (math.isfinite(cfg.lr) and cfg.lr > 0 and 0 < cfg.lr_min_factor <= 1):
        raise FitError(f"fit_tiles: lr must be positive and lr_min_factor in (0, 1], got {cfg.lr!r}, "
                       f"{cfg.lr_min_factor!r}")
    if cfg.minutes is not None and not (math.isfinite(cfg.minutes) and cfg.minutes > 0):
        raise FitError(f"fit_tiles: minutes must be a positive number, got {cfg.minutes!r}")


def tile_grid_for(surface: torch.Tensor, grid: int, margin: float, min_surface: int = 1) -> TileGrid:
    """The grid around the bounding cube of ``surface`` (N, 3) points (widened by a thousandth of its side), a seam
    wider on every side so that no point lies in an outer seam; its active cells those with at least
    ``min_surface`` of the points in their cell or seams: at 1, the weights around every one of the points sum
    to 1 (no surface point sits in a seam towards a cell without a network)."""
    lo = surface.min(dim=0).values.double()
    hi = surface.max(dim=0).values.double()
    side = float((hi - lo).max()) * 1.002 + 1e-9
    cell = side / (grid - 2.0 * margin)
    origin = 0.5 * (lo + hi) - 0.5 * grid * cell
    every = TileGrid(origin, cell, grid, margin, torch.arange(grid ** 3))
    tiles, weights, _ = every.covering(surface.double())
    counts = torch.bincount(tiles[weights > 0], minlength=grid ** 3)
    active = torch.nonzero(counts >= min_surface).reshape(-1)
    if active.numel() == 0:
        active = torch.nonzero(counts > 0).reshape(-1)
    return TileGrid(origin, cell, grid, margin, active)


def _by_tile(grid: TileGrid, points: torch.Tensor) -> list[torch.Tensor]:
    """For each active tile, the indices of ``points`` inside its cell and seams."""
    pairs, bounds = by_tile(grid.covering(points)[0], grid.active.numel())
    rows = pairs // 8
    return [rows[bounds[t]: bounds[t + 1]] for t in range(grid.active.numel())]


def _draw(buckets: list[torch.Tensor], n: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """(K, n) indices drawn uniformly with replacement from each tile's bucket, and (K,) whether it had any, on
    the buckets' device (the draws from the CPU generator ``gen``)."""
    device = buckets[0].device
    idx, has = [], []
    for b in buckets:
        has.append(len(b) > 0)
        pick = torch.randint(max(len(b), 1), (n,), generator=gen).to(device)
        idx.append(b[pick] if len(b) else torch.zeros(n, dtype=torch.long, device=device))
    return torch.stack(idx), torch.tensor(has, device=device)


def _progress(show: bool, cfg: TileFitConfig, tiles: int):
    """A tqdm bar of the fit's steps, or of the seconds of its time budget; None when ``show`` is False."""
    if not show:
        return None
    from tqdm.auto import tqdm

    desc = f"fit sdf tiles {tiles}x({cfg.width}x{cfg.depth})"
    if cfg.minutes is not None:
        return tqdm(total=round(60.0 * cfg.minutes, 1), desc=desc, leave=False, dynamic_ncols=True, unit="s",
                    bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s of the budget{postfix}")
    return tqdm(total=cfg.steps, desc=desc, leave=False, dynamic_ncols=True)


def fit_tiles(mesh: Mesh, base: Siren, band: float, sdf_config: SdfFitConfig, config: TileFitConfig | None = None,
              *, clock: Callable[[], float] = time.perf_counter, log_every: int = 100, pool_cache: dict | None = None,
              audit: tuple | None = None) -> TileFit:
    """Fit a tile level r on the frozen coarse SDF ``base`` (unit frame) inside its band |base| < ``band``.

    ``sdf_config`` gives the pools (sizes, refreshes, sampling), the loss weights, the device and dtype;
    ``config`` the tiles and the schedule (:class:`TileFitConfig`). ``pool_cache``: the pools a construction's
    levels share (:class:`~neural_bake.fit.sdf_pools._Pools`); ``audit``: (points, true distances) of the
    coarse level's band audit (:func:`~neural_bake.fit.sdf_pools.band_audit`), added to every pool's uniform
    points. Returns a :class:`TileFit` whose ``model`` starts from zero output layers (r = 0) and is in eval
    mode. Raises FitError for bad settings or a band without surface points.
    """
    from .sdf_config import _DTYPES
    start = clock()  # the budget counts the band's pool and the grid too

    cfg = config or TileFitConfig()
    _check(cfg)
    if not (math.isfinite(band) and band > 0):
        raise FitError(f"fit_tiles: band must be a positive distance, got {band!r}")
    dtype, device = _DTYPES[sdf_config.dtype], torch.device(sdf_config.device or "cpu")
    base = base.to(device=device, dtype=dtype).eval()
    for p in base.parameters():
        p.requires_grad_(False)
    pools = _Pools(mesh, sdf_config, device, dtype, prepare=band_pools(base, band, audit=audit), cache=pool_cache)
    gen = torch.Generator().manual_seed(int(cfg.seed))
    data = pools.get(0)
    grid = tile_grid_for(data["surf_p"], cfg.grid, cfg.margin, cfg.min_surface)
    model = TiledSiren(grid, cfg.width, cfg.depth, cfg.omega_0, cfg.hidden_omega, zero_output=True,
                       generator=gen).to(device=device, dtype=dtype)
    centres = grid.centres(dtype=dtype, device=device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    history: list[dict] = []
    index, buckets = None, None
    budget = None if cfg.minutes is None else 60.0 * cfg.minutes
    step, stopped = 0, "steps"
    bar = _progress(sdf_config.progress, cfg, model.tiles)
    while step < cfg.steps:
        elapsed = clock() - start
        if budget is not None and elapsed >= budget:
            stopped = "time"
            break
        data = pools.get(step)
        if buckets is None or pools.index != index:  # a new pool: its points sorted by tile once
            index = pools.index
            buckets = (_by_tile(grid, data["surf_p"]), _by_tile(grid, data["vol_p"]))
        lr = cosine_lr(cfg.lr, cfg.lr_min_factor, step, cfg.steps, elapsed, cfg.minutes)
        for group in opt.param_groups:
            group["lr"] = lr
        si, s_has = _draw(buckets[0], cfg.surface_points, gen)
        vi, v_has = _draw(buckets[1], cfg.volume_points, gen)
        x = torch.cat([data["surf_p"][si], data["vol_p"][vi]], dim=1)
        h = torch.cat([data["surf_base"][si], data["vol_base"][vi]], dim=1)
        hg = torch.cat([data["surf_base_grad"][si], data["vol_base_grad"][vi]], dim=1)
        r, rg = model.tile_values_and_gradients((x - centres[:, None, :]) / grid.half)
        f, g = h + r, hg + rg
        s = cfg.surface_points
        # the SDF loss's terms of the rows of the tiles that have points (surface rows first), each tile's
        # share a mean over its own points: the means over all rows × the tiles with surface points
        terms = loss_terms_of(torch.cat([f[s_has, :s].reshape(-1), f[v_has, s:].reshape(-1)]),
                              torch.cat([g[s_has, :s].reshape(-1, 3), g[v_has, s:].reshape(-1, 3)]),
                              data["surf_n"][si[s_has]].reshape(-1, 3), data["vol_d"][vi[v_has]].reshape(-1),
                              sdf_config)
        k = float(max(1, int(s_has.sum())))
        loss = terms.pop("loss")
        value = float(loss.detach())
        if not math.isfinite(value):  # before the step: the weights are never left non-finite
            raise FitError(f"fit_tiles: the loss became non-finite at step {step + 1}")
        # a tile's loss reaches only its own network: the sum over tiles steps them all at once
        loss = loss * k
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        if step % log_every == 0 or step == 1:
            history.append({"step": step, "lr": lr, "loss": value,
                            **{name: float(v.detach()) for name, v in terms.items()}})
            if bar is not None:
                bar.set_postfix({"step": step, "loss": f"{value:.3g}"}, refresh=False)
        if bar is not None:  # a step, or the seconds since the last one
            bar.update(1 if budget is None else max(0.0, round(min(elapsed, bar.total) - bar.n, 3)))
    if bar is not None:
        bar.close()
    model.eval()
    for p in model.parameters():
        p.requires_grad_(False)
    return TileFit(model=model, steps=step, seconds=clock() - start, history=history, stopped_reason=stopped,
                   config=cfg)
