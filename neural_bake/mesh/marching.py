"""Coarse meshes by marching cubes of an SDF, dense or range-pruned (Spelunking §4.7)."""

from __future__ import annotations

import time
from typing import Callable

import numpy as np
import torch

from ..constants import DEGENERATE_AREA
from ..errors import NeuralBakeError
from ..types import Frame, Mesh

__all__ = ["march", "grid_points"]

#: Default number of points per network evaluation batch.
DEFAULT_CHUNK = 1 << 16


def grid_points(resolution: int, bound: float = 1.0) -> np.ndarray:
    """(R+1,) float64 grid coordinates along one axis: ``-bound + i * 2 bound / R``, i = 0..R."""
    return -bound + np.arange(resolution + 1, dtype=np.float64) * (2.0 * bound / resolution)


def _as_field(field) -> tuple[Callable[[torch.Tensor], torch.Tensor], torch.dtype, torch.device, bool]:
    """(evaluate (N, 3) -> (N,), dtype, device, is_siren) for a scalar Siren or a callable."""
    from ..nets.siren import Siren

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


def _prune(model, resolution, bound, level, method, leaf_cells, chunk):
    """Octree over cells: returns (unknown leaf boxes (K, 2, 3) int64 [lo, hi) cell ranges, pruned boxes
    with their sign, stats). Boxes proven (range bound) not to contain the level set are pruned."""
    from ..nets.range_analysis import range_bound

    h = 2.0 * bound / resolution
    p = next(model.parameters())
    size = 1
    while size < resolution:
        size *= 2
    # start from boxes of at most 8^3 per axis split of the root, to batch the bound evaluations
    start = max(leaf_cells, size // 8)
    ticks = np.arange(0, resolution, start)
    g = np.stack(np.meshgrid(ticks, ticks, ticks, indexing="ij"), -1).reshape(-1, 3)
    boxes = np.stack([g, np.minimum(g + start, resolution)], axis=1)  # (B, 2, 3)
    cur = start
    leaves, pruned, signs = [], [], []
    n_bounds = 0
    while len(boxes):
        lo_c = -bound + boxes[:, 0] * h
        hi_c = -bound + boxes[:, 1] * h
        center = torch.as_tensor((lo_c + hi_c) / 2, dtype=p.dtype, device=p.device)
        half = (hi_c - lo_c) / 2
        axes = torch.as_tensor(np.einsum("bi,ij->bij", half, np.eye(3)), dtype=p.dtype, device=p.device)
        lo, hi = range_bound(model, center, axes, method=method)
        n_bounds += len(boxes)
        lo = lo.detach().to("cpu", torch.float64).numpy()
        hi = hi.detach().to("cpu", torch.float64).numpy()
        pos, neg = lo > level, hi < level
        keep = pos | neg
        pruned.append(boxes[keep])
        signs.append(np.where(pos[keep], 1.0, -1.0))
        unknown = boxes[~keep]
        if cur <= leaf_cells:
            leaves.append(unknown)
            break
        cur //= 2
        # split each unknown box into up to 8 children of side cur (clipped to the grid)
        kids = []
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    o = unknown[:, 0] + np.array([dx, dy, dz]) * cur
                    kids.append(np.stack([o, np.minimum(o + cur, unknown[:, 1])], axis=1))
        boxes = np.concatenate(kids) if kids else np.zeros((0, 2, 3), np.int64)
        boxes = boxes[(boxes[:, 1] > boxes[:, 0]).all(axis=1)]
    leaves = np.concatenate(leaves) if leaves else np.zeros((0, 2, 3), np.int64)
    return leaves, np.concatenate(pruned), np.concatenate(signs), n_bounds


def march(
    field,
    resolution: int = 64,
    *,
    level: float = 0.0,
    bound: float = 1.0,
    pruned: bool = False,
    method: str = "affine-fixed",
    chunk_size: int = DEFAULT_CHUNK,
    leaf_cells: int = 4,
    frame: Frame | None = None,
) -> tuple[Mesh, dict]:
    """Triangle mesh of the level set ``field = level`` by Lewiner's marching cubes on a regular grid.

    Args:
        field: a scalar :class:`~neural_bake.nets.siren.Siren` (3 -> 1), or a callable mapping (N, 3) tensors
            to (N,) (or (N, 1)) values; evaluated in its parameters' dtype/device (float32 on CPU for plain
            callables), under ``torch.no_grad``.
        resolution: R cells per axis: the grid has (R+1)³ points over [-bound, bound]³, spacing 2 bound / R.
        level: the iso-value (0 for an SDF's surface).
        bound: half side of the cube, unit frame.
        pruned: evaluate only the grid points of octree boxes whose guaranteed range
            (:func:`neural_bake.nets.range_analysis.range_bound`, ``method``) contains ``level``
            (Spelunking §4.7). Other points are filled with ``level ± 1`` of the proven sign. Every cell
            with a crossing has all eight corners evaluated exactly, and the others keep their signs, so
            the triangles are exactly those of the dense run. Needs a Siren.
        method: range-analysis method for ``pruned`` (``"interval"``, ``"affine-fixed"``, …).
        chunk_size: points per network evaluation batch.
        leaf_cells: side (cells) of the octree leaves evaluated densely.
        frame: the mesh's ``frame`` (default identity; pass the fine mesh's frame).

    Returns:
        ``(mesh, stats)``: ``mesh`` in the unit frame, faces wound so that normals point towards
        ``field > level`` (outward for an SDF), area-weighted vertex normals, degenerate triangles removed;
        ``stats``: ``{"evaluations", "grid_points", "seconds", "seconds_eval", "seconds_bound",
        "bound_evaluations", "boxes_pruned", "boxes_unknown", "pruned"}``.

    Values are marched in float32 (scikit-image's precision). Raises :class:`NeuralBakeError` for bad
    arguments, non-finite field values, or a level set that does not cross the grid.
    """
    from skimage.measure import marching_cubes

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
    resolution, chunk_size, leaf_cells = int(resolution), int(chunk_size), int(leaf_cells)
    evaluate, dtype, device, is_siren = _as_field(field)
    if pruned and not is_siren:
        raise NeuralBakeError("march: pruned=True needs a Siren field (range analysis bounds its values)")
    n = resolution + 1
    axis = grid_points(resolution, bound)
    stats = {
        "resolution": resolution,
        "pruned": bool(pruned),
        "grid_points": n**3,
        "bound_evaluations": 0,
        "boxes_pruned": 0,
        "boxes_unknown": 0,
        "seconds_bound": 0.0,
    }
    if not pruned:
        t1 = time.perf_counter()
        vol = _evaluate(evaluate, _points(axis, np.arange(n**3)), dtype, device, chunk_size).reshape(n, n, n)
        stats["seconds_eval"] = time.perf_counter() - t1
        stats["evaluations"] = n**3
    else:
        t1 = time.perf_counter()
        leaves, boxes, signs, n_bounds = _prune(field, resolution, bound, level, method, leaf_cells, chunk_size)
        stats["seconds_bound"] = time.perf_counter() - t1
        stats.update(bound_evaluations=int(n_bounds), boxes_pruned=int(len(boxes)), boxes_unknown=int(len(leaves)))
        vol = np.empty((n, n, n), dtype=np.float32)
        # pruned boxes: the proven sign (grid points of the box, ends included)
        for (lo, hi), s in zip(boxes, signs):
            vol[lo[0] : hi[0] + 1, lo[1] : hi[1] + 1, lo[2] : hi[2] + 1] = level + s
        need = np.zeros((n, n, n), dtype=bool)
        for lo, hi in leaves:
            need[lo[0] : hi[0] + 1, lo[1] : hi[1] + 1, lo[2] : hi[2] + 1] = True
        idx = np.flatnonzero(need)
        t2 = time.perf_counter()
        vol.reshape(-1)[idx] = _evaluate(evaluate, _points(axis, idx), dtype, device, chunk_size)
        stats["seconds_eval"] = time.perf_counter() - t2
        stats["evaluations"] = int(len(idx))
    vmin, vmax = float(vol.min()), float(vol.max())
    if not (vmin < level < vmax):
        raise NeuralBakeError(
            f"march: the level set f = {level:g} does not cross the grid over [-{bound:g}, {bound:g}]^3"
            f" (values in [{vmin:.4g}, {vmax:.4g}])"
        )
    h = 2.0 * bound / resolution
    # pruned: march only the cells of unknown boxes (mask); the others hold no crossing by construction
    verts, faces, _, _ = marching_cubes(
        vol,
        level=level,
        spacing=(h, h, h),
        gradient_direction="descent",
        method="lewiner",
        allow_degenerate=False,
        mask=need if pruned else None,
    )
    verts = verts.astype(np.float64) - bound
    faces = faces.astype(np.int64)
    mesh = Mesh(vertices=verts, faces=faces, frame=frame or Frame(), source="")
    from .tangents import vertex_normals

    mesh.vertex_normals = vertex_normals(mesh)
    mesh.degenerate = mesh.face_areas < DEGENERATE_AREA
    from .cleanup import edge_report

    mesh.watertight = edge_report(faces)["watertight"]
    stats["seconds"] = time.perf_counter() - t0
    stats["vertices"], stats["faces"] = mesh.n_vertices, mesh.n_faces
    return mesh, stats
