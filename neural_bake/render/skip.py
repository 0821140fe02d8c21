"""Empty-space skipping: where along a ray the coarsest level's band can be, from a range-analysis octree.

The octree (Spelunking §4.5's spatial tree, NGLOD §3.3's idea of skipping empty voxels) subdivides the
cube [-b, b]³ top-down: a cell whose range bound of h_1 lies above δ_1 holds no point of the band
[|h_1| ≤ δ_1] and, by nesting, no finer surface: it is empty and not subdivided; a cell whose bound lies
below −δ_1 is inside the object (kept whole); the others are split down to ``depth`` levels. The leaves are a
boolean occupancy grid of side 2^depth.

Rays are clipped to the part of them that can meet an occupied cell: the grid is dilated by one cell and
sampled along each ray at half a cell's spacing. A ray that meets an occupied cell X first passes at least
one cell's length through X's dilated neighbourhood, so a sample lands there before X (and after X on the
way out): the first (last) such sample is a safe start (end). A ray with no such sample misses without
any network evaluation. The grid of a network is built once per (weights, δ, depth, bound) and cached in memory.
"""

from __future__ import annotations

import hashlib
import io
import math
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..io.atomic import atomic_write_bytes
from .asset import RenderError, TraceLevel
from .stats import EvalCounter
from .trace import box_interval

__all__ = ["OccupancyGrid", "build_occupancy", "occupancy_for", "clear_cache", "DEFAULT_SKIP_DEPTH"]

#: Octree depth of the skipping grid: 2^5 = 32 cells per axis. Affine bounds of an ω0 = 15 (64, 1) SIREN over
#: cells of side 1/8 (depth 4) are too wide to prove any cell empty; at side 1/16 the far cells are.
DEFAULT_SKIP_DEPTH = 5

_CACHE: "OrderedDict[tuple, OccupancyGrid]" = OrderedDict()
_CACHE_SIZE = 8


