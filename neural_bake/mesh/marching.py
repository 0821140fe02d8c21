"""Coarse meshes by marching cubes of an SDF, dense or range-pruned (Spelunking §4.7), or cost-aware.

Range bounds of a box cost ~12–70 network evaluations (interval, affine-fixed; measured for (64, 1) to
(256, 3) on this project's CPU) and prune nothing on boxes much wider than ~1/ω0 of a trained SIREN, so
always pruning can be slower than evaluating every grid point. ``pruned="auto"`` measures both costs and a
probe's pruned fraction per octree level and bounds only levels that pay (see :func:`march`).
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np
import torch

from ..constants import DEGENERATE_AREA
from ..errors import NeuralBakeError
from ..types import Frame, Mesh

__all__ = ["march", "grid_points", "AUTO_METHODS", "PAYBACK"]

#: Default number of points per network evaluation batch.
DEFAULT_CHUNK = 1 << 16


def grid_points(resolution: int, bound: float = 1.0) -> np.ndarray:
    """(R+1,) float64 grid coordinates along one axis: ``-bound + i * 2 bound / R``, i = 0..R."""
    return -bound + np.arange(resolution + 1, dtype=np.float64) * (2.0 * bound / resolution)


def _as_field(field) -> tuple[Callable[[torch.Tensor], torch.Tensor], torch.dtype, torch.device, bool]:
    """(evaluate (N, 3) -> (N,), dtype, device, bounded) for a scalar Siren, a tiled SDF or a callable (``bounded``:
    range analysis bounds its values over boxes)."""
    from ..nets.siren import Siren

    if getattr(field, "composite", False):  # several networks with their own range bounds (nets.tiles.TiledSdf)
        p = next(field.parameters())
        return field.value, p.dtype, p.device, True

    if isinstance(field, Siren):
        if field.in_dim != 3 or field.out_dim != 1:
            raise NeuralBakeError(
                f"march: field must be a scalar SDF of 3-D points, got a Siren {field.in_dim} -> {field.out_dim}"
            )
        p = next(field.parameters())
        return (lambda x: field(x)[:, 0]), p.dtype, p.device, True
    if isinstance(field, torch.nn.Module):
        params = list(field.parameters())
        dtype = params[0].dtype if params else torch.float32
        device = params[0].device if params else torch.device("cpu")
    elif callable(field):
        dtype, device = torch.float32, torch.device("cpu")
    else:
        raise NeuralBakeError(f"march: field must be a Siren or a callable (N, 3) -> (N,), got {type(field).__name__}")

    def evaluate(x):
        y = field(x)
        if y.dim() == 2 and y.shape[1] == 1:
            y = y[:, 0]
        if y.shape != (x.shape[0],):
            raise NeuralBakeError(f"march: field must map (N, 3) points to (N,) values, got {tuple(y.shape)}")
        return y

    return evaluate, dtype, device, False


def _evaluate(evaluate, pts: np.ndarray, dtype, device, chunk: int) -> np.ndarray:
    """f at (N, 3) float64 points, in chunks -> (N,) float32 (what marching cubes works in)."""
    out = np.empty(len(pts), dtype=np.float32)
    with torch.no_grad():
        for s in range(0, len(pts), chunk):
            x = torch.as_tensor(pts[s : s + chunk], dtype=dtype, device=device)
            out[s : s + chunk] = evaluate(x).detach().to("cpu", torch.float32).numpy()
    if not np.isfinite(out).all():
        raise NeuralBakeError("march: the field returned non-finite values on the grid")
    return out


def _points(axis: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(N, 3) coordinates of flat grid indices ``idx`` into an (R+1)³ grid with coordinates ``axis``."""
    n = len(axis)
    i, rem = np.divmod(idx, n * n)
    j, k = np.divmod(rem, n)
    return np.stack([axis[i], axis[j], axis[k]], axis=1)


#: Range-analysis methods ``method="auto"`` chooses from, per octree level (cheapest first).
AUTO_METHODS = ("interval", "affine-fixed")

#: Boxes bounded with each candidate method to estimate a level's pruned fraction before committing to it.
PROBE_BOXES = 64

#: ``pruned="auto"`` bounds a level only when the evaluations it is expected to save cost at least this many
#: times its bounds (a margin for the noise of the measured costs).
PAYBACK = 1.5