@dataclass
class OccupancyGrid:
    """Occupied cells (R, R, R) bool (index [i, j, k] ↔ x, y, z) of the cube [-bound, bound]³, unit frame;
    ``boxes`` how many range bounds building it took."""

    occupied: torch.Tensor
    bound: float
    boxes: int

    @property
    def resolution(self) -> int:
        return int(self.occupied.shape[0])

    def fraction(self) -> float:
        """Share of the cube's cells that are occupied."""
        return float(self.occupied.float().mean())

    def ray_interval(self, origins: torch.Tensor, dirs: torch.Tensor, chunk: int = 1 << 20
                     ) -> tuple[torch.Tensor, torch.Tensor]:
        """(t_start, t_end) (N,) of rays (unit frame) around every occupied cell they can meet;
        t_end < t_start where they meet none."""
        r = self.resolution
        cell = 2 * self.bound / r
        dil = _dilate(self.occupied).to(origins.device)
        t_in, t_out = box_interval(origins, dirs, self.bound)
        h = cell / 2
        start = torch.full_like(t_in, math.inf)
        end = torch.full_like(t_in, -math.inf)
        length = (t_out - t_in).clamp_min(0)
        steps = int(math.ceil(float(length.max()) / h)) + 1 if length.numel() else 0
        ks = torch.arange(steps + 1, device=origins.device, dtype=origins.dtype) * h
        for s in range(0, origins.shape[0], max(1, chunk // max(1, steps))):
            e = min(origins.shape[0], s + max(1, chunk // max(1, steps)))
            tk = t_in[s:e, None] + ks[None, :]  # (n, S)
            tk = torch.minimum(tk, t_out[s:e, None])  # the last sample sits on the exit
            p = origins[s:e, None, :] + tk[..., None] * dirs[s:e, None, :]
            ijk = ((p + self.bound) / cell).floor().long().clamp(0, r - 1)
            occ = dil[ijk[..., 0], ijk[..., 1], ijk[..., 2]] & (length[s:e, None] > 0)
            any_occ = occ.any(dim=1)
            first = occ.float().argmax(dim=1)
            lastk = steps - occ.flip(1).float().argmax(dim=1)
            rows = torch.arange(e - s, device=origins.device)
            start[s:e] = torch.where(any_occ, tk[rows, first], start[s:e])
            end[s:e] = torch.where(any_occ, tk[rows, lastk], end[s:e])
        return start, end


def _dilate(occ: torch.Tensor) -> torch.Tensor:
    x = occ.float()[None, None]
    return (torch.nn.functional.max_pool3d(x, 3, stride=1, padding=1)[0, 0] > 0)


def build_occupancy(level: TraceLevel, counter: EvalCounter, *, depth: int = DEFAULT_SKIP_DEPTH,
                    bound: float = 1.0, dtype=torch.float32, device=None) -> OccupancyGrid:
    """The occupancy grid of ``level``'s band [|h| ≤ δ] (module docstring); bounds counted as ``skip_octree``."""
    if level.bound is None:
        raise RenderError(f"empty-space skipping: level {level.name} has no range bound")
    if isinstance(depth, bool) or int(depth) != depth or not 1 <= depth <= 8:
        raise RenderError(f"empty-space skipping depth: expected a whole number in 1..8, got {depth!r}")
    r = 1 << int(depth)
    occ = torch.zeros((r, r, r), dtype=torch.bool)
    delta = level.delta
    cells = torch.zeros((1, 3), dtype=torch.long)  # corners, in leaf cells
    side = r
    boxes = 0
    while len(cells):
        half = side * bound / r  # half-side, unit frame
        centers = (-bound + (cells.to(torch.float64) + side / 2) * (2 * bound / r)).to(dtype)
        axes = (torch.eye(3, dtype=dtype) * half).expand(len(cells), 3, 3).contiguous()
        if device is not None:
            centers, axes = centers.to(device), axes.to(device)
        lo, hi = counter.bound(level, "skip_octree", centers, axes)
        lo, hi = lo.cpu(), hi.cpu()
        boxes += len(cells)
        inner = hi < -delta
        straddle = ~inner & ~(lo > delta)
        for c in cells[inner].tolist():
            occ[c[0]:c[0] + side, c[1]:c[1] + side, c[2]:c[2] + side] = True
        if side == 1:
            for c in cells[straddle].tolist():
                occ[c[0], c[1], c[2]] = True
            break
        side //= 2
        parents = cells[straddle]
        offsets = torch.tensor([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], dtype=torch.long) * side
        cells = (parents[:, None, :] + offsets[None]).reshape(-1, 3)
    return OccupancyGrid(occ, float(bound), boxes)


def occupancy_for(level: TraceLevel, counter: EvalCounter, *, depth: int = DEFAULT_SKIP_DEPTH, bound: float = 1.0,
                  dtype=torch.float32, device=None, cache_dir=None) -> tuple[OccupancyGrid, bool]:
    """The cached grid of ``level`` (built on first use); returns (grid, built_now). With ``cache_dir`` the
    grid is also kept on disk (``<digest>.npz``, written atomically), so later processes reuse it."""
    if level.model is None:  # analytic levels have no weights to key a cache by (and build fast)
        return build_occupancy(level, counter, depth=depth, bound=bound, dtype=dtype, device=device), True
    key = (level.fingerprint(), level.delta, int(depth), float(bound), str(dtype))
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key], False
    path = None
    if cache_dir is not None:
        digest = hashlib.sha1(repr(key).encode()).hexdigest()[:24]
        path = Path(cache_dir) / f"skip-{digest}.npz"
        grid = _read_cached(path, 1 << int(depth), float(bound))
        if grid is not None:
            _CACHE[key] = grid
            return grid, False
    grid = build_occupancy(level, counter, depth=depth, bound=bound, dtype=dtype, device=device)
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            buf = io.BytesIO()
            np.savez_compressed(buf, occupied=grid.occupied.numpy(), bound=grid.bound, boxes=grid.boxes)
            atomic_write_bytes(path, buf.getvalue())
        except OSError:  # a cache that cannot be written only costs a rebuild next time
            pass
    _CACHE[key] = grid
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return grid, True


def _read_cached(path: Path, resolution: int, bound: float) -> OccupancyGrid | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            occ = torch.as_tensor(z["occupied"])
            grid = OccupancyGrid(occ.bool(), float(z["bound"]), int(z["boxes"]))
    except (OSError, ValueError, KeyError):
        return None
    if tuple(grid.occupied.shape) != (resolution,) * 3 or grid.bound != bound:
        return None
    return grid


def clear_cache() -> None:
    """Forget every cached grid (tests, benchmarks timing the build)."""
    _CACHE.clear()