#: Prior cost of one box bound in point evaluations (measured on this project's CPU: 12–28 for interval, 44–70
#: for affine-fixed, widths 64–256), used by ``pruned="auto"`` only to skip pruning on grids too small for its
#: probes to pay back; the decisions themselves use measured costs.
PRIOR_BOUND_COST = {"interval": 30.0, "affine-fixed": 70.0, "affine-truncate": 200.0, "affine-full": 400.0}

#: ``pruned="auto"`` marches densely when the first level's probes would cost more than this fraction of a
#: dense evaluation (at the prior costs).
MAX_PROBE_FRACTION = 0.1


def _top_side(resolution: int, leaf_cells: int) -> int:
    """Side (cells) of the octree's top-level boxes: the grid split in ~8 per axis, at least ``leaf_cells``."""
    size = 1
    while size < resolution:
        size *= 2
    return max(leaf_cells, size // 8)


def _boxes_at(lo: np.ndarray, side: int, resolution: int) -> np.ndarray:
    """(B, 2, 3) int64 [lo, hi) cell ranges of boxes with corners ``lo`` (B, 3) and ``side``, clipped to the grid."""
    return np.stack([lo, np.minimum(lo + side, resolution)], axis=1)


class _Bounder:
    """Range bounds of boxes of grid cells, timed (seconds per box per method)."""

    def __init__(self, model, resolution, bound, level):
        p = next(model.parameters())
        self.model, self.dtype, self.device = model, p.dtype, p.device
        self.h, self.bound, self.level, self.resolution = 2.0 * bound / resolution, bound, level, resolution
        self.seconds, self.count, self.warm = 0.0, 0, set()

    def signs(self, boxes: np.ndarray, method: str) -> tuple[np.ndarray, float]:
        """(B,) int8: +1 proven above ``level``, -1 proven below, 0 unknown; and the seconds it took."""
        from ..nets.range_analysis import range_bound

        if len(boxes) == 0:
            return np.zeros(0, np.int8), 0.0
        if method not in self.warm:  # the first call of a method pays one-off set-up: keep it out of the timing
            self._bound(boxes[:2], method, range_bound)
            self.warm.add(method)
        t0 = time.perf_counter()
        lo, hi = self._bound(boxes, method, range_bound)
        dt = time.perf_counter() - t0
        self.seconds += dt
        self.count += len(boxes)
        return np.where(lo > self.level, 1, np.where(hi < self.level, -1, 0)).astype(np.int8), dt

    def _bound(self, boxes, method, range_bound):
        lo_c = -self.bound + boxes[:, 0] * self.h
        hi_c = -self.bound + boxes[:, 1] * self.h
        center = torch.as_tensor((lo_c + hi_c) / 2, dtype=self.dtype, device=self.device)
        half = (hi_c - lo_c) / 2
        axes = torch.as_tensor(np.einsum("bi,ij->bij", half, np.eye(3)), dtype=self.dtype, device=self.device)
        lo, hi = range_bound(self.model, center, axes, method=method)
        return lo.detach().to("cpu", torch.float64).numpy(), hi.detach().to("cpu", torch.float64).numpy()


def _children(lo: np.ndarray, side: int, resolution: int) -> np.ndarray:
    """Corners of the (up to) 8 children of side ``side // 2`` of boxes at corners ``lo`` (inside the grid)."""
    half = side // 2
    kids = np.concatenate([lo + np.array(d) * half for d in np.ndindex(2, 2, 2)]) if len(lo) else lo
    return kids[(kids < resolution).all(axis=1)]


def _plan(bounder: _Bounder, resolution, leaf_cells, methods, auto, eval_cost, bound_cost):
    """Octree over the grid's cells, top-down (Spelunking §4.7), cost-aware when ``auto``.

    At each level the boxes (children of the previous level's unknown boxes) are bounded, those proven not to
    contain the level set are pruned, and the unknown ones are split in 8, down to ``leaf_cells``. With several
    ``methods`` or ``auto``, a random sample of :data:`PROBE_BOXES` boxes is bounded first with every method:
    its pruned fraction q and the cost of a bound c_b (``bound_cost(method, seconds_per_box)``) estimate the
    gain per box of bounding the level, ``q · cells · c_e - PAYBACK · c_b`` (c_e = ``eval_cost()``, the cost
    of one evaluation); the method with the larger gain bounds the rest. When ``auto`` and no gain is
    positive, the level is *skipped* (its boxes split unbounded, the probes proven empty kept) if its
    children could still pay (``cells / 8 · c_e > PAYBACK · c_b`` for some method, i.e. with q = 1: bounds
    of large boxes of a SIREN with a large ω0 prune nothing, those of small ones a lot), else its boxes are
    evaluated densely.

    Returns ``(levels, log)``: ``levels`` a list of ``(side, pruned_lo (P, 3), signs (P,), dense_lo (Q, 3))``
    (box corners in cells; every cell is in exactly one pruned or dense box) and ``log`` a list of per-level
    dicts for the stats.
    """
    rng = np.random.default_rng(0)
    side = _top_side(resolution, leaf_cells)
    ticks = np.arange(0, resolution, side)
    lo = np.stack(np.meshgrid(ticks, ticks, ticks, indexing="ij"), -1).reshape(-1, 3)
    none = np.zeros((0, 3), np.int64)
    levels, log = [], []
    while len(lo):
        boxes = _boxes_at(lo, side, resolution)
        n = len(boxes)
        cells = float(np.prod(boxes[:, 1] - boxes[:, 0], axis=1).mean())
        sign = np.zeros(n, np.int8)
        entry = {"side": side, "boxes": n, "cells_per_box": cells}
        log.append(entry)
        chosen, rest = methods[0], np.arange(n)
        if (len(methods) > 1 or auto) and n > PROBE_BOXES:
            probe = np.sort(rng.choice(n, PROBE_BOXES, replace=False))
            rest = np.setdiff1d(rest, probe)
            gains, probes, c_b = {}, {}, {}
            for m in methods:
                s, dt = bounder.signs(boxes[probe], m)
                sign[probe] = np.where(sign[probe] != 0, sign[probe], s)
                q = float((s != 0).mean())
                c_b[m], c_e = bound_cost(m, dt / len(probe)), eval_cost()
                gains[m] = q * cells * c_e - PAYBACK * c_b[m]
                probes[m] = {"pruned_fraction": q, "bound_cost": c_b[m], "eval_cost": c_e}
            chosen = max(methods, key=lambda m: gains[m])
            entry["probe"] = probes
            if auto and gains[chosen] <= 0:
                known = sign != 0
                deeper = side > leaf_cells and any(cells / 8 * c_e > PAYBACK * c_b[m] for m in methods)
                entry.update(decision="skip" if deeper else "dense", method=None, bounded=len(probe),
                             pruned=int(known.sum()), dense=0 if deeper else int((~known).sum()))
                levels.append((side, lo[known], sign[known], none if deeper else lo[~known]))
                if not deeper:
                    break
                lo, side = _children(lo[~known], side, resolution), side // 2
                continue
        s, _ = bounder.signs(boxes[rest], chosen)
        sign[rest] = s
        known = sign != 0
        last = side <= leaf_cells
        entry.update(decision="bound", method=chosen, bounded=n, pruned=int(known.sum()),
                     dense=int((~known).sum()) if last else 0)
        levels.append((side, lo[known], sign[known], lo[~known] if last else none))
        if last:
            break
        lo, side = _children(lo[~known], side, resolution), side // 2
    return levels, log


def _cell_grid(resolution: int, side: int, lo: np.ndarray, values, dtype) -> np.ndarray:
    """(R, R, R) array of the cells: ``values`` on the boxes of ``side`` cells at corners ``lo``, 0 elsewhere."""
    nb = -(-resolution // side)
    g = np.zeros((nb, nb, nb), dtype)
    c = lo // side
    g[c[:, 0], c[:, 1], c[:, 2]] = values
    if side > 1:
        g = g.repeat(side, 0).repeat(side, 1).repeat(side, 2)
    return g[:resolution, :resolution, :resolution]


def _touching_points(cells: np.ndarray) -> np.ndarray:
    """(R+1,)³ bool: grid points that are a corner of at least one True cell of ``cells`` (R, R, R)."""
    r = cells.shape[0]
    out = np.zeros((r + 1,) * 3, bool)
    for dx, dy, dz in np.ndindex(2, 2, 2):
        out[dx : dx + r, dy : dy + r, dz : dz + r] |= cells
    return out


def _lattice(n: int) -> np.ndarray:
    """Flat indices of a sub-lattice of the (n,)³ grid (every ``step``-th point, ≤ 17³ points), evaluated first
    to measure the cost of one evaluation (and kept for the march)."""
    step = max(2, -(-n // 16))
    t = np.arange(0, n, step)
    i, j, k = np.meshgrid(t, t, t, indexing="ij")
    return ((i * n + j) * n + k).reshape(-1)


def march(
    field,
    resolution: int = 64,
    *,
    level: float = 0.0,
    bound: float = 1.0,
    pruned: bool | str = False,
    method: str = "auto",
    chunk_size: int = DEFAULT_CHUNK,
    leaf_cells: int = 4,
    bound_cost: float | dict | None = None,
    frame: Frame | None = None,
) -> tuple[Mesh, dict]:
    """Triangle mesh of the level set ``field = level`` by Lewiner's marching cubes on a regular grid.

    Args:
        field: a scalar :class:`~neural_bake.nets.siren.Siren` (3 -> 1), a
            :class:`~neural_bake.nets.tiles.TiledSdf`, or a callable mapping (N, 3) tensors
            to (N,) (or (N, 1)) values; evaluated in its parameters' dtype/device (float32 on CPU for plain
            callables), under ``torch.no_grad``.
        resolution: R cells per axis: the grid has (R+1)³ points over [-bound, bound]³, spacing 2 bound / R.
        level: the iso-value (0 for an SDF's surface).
        bound: half side of the cube, unit frame.
        pruned: ``False``: evaluate every grid point. ``True``: an octree over the cells (Spelunking §4.7):
            boxes whose guaranteed range (:func:`neural_bake.nets.range_analysis.range_bound`) excludes
            ``level`` are pruned, the others split down to ``leaf_cells`` and their grid points evaluated.
            ``"auto"``: the same, cost-aware: a level is bounded only when the evaluations its bounds are
            expected to save (pruned fraction of a probe sample × cells, at the measured cost of one
            evaluation) pay :data:`PAYBACK` times their measured cost, otherwise its boxes are evaluated
            densely — so it is never much slower than dense (a few probes, a few %); it marches densely on
            grids too small for the probes to pay (:data:`MAX_PROBE_FRACTION`) and for fields that are not a
            Siren. In every case pruned points are filled with ``level ± 1`` of their proven sign and every
            cell with a crossing has its eight corners evaluated exactly, so the triangles are exactly those
            of the dense run. ``True`` needs a Siren.
        method: range-analysis method for the octree: one of
            :data:`~neural_bake.nets.range_analysis.METHODS`, or ``"auto"``: per level, the one of
            :data:`AUTO_METHODS` with the larger estimated gain on a probe sample (interval bounds cost
            ~3× less per box, affine-fixed ones prune more).
        chunk_size: points per network evaluation batch.
        leaf_cells: side (cells) of the octree leaves evaluated densely.
        bound_cost: the cost of bounding one box in network evaluations, a number or ``{method: number}``,
            in place of the measured costs (makes the choices of ``"auto"`` reproducible); None: measured
            (seconds per box of the probes ÷ seconds per point of an evaluation of a sub-lattice of the grid,
            whose values are kept).
        frame: the mesh's ``frame`` (default identity; pass the fine mesh's frame).

    Returns:
        ``(mesh, stats)``: ``mesh`` in the unit frame, faces wound so that normals point towards
        ``field > level`` (outward for an SDF), area-weighted vertex normals, degenerate triangles removed;
        ``stats``: ``mode`` ("dense", "pruned", "auto"), ``grid_points``, ``evaluations`` (network evaluations
        of grid points), ``evaluation_ratio`` (grid points ÷ evaluations), ``bound_evaluations`` (box bounds,
        probes included), ``boxes_pruned``, ``boxes_unknown`` (boxes evaluated densely), ``levels_bounded``,
        ``levels`` (per octree level: side, boxes, decision "bound"/"dense", method, bounded, pruned, dense,
        the probes' pruned fraction and costs), ``reason`` (why a run marched densely, else ""),
        ``seconds`` (total), ``seconds_eval``, ``seconds_bound``, ``seconds_plan`` (masks), ``seconds_march``,
        ``vertices``, ``faces``.

    Values are marched in float32 (scikit-image's precision). Raises :class:`NeuralBakeError` for bad
    arguments, non-finite field values, or a level set that does not cross the grid.
    """
    from skimage.measure import marching_cubes

    from ..nets.range_analysis import METHODS

    t0 = time.perf_counter()
    if int(resolution) != resolution or resolution < 2:
        raise NeuralBakeError(f"march: resolution must be an integer >= 2, got {resolution!r}")
    if not (np.isfinite(bound) and bound > 0):
        raise NeuralBakeError(f"march: bound must be a positive number, got {bound!r}")
    if int(chunk_size) != chunk_size or chunk_size < 1:
        raise NeuralBakeError(f"march: chunk_size must be a positive integer, got {chunk_size!r}")
    if int(leaf_cells) != leaf_cells or leaf_cells < 1:
        raise NeuralBakeError(f"march: leaf_cells must be a positive integer, got {leaf_cells!r}")
    if not np.isfinite(level):
        raise NeuralBakeError(f"march: level must be finite, got {level!r}")
    if pruned not in (False, True, "auto") or isinstance(pruned, (int, float)) and not isinstance(pruned, bool):
        raise NeuralBakeError(f"march: pruned must be False, True or 'auto', got {pruned!r}")
    if method != "auto" and method not in METHODS:
        raise NeuralBakeError(f"march: unknown method {method!r} (expected auto or one of {', '.join(METHODS)})")
    methods = list(AUTO_METHODS) if method == "auto" else [method]
    costs = _check_bound_cost(bound_cost, methods)
    resolution, chunk_size, leaf_cells = int(resolution), int(chunk_size), int(leaf_cells)
    evaluate, dtype, device, is_siren = _as_field(field)
    if pruned is True and not is_siren:
        raise NeuralBakeError("march: pruned=True needs a Siren or tiled SDF field (range analysis bounds its "
                              "values)")
    n = resolution + 1
    axis = grid_points(resolution, bound)
    mode = "dense" if pruned is False else ("auto" if pruned == "auto" else "pruned")
    stats = {
        "resolution": resolution,
        "mode": mode,
        "pruned": mode != "dense",
        "grid_points": n**3,
        "bound_evaluations": 0,
        "boxes_pruned": 0,
        "boxes_unknown": 0,
        "levels_bounded": 0,
        "levels": [],
        "reason": "",
        "seconds_bound": 0.0,
        "seconds_eval": 0.0,
        "seconds_plan": 0.0,
    }
    if mode == "auto":
        probe_cost = PROBE_BOXES * sum(costs.get(m, PRIOR_BOUND_COST[m]) for m in methods)
        if not is_siren:
            stats["reason"] = "not a Siren or tiled SDF: no range bounds"
        elif probe_cost > MAX_PROBE_FRACTION * n**3:
            stats["reason"] = (f"grid too small: probes (~{probe_cost:.0f} evaluations) would cost more than "
                               f"{MAX_PROBE_FRACTION:.0%} of the {n**3} grid points")
    if mode == "dense" or stats["reason"]:
        t1 = time.perf_counter()
        vol = _evaluate(evaluate, _points(axis, np.arange(n**3)), dtype, device, chunk_size).reshape(n, n, n)
        stats["seconds_eval"] = time.perf_counter() - t1
        stats["evaluations"] = n**3
        need = None
    else:
        vol, need = _march_octree(field, evaluate, dtype, device, axis, resolution, bound, level, methods,
                                  mode == "auto", leaf_cells, chunk_size, costs, stats)
    stats["evaluation_ratio"] = stats["grid_points"] / max(stats["evaluations"], 1)
    vmin, vmax = float(vol.min()), float(vol.max())
    if not (vmin < level < vmax):
        raise NeuralBakeError(
            f"march: the level set f = {level:g} does not cross the grid over [-{bound:g}, {bound:g}]^3"
            f" (values in [{vmin:.4g}, {vmax:.4g}])"
        )
    h = 2.0 * bound / resolution
    t3 = time.perf_counter()
    # pruned: march only the cells of unknown boxes (mask); the others hold no crossing by construction
    verts, faces, _, _ = marching_cubes(
        vol,
        level=level,
        spacing=(h, h, h),
        gradient_direction="descent",
        method="lewiner",
        allow_degenerate=False,
        mask=need,
    )
    stats["seconds_march"] = time.perf_counter() - t3
    verts = verts.astype(np.float64) - bound
    faces = faces.astype(np.int64)
    mesh = Mesh(vertices=verts, faces=faces, frame=frame or Frame(), source="")
    from ..geometry import vertex_normals

    mesh.vertex_normals = vertex_normals(mesh)
    mesh.degenerate = mesh.face_areas < DEGENERATE_AREA
    from ..geometry import edge_report

    mesh.watertight = edge_report(faces)["watertight"]
    stats["seconds"] = time.perf_counter() - t0
    stats["vertices"], stats["faces"] = mesh.n_vertices, mesh.n_faces
    return mesh, stats


def _check_bound_cost(bound_cost, methods) -> dict:
    """``bound_cost`` as ``{method: evaluations per box}`` for ``methods`` ({} when None)."""
    if bound_cost is None:
        return {}
    if isinstance(bound_cost, dict):
        missing = [m for m in methods if m not in bound_cost]
        if missing:
            raise NeuralBakeError(f"march: bound_cost has no cost for method(s) {', '.join(missing)}")
        values = {m: bound_cost[m] for m in methods}
    else:
        values = {m: bound_cost for m in methods}
    for m, v in values.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and v >= 0):
            raise NeuralBakeError(f"march: bound_cost must be a non-negative number of evaluations, got {v!r}")
    return {m: float(v) for m, v in values.items()}


def _march_octree(model, evaluate, dtype, device, axis, resolution, bound, level, methods, auto, leaf_cells,
                  chunk_size, costs, stats):
    """The pruned/auto branch of :func:`march`: returns (volume (n, n, n) float32, point mask to march)."""
    n = resolution + 1
    vol = np.empty((n, n, n), dtype=np.float32)
    have = np.zeros(n**3, bool)
    eval_seconds = [0.0]
    cost_state: dict = {}

    def eval_cost() -> float:
        """Seconds per evaluation (or 1 when ``bound_cost`` is given): times a sub-lattice of the grid, once."""
        if costs:
            return 1.0
        if "c_e" not in cost_state:
            idx = _lattice(n)
            _evaluate(evaluate, _points(axis, idx[:64]), dtype, device, chunk_size)  # warm-up, untimed
            t = time.perf_counter()
            vol.reshape(-1)[idx] = _evaluate(evaluate, _points(axis, idx), dtype, device, chunk_size)
            dt = time.perf_counter() - t
            eval_seconds[0] += dt
            have[idx] = True
            cost_state["c_e"] = dt / len(idx)
        return cost_state["c_e"]

    def bound_cost(method: str, seconds_per_box: float) -> float:
        return costs[method] if costs else seconds_per_box

    bounder = _Bounder(model, resolution, bound, level)
    t1 = time.perf_counter()
    levels, log = _plan(bounder, resolution, leaf_cells, methods, auto, eval_cost, bound_cost)
    t_plan = time.perf_counter() - t1 - bounder.seconds - eval_seconds[0]
    t2 = time.perf_counter()
    pos = np.zeros((resolution,) * 3, bool)
    neg = np.zeros((resolution,) * 3, bool)
    dense = np.zeros((resolution,) * 3, bool)
    for side, p_lo, p_sign, d_lo in levels:
        if len(p_lo):
            g = _cell_grid(resolution, side, p_lo, p_sign, np.int8)
            pos |= g > 0
            neg |= g < 0
        if len(d_lo):
            dense |= _cell_grid(resolution, side, d_lo, True, bool)
    # every point is a corner of a pruned or a dense cell; a point touching pruned cells of both signs would
    # contradict the bounds. Exact values (lattice, dense points) are written over the proven signs.
    flat = vol.reshape(-1)
    exact = flat[have]
    flat[:] = np.nan
    step = max(1.0, abs(level) * 2.0**-10)  # a value of the proven sign that float32 tells apart from level
    vol[_touching_points(pos)] = level + step
    vol[_touching_points(neg)] = level - step
    flat[have] = exact
    need = _touching_points(dense)
    idx = np.flatnonzero(need.reshape(-1) & ~have)
    t_plan += time.perf_counter() - t2
    t3 = time.perf_counter()
    flat[idx] = _evaluate(evaluate, _points(axis, idx), dtype, device, chunk_size)
    eval_seconds[0] += time.perf_counter() - t3
    if np.isnan(flat).any():  # every grid point is in a pruned or a dense box: a bug if not
        raise RuntimeError("march: octree left grid points neither evaluated nor proven")
    stats.update(
        evaluations=int(len(idx) + have.sum()),
        bound_evaluations=int(bounder.count),
        boxes_pruned=int(sum(len(p) for _, p, _, _ in levels)),
        boxes_unknown=int(sum(len(d) for _, _, _, d in levels)),
        levels_bounded=int(sum(e["decision"] == "bound" for e in log)),
        levels=log,
        seconds_bound=bounder.seconds,
        seconds_eval=eval_seconds[0],
        seconds_plan=max(t_plan, 0.0),
    )
    if not costs and "c_e" in cost_state:
        stats["seconds_per_evaluation"] = cost_state["c_e"]
    if auto and stats["levels"] and stats["levels"][0]["decision"] == "dense":
        stats["reason"] = "bounds at the top level prune too little to pay for themselves"
    return vol, need
