"""Adaptive texel evaluation: the fields on a coarse lattice of each chart, refined where interpolation would err.

The samples of a band of texels lie on the sample grid (H·s, W·s) (s = supersample). A *cell* is a square of
that grid whose corners are multiples of its side k, from k = ``lattice`` down to 4. A cell is *pure* when
every position of its closed square holds a sample of one chart (no seam, no uncovered texel, no border
sample inside it) and, when wider than ``vertex_side``, no feature of the coarse mesh (an edge that bends
more than ``ADAPTIVE_EDGE_DEG``, with its ends) lies inside it. For a pure cell the fields are evaluated at its
3×3 nodes (corners, edge midpoints, centre), and the cell is accepted when the midpoints' and the centre's
values lie within ``ADAPTIVE_SAFETY`` times the tolerances of what the corners predict (the hierarchical
surplus: an estimate of the interpolation error, larger than the error left when interpolating from the 3×3
nodes in a smooth field). Its other samples are then interpolated from those 3×3 nodes, each from the four
of its quarter, with weights from its position in space (:func:`_weights`; normals renormalised, f
extrapolated to first order from each node). A pure cell that fails is tested once more for quadratic
interpolation: the fields are evaluated at its quarters' centres (nodes of the next level; at side 4, samples
the failed cell evaluates anyway: a failure costs nothing) and compared with the quadratic through its 3×3
nodes in the same spatial coordinates (:func:`_quadratic_weights`), at half the tolerances; when they pass,
its other samples are interpolated from all nine nodes. Otherwise, and for impure cells, the cell splits into
four of side k/2. Every sample that no accepted cell covers is evaluated: chart borders, seams, islands smaller
than the lattice, border samples, and every cell refined below side 4. Interpolation never crosses a seam: the
nodes and samples of an accepted cell all belong to one chart. With the coarse mesh's faces
(``faces``), the samples no cell could hold (chart borders, seams, off-grid samples, around vertices; not those
of side-4 cells that failed, where the fields vary too fast) are interpolated inside their own faces where that
pays (:mod:`.adaptive_faces`), when the lattice itself interpolated more samples than it evaluated.

A hybrid bake may give cells up to the classical bake (``give_up``, :meth:`~neural_bake.bake.hybrid.HybridFallback.early`):
on its decision at the nodes of a cell that fails; in a bake of normals alone also before the nodes are evaluated, on
the classical rays' normals there (the source's detail), and, after the face pass, the samples still to evaluate
next to a given-up one where their rays hit (the detail rim).

The same refinement serves every field: f, the unit normals ∇f/|∇f| and (when a texture is baked) the colours
are evaluated at the same samples, and a cell is accepted only when all of them pass their tolerance. The
surplus is an estimate, not a bound: a feature of the field narrower than the node spacing can hide between
nodes; the bake measures its error against a full evaluation on a seeded subsample (the bake report).
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..constants import ADAPTIVE_GRID_SNAP, ADAPTIVE_SAFETY, ADAPTIVE_EDGE_DEG, DIRECTION_EPS
from ..nets.native import Kernel, threads
from ..types import Mesh
from .adaptive_faces import FaceGeometry, face_pass
from .adaptive_options import AdaptiveOptions

__all__ = ["AdaptiveOptions", "chart_labels", "grid_positions", "vertex_positions", "adaptive_evaluate",
           "kernel_status", "ENV_SWITCH"]

#: 0/off/false: the torch interpolation even where the C kernel (adaptive.c) builds (A/B checks).
ENV_SWITCH = "NEURAL_BAKE_NATIVE_ADAPTIVE"


def _declare(lib) -> None:
    p, i64, f64 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
    lib.nb_interp_cells.argtypes = [p, i64, p, p, i64, i64, p, p, p, p, i64, p, p, p, f64, f64, i64]
    lib.nb_interp_cells.restype = None
    lib.nb_interp_cells_quadratic.argtypes = lib.nb_interp_cells.argtypes
    lib.nb_interp_cells_quadratic.restype = None
    lib.nb_quadratic_test.argtypes = [p, p, i64, p, p, p, p, i64, p, f64, f64, f64, f64, f64, p, i64]
    lib.nb_quadratic_test.restype = None
    lib.nb_surplus_test.argtypes = [p, i64, p, p, p, p, i64, p, f64, f64, f64, f64, f64, p, i64]
    lib.nb_surplus_test.restype = None
    lib.nb_face_components.argtypes = [p, i64, i64, p, p]
    lib.nb_face_components.restype = i64


#: The C kernel (adaptive.c, :class:`neural_bake.nets.native.Kernel`; the cells' insides on torch's OpenMP team
#: where it shares it); torch where it does not build.
KERNEL = Kernel(Path(__file__).with_name("adaptive.c"), switch=ENV_SWITCH, declare=_declare, openmp=True)


def kernel_status() -> str:
    """Which cell interpolation (bilinear and quadratic), quadratic test and chart labelling run here: the C kernel
    (and its file), or why torch's interpolation and scipy's labelling do."""
    return KERNEL.status().replace("numpy (", "torch (", 1)

#: Interpolated samples handled at once (bounds the (7 + C, 4, n) gathered corner arrays; small enough for the cache).
_INTERP_CHUNK = 1 << 16


def chart_labels(mesh: Mesh) -> np.ndarray:
    """(F,) int64 chart of each face: the connected components of faces sharing a vertex.

    ``mesh`` must be split at its UV seams (:func:`neural_bake.mesh.unwrap.split_uv_seams`, as
    ``Baker.mesh`` is), so that faces sharing a vertex share its UV: a component is then a UV chart. Charts are
    numbered in the order of their first face (union-find in C where it builds, else scipy: the same numbers).
    """
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    nf, nv = len(faces), int(mesh.n_vertices)
    if nf == 0:
        return np.zeros(0, dtype=np.int64)
    lib = KERNEL.lib()
    if lib is not None and faces.min() >= 0 and faces.max() < nv:  # union-find in C: the same numbering
        labels, parent = np.empty(nf, dtype=np.int64), np.empty(nv, dtype=np.int64)
        lib.nb_face_components(faces.ctypes.data, nf, nv, parent.ctypes.data, labels.ctypes.data)
        return labels
    return _chart_labels_scipy(faces, nv)


def _chart_labels_scipy(faces: np.ndarray, nv: int) -> np.ndarray:
    """:func:`chart_labels` by scipy's connected components of the face-vertex graph (faces (F, 3) int64)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nf = len(faces)
    rows = np.repeat(np.arange(nf), 3)
    graph = coo_matrix((np.ones(3 * nf, dtype=np.int8), (rows, nf + faces.reshape(-1))), shape=(nf + nv, nf + nv))
    _, labels = connected_components(graph, directed=False)
    return labels[:nf].astype(np.int64)


def grid_positions(texels, mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) (M,) int64 of each sample on the sample grid (H·s, W·s), row 0 at the top; -1 for samples
    that are not at a grid position (border samples, placed at the closest point of a triangle).

    ``texels``: a :class:`~neural_bake.mesh.texels.TexelSet` (or band) of ``mesh`` (per-corner UVs (F, 3, 2)).
    A sample's position is recovered from its face's UVs and barycentrics; it must land on a grid position
    within :data:`ADAPTIVE_GRID_SNAP` and inside its own texel, else it counts as off the grid.
    """
    s = int(texels.supersample)
    h, w = texels.size
    face = np.asarray(texels.face, dtype=np.int64)
    if mesh.uv is None or len(face) == 0:
        e = np.full(len(face), -1, dtype=np.int64)
        return e, e.copy()
    if s == 1:  # one sample per texel, at its centre unless it is a border sample: the grid is the texels
        pix = np.asarray(texels.pixel, dtype=np.int64)
        off = np.asarray(texels.border, dtype=bool)
        return np.where(off, -1, pix[:, 0]), np.where(off, -1, pix[:, 1])
    return _grid_positions_from_uv(texels, mesh, face)


def _grid_positions_from_uv(texels, mesh: Mesh, face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`grid_positions` from the samples' UVs (any supersampling); ``face``: the samples' faces (int64)."""
    s = int(texels.supersample)
    h, w = texels.size
    uv = np.einsum("mk,mkd->md", np.asarray(texels.bary, dtype=np.float64), np.asarray(mesh.uv, np.float64)[face])
    x = uv[:, 0] * (w * s) - 0.5
    y = (1.0 - uv[:, 1]) * (h * s) - 0.5
    rx, ry = np.rint(x), np.rint(y)
    col = np.mod(rx.astype(np.int64), w * s)
    row = np.mod(ry.astype(np.int64), h * s)
    pix = np.asarray(texels.pixel, dtype=np.int64)
    ok = ((np.abs(x - rx) <= ADAPTIVE_GRID_SNAP) & (np.abs(y - ry) <= ADAPTIVE_GRID_SNAP)
          & ~np.asarray(texels.border, dtype=bool) & (row // s == pix[:, 0]) & (col // s == pix[:, 1]))
    return np.where(ok, row, -1), np.where(ok, col, -1)


def vertex_positions(mesh: Mesh, size: tuple[int, int], supersample: int,
                     edge_deg: float = ADAPTIVE_EDGE_DEG) -> np.ndarray:
    """(K, 2) float64 (row, col) positions on the sample grid (H·s, W·s) of the coarse mesh's geometric
    features: points at most half a grid step apart along every edge whose two faces' normals differ by more
    than ``edge_deg`` degrees, its two end vertices included. Interpolation errs most there: across such an
    edge the surface bends. A vertex only counts where such an edge ends: around the others the piecewise-flat
    surface bends by less than ``edge_deg`` between neighbouring faces, and refining every cell that holds a vertex
    cost 0.3–4.9 % more evaluations on the data meshes for nothing the check against a full evaluation saw
    (docs/findings.md, "The bake command: bytecode, …")."""
    if mesh.uv is None or mesh.n_faces == 0:
        return np.zeros((0, 2))
    h, w = size
    s = int(supersample)
    uv = np.asarray(mesh.uv, dtype=np.float64)  # (F, 3, 2)
    grid = np.stack([(1.0 - uv[..., 1]) * (h * s) - 0.5, uv[..., 0] * (w * s) - 0.5], axis=-1)  # (F, 3, 2)
    out = [np.zeros((0, 2))]
    faces = np.asarray(mesh.faces, dtype=np.int64)
    fn = np.asarray(mesh.face_normals, dtype=np.float64)
    edges = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)  # (3F, 2)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    e = edges[order]
    same = np.flatnonzero((e[1:] == e[:-1]).all(axis=1))  # pairs of face corners sharing an edge
    a, b = order[same], order[same + 1]
    sharp = np.einsum("ij,ij->i", fn[a // 3], fn[b // 3]) < np.cos(np.radians(edge_deg))
    for corner in a[sharp]:
        f, k = divmod(int(corner), 3)
        p, q = grid[f, k], grid[f, (k + 1) % 3]
        n = int(np.ceil(2 * np.abs(q - p).max())) + 1
        t = np.linspace(0.0, 1.0, n)[:, None]
        out.append(p + t * (q - p))
    pts = np.concatenate(out)
    return np.stack([np.mod(pts[:, 0], h * s), np.mod(pts[:, 1], w * s)], axis=1)


def _vertex_image(vertices: np.ndarray | None, r_base: int, hg: int, wg: int) -> np.ndarray:
    """(hg, wg) int64 count of vertices whose position lies in [r, r + 1) × [c, c + 1) (local rows)."""
    img = np.zeros((hg, wg), dtype=np.int64)
    if vertices is None or len(vertices) == 0:
        return img
    r = np.floor(vertices[:, 0]).astype(np.int64) - r_base
    c = np.floor(vertices[:, 1]).astype(np.int64)
    ok = (r >= 0) & (r < hg) & (c >= 0) & (c < wg)
    np.add.at(img, (r[ok], c[ok]), 1)
    return img


@dataclass
class _Store:
    """Per-sample field values of a band, filled by evaluation and interpolation."""

    values: np.ndarray
    normals: np.ndarray
    valid: np.ndarray
    colors: np.ndarray | None = None
    evaluated: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    interpolated: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    calls: int = 0


def _integral(image: np.ndarray) -> np.ndarray:
    """Integral image of counts (int32 where the grid is small enough not to overflow it) with a leading zero
    row and column."""
    dtype = np.int32 if image.size < 2**31 - 1 else np.int64
    out = np.zeros((image.shape[0] + 1, image.shape[1] + 1), dtype=dtype)
    np.cumsum(image, axis=1, dtype=dtype, out=out[1:, 1:])
    # down the columns one row at a time: contiguous rows, five times faster than cumsum(axis=0) at 2048²
    for i in range(2, out.shape[0]):
        np.add(out[i], out[i - 1], out=out[i])
    return out


def _box(s: np.ndarray, r0: np.ndarray, c0: np.ndarray, k: int) -> np.ndarray:
    """Sums of the closed squares [r0, r0 + k] × [c0, c0 + k] from the integral image ``s``."""
    r1, c1 = r0 + k + 1, c0 + k + 1
    return s[r1, c1] - s[r0, c1] - s[r1, c0] + s[r0, c0]


#: The 3×3 nodes of a cell as (row, col) multiples of half its side; corners are nodes 0, 2, 6, 8.
_NODES = np.array([(a, b) for a in range(3) for b in range(3)], dtype=np.int64)


def adaptive_evaluate(
    texels,
    charts: np.ndarray,
    grid: tuple[np.ndarray, np.ndarray],
    evaluate: Callable[[np.ndarray], dict],
    options: AdaptiveOptions | None = None,
    vertices: np.ndarray | None = None,
    dtype: torch.dtype = torch.float64,
    faces: FaceGeometry | None = None,
    evaluate_points: Callable[[np.ndarray, np.ndarray], dict] | None = None,
    give_up: Callable[..., np.ndarray] | None = None,
) -> dict:
    """Evaluate the fields at a band's samples adaptively (module docstring).

    - ``texels``: the band's :class:`~neural_bake.mesh.texels.TexelSet` (M samples).
    - ``charts``: (M,) int64 chart of each sample (``chart_labels(mesh)[texels.face]``).
    - ``grid``: (row, col) of each sample on the sample grid, -1 off it (:func:`grid_positions`).
    - ``vertices``: (V, 2) float (row, col) sample-grid positions of the mesh's features
      (:func:`vertex_positions`: points along its bent edges): cells wider than ``options.vertex_side`` holding
      one are refined.
    - ``dtype``: of the tolerance checks and the interpolation (torch, on the CPU's threads): float32 for
      the fields of a float32 network (its own precision), float64 (the default) to interpolate exactly.
    - ``evaluate``: sample indices (n,) int64 → ``{"values": (n,), "normals": (n, 3) unit ∇f (0 where
      invalid), "valid": (n,) bool, "colors": (n, C) or absent/None}``.
    - ``faces`` and ``evaluate_points`` ((points (n, 3), their faces (n,)) → the same dict): with both, the
      samples no cell covers are interpolated inside their faces where the fields allow (:mod:`.adaptive_faces`).
    - ``give_up`` ((nodes (P, 9) sample indices of cells that failed the bilinear test, normals (M, 3), valid (M,),
      values (M,), colours (M, C) or None: the band's fields so far; keyword ``side``: the cells' side) → (P,)
      bool): a hybrid bake's decision at
      their nodes (:meth:`~neural_bake.bake.hybrid.HybridFallback.early`); a cell it says is mostly unfaithful is
      *given up*: not tested or refined further, its samples interpolated bilinearly from its nodes (that ∇f is not
      what the map shows: the hybrid gives them the classical bake's normal) and returned in ``"given_up"``. With
      its attributes ``classical``, ``detail_side`` and ``rim_reach`` (a bake of normals alone), a cell no wider than
      ``detail_side`` with a node still to evaluate is first tested on the classical rays' normals at its nodes and
      given up unevaluated where they all hit and fail (its samples and evaluated nodes in ``"given_up"``, f there
      the source's signed distance; a wider cell is split unevaluated), and the samples left to evaluate within
      ``rim_reach`` of a given-up one whose rays hit are given up too.

    Returns ``{"values", "normals", "valid", "colors"}`` for all M samples (interpolated normals are unit,
    valid), ``"evaluated"`` and ``"interpolated"`` (M,) bool masks (one of the two holds for every sample),
    ``"decide"`` (the evaluated samples and the face pass's decision points: where a hybrid decides), ``"given_up"``
    ((M,) bool: the samples of given-up cells that no accepted cell covers, and the rim's), ``"side"``
    ((M,) int16: the side of the cell each interpolated sample lies in, every sample of which is that close to
    the cell's nodes; the lattice's side for samples interpolated inside faces, 0 for evaluated ones) and
    ``"stats"`` (samples evaluated / interpolated, cells accepted per level (``cells_quadratic``: of them, those
    interpolated quadratically; ``cells_given_up``, of them ``cells_source_detail``; ``cells_source_split``: wider cells
    split unevaluated on the source's detail), the face pass's evaluations at
    points of faces, samples and sub-triangles, the rim's samples (``rim``), evaluation calls).
    """
    opt = options or AdaptiveOptions()
    m = int(texels.n_samples)
    points = np.asarray(texels.points, dtype=np.float64)
    store = _Store(values=np.zeros(m), normals=np.zeros((m, 3)), valid=np.zeros(m, bool),
                   evaluated=np.zeros(m, bool), interpolated=np.zeros(m, bool))

    todo = np.zeros(m, bool)

    def run(idx: np.ndarray) -> None:
        idx = idx[~store.evaluated[idx]]
        todo[idx] = True  # a mask, not np.unique: linear in the band, no sort
        idx = np.flatnonzero(todo)
        todo[idx] = False
        if idx.size == 0:
            return
        ev = evaluate(idx)
        store.values[idx] = ev["values"]
        nrm = np.asarray(ev["normals"], dtype=np.float64)
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        # renormalised in float64: a float32 unit vector's dot with itself is 1 only to ~1e-7, the size of
        # cos(tolerance) − 1 for tolerances of a few hundredths of a degree
        store.normals[idx] = np.divide(nrm, length, out=np.zeros_like(nrm), where=length > DIRECTION_EPS)
        store.valid[idx] = ev["valid"]
        col = ev.get("colors")
        if col is not None:
            if store.colors is None:
                store.colors = np.zeros((m, col.shape[1]))
            store.colors[idx] = col
        store.evaluated[idx] = True
        store.calls += 1

    hard = np.zeros(m, bool)
    given_up = np.zeros(m, bool)
    rim_n = 0
    # the source's detail (a hybrid bake of normals alone): its classical rays at a cell's nodes before ∇f's
    classical = getattr(give_up, "classical", None)
    detail_side = int(getattr(give_up, "detail_side", 0)) if classical is not None else 0
    flat_f = np.zeros(m) if detail_side else None  # f of the source's test: not tested, its normals are
    side = np.zeros(m, np.int16)  # the side of the cell each sample was interpolated in
    gr, gc = (np.asarray(g, dtype=np.int64) for g in grid)
    on = np.flatnonzero(gr >= 0)
    k0 = int(opt.lattice)
    levels: dict[int, int] = {}
    given_cells: dict[int, int] = {}
    sourced_cells: dict[int, int] = {}
    split_cells: dict[int, int] = {}  # split on the source's detail, not evaluated
    if on.size:
        r_base = (int(gr[on].min()) // k0) * k0
        rows = int(gr[on].max()) - r_base + 1
        hg = -(-rows // k0) * k0 + 1
        wg = -(-(int(gc[on].max()) + 1) // k0) * k0 + 1
        index = np.full((hg, wg), -1, dtype=np.int64)
        index[gr[on] - r_base, gc[on]] = on
        occ = index >= 0
        lab = np.where(occ, np.asarray(charts, dtype=np.int64)[np.maximum(index, 0)], -1)
        # a full closed square [r0, r0 + k]² holds one chart when no position of [r0, r0 + k)² differs from
        # its right or lower neighbour (that reaches every position but the far corner) and the far corner
        # matches the near one
        s0 = _integral(occ)
        sd = _integral((lab[:-1, 1:] != lab[:-1, :-1]) | (lab[1:, :-1] != lab[:-1, :-1]))
        sv = _integral(_vertex_image(vertices, r_base, hg, wg))
        r0, c0 = (a.reshape(-1) for a in np.meshgrid(np.arange(0, hg - 1, k0), np.arange(0, wg - 1, k0),
                                                      indexing="ij"))
        keep = _box(s0, r0, c0, k0) > 0
        r0, c0 = r0[keep], c0[keep]
        k = k0
        accepted: list[tuple[np.ndarray, np.ndarray, int, bool]] = []
        gave: list[tuple[np.ndarray, np.ndarray, int]] = []
        sourced: list[tuple[np.ndarray, np.ndarray, int]] = []  # given up on the source's detail, not evaluated
        quadratic: dict[int, int] = {}
        while k >= 4 and r0.size:  # a side-2 cell has no sample besides its 3×3 nodes
            n = (k + 1) ** 2
            pure = _box(s0, r0, c0, k) == n  # full
            pure &= (_box(sd, r0, c0, k - 1) == 0) & (lab[r0 + k, c0 + k] == lab[r0, c0])  # one chart
            h = k // 2
            if k > opt.vertex_side:  # a bent edge of the mesh inside: the surface bends there, not smooth
                pure &= _box(sv, r0, c0, k - 1) == 0
            acc = np.zeros(len(r0), bool)
            p = np.flatnonzero(pure)
            quad = np.zeros(len(r0), bool)
            given = np.zeros(len(r0), bool)
            nodes = index[r0[p, None] + h * _NODES[:, 0], c0[p, None] + h * _NODES[:, 1]]  # (P, 9)
            fresh = ~store.evaluated[nodes].all(axis=1) if detail_side else None  # ∇f still to evaluate at a node
            if fresh is not None and fresh.any():
                off = np.zeros(len(p), bool)
                off[fresh] = _source_detail(classical, flat_f, points, nodes[fresh], opt, dtype)
                if off.any():
                    q = p[off]
                    if k <= detail_side:  # given up: the classical normal
                        sourced.append((r0[q], c0[q], k))
                        sourced_cells[k] = len(q)
                        given[q] = True
                    else:  # wider: split without evaluating ∇f, each quarter tested again
                        split_cells[k] = len(q)
                    p, nodes = p[~off], nodes[~off]
            if p.size:
                run(nodes.reshape(-1))
                acc[p] = _surplus_ok(store, points, nodes, opt, dtype)
                fail = ~acc[p]
                if give_up is not None and fail.any():  # mostly unfaithful: the classical bake's, not refined
                    off = np.flatnonzero(fail)[np.asarray(give_up(nodes[fail], store.normals, store.valid,
                                                                  store.values, store.colors, side=k), dtype=bool)]
                    if off.size:
                        gave.append((r0[p[off]], c0[p[off]], k))
                        given[p[off]] = True
                        fail[off] = False
                if k >= _QUADRATIC_SIDE and fail.any():  # the quarters' centres: evaluated anyway when it fails
                    f = p[fail]
                    tests = index[r0[f, None] + (k // 4) * _QUARTERS[:, 0], c0[f, None] + (k // 4) * _QUARTERS[:, 1]]
                    run(tests.reshape(-1))
                    quad[f] = _quadratic_ok(store, points, nodes[fail], tests, opt, dtype)
            if acc.any():
                accepted.append((r0[acc], c0[acc], k, False))
            if quad.any():
                accepted.append((r0[quad], c0[quad], k, True))
                quadratic[k] = int(quad.sum())
            if acc.any() or quad.any():
                levels[k] = int(acc.sum() + quad.sum())
            if given.any():
                given_cells[k] = int(given.sum())
            split = ~(acc | quad | given)
            if k == 4 and p.size:  # pure cells that failed at the last level: the fields vary too fast there
                f = p[split[p]]
                d = np.arange(k + 1)
                cells = index[r0[f, None, None] + d[:, None], c0[f, None, None] + d[None, :]]
                hard[cells[cells >= 0]] = True
            r0 = (r0[split, None] + h * np.array([0, 0, 1, 1])).reshape(-1)
            c0 = (c0[split, None] + h * np.array([0, 1, 0, 1])).reshape(-1)
            if h >= 2:
                keep = _box(s0, r0, c0, h) > 0
                r0, c0 = r0[keep], c0[keep]
            k = h
        # the nodes are all evaluated by now; the C kernel reads them from the store itself. The given-up cells
        # (bilinear) come after every accepted one: a sample an accepted cell covers keeps its interpolation
        cells = accepted + [(ar, ac, k, False) for ar, ac, k in gave]
        lib = KERNEL.lib() if cells else None
        packed = _pack(store, points, None, dtype) if cells and lib is None else None
        before = None
        for i, (ar, ac, k, quad) in enumerate(cells):
            if i == len(accepted):
                before = store.interpolated.copy()
            if lib is not None:
                _interpolate_native(lib, store, points, index, ar, ac, k, quadratic=quad)
            else:
                (_interpolate_quadratic if quad else _interpolate)(store, packed, index, ar, ac, k)
            side[store.interpolated & (side == 0)] = k
        if before is not None:
            given_up = store.interpolated & ~before
        for ar, ac, k in sourced:  # what no accepted cell holds: the classical normal (the hybrid's), its nodes' too
            d = np.arange(k + 1)
            held = index[ar[:, None, None] + d[:, None], ac[:, None, None] + d[None, :]].reshape(-1)
            held = held[~store.interpolated[held]]  # every position of a pure cell holds a sample
            given_up[held] = True
            held = held[~store.evaluated[held]]  # f not known there: the source's distance
            store.values[held] = classical(held).values[held]  # the normal is the hybrid's
            store.valid[held] = store.interpolated[held] = True
            side[held] = k
    rest = np.flatnonzero(~store.evaluated & ~store.interpolated)
    decide = np.zeros(m, bool)
    face_stats = {"nodes": 0, "interpolated": 0, "accepted": 0}
    # the lattice is the face pass's free probe: where it interpolated less than it evaluated, the fields vary
    # too fast for the faces' sub-triangles too
    if faces is not None and evaluate_points is not None and rest.size \
            and (store.interpolated & ~given_up).sum() >= store.evaluated.sum():
        # the samples no cell could hold (borders, seams, around vertices), not those of cells that failed
        rest = rest[~hard[rest]]
        fp = face_pass(rest, np.asarray(texels.face, dtype=np.int64)[rest], np.asarray(texels.bary)[rest],
                       points[rest], faces, evaluate_points, tolerance_deg=opt.tolerance_deg,
                       value_tol=opt.value_tol, color_tol=opt.color_tol)
        ok = fp["done"]
        d = rest[ok]
        store.normals[d], store.values[d], store.valid[d] = fp["normals"][ok], fp["values"][ok], True
        if fp["colors"] is not None:
            if store.colors is None:
                store.colors = np.zeros((m, fp["colors"].shape[1]))
            store.colors[d] = fp["colors"][ok]
        store.interpolated[d] = True
        side[d] = k0  # inside a face: the lattice's reach
        decide[rest[fp["decide"]]] = True
        face_stats = {"nodes": int(fp["nodes"]), "interpolated": int(d.size), "accepted": int(fp["accepted"])}
    rest = np.flatnonzero(~store.evaluated & ~store.interpolated)
    if classical is not None and rest.size and given_up.any():  # the detail rim: the classical normal where rays hit
        reach = int(getattr(give_up, "rim_reach", 1))
        near = _next_to(rest, given_up, index, texels, gr, gc, r_base, reach)
        if near.size:
            rays = classical(near)
            d = near[rays.hit[near]]
            store.values[d], store.valid[d] = rays.values[d], True  # the normal is the hybrid's
            store.interpolated[d] = given_up[d] = True
            side[d] = reach
            rim_n = int(d.size)
            rest = np.flatnonzero(~store.evaluated & ~store.interpolated)
    run(rest)
    n_eval = int(store.evaluated.sum())
    return {
        "values": store.values,
        "normals": store.normals,
        "valid": store.valid,
        "colors": store.colors,
        "evaluated": store.evaluated,
        "interpolated": store.interpolated,
        "decide": store.evaluated | decide,
        "given_up": given_up,
        "side": side,
        "stats": {"samples": m, "evaluated": n_eval, "interpolated": int(store.interpolated.sum()),
                  "face_nodes": face_stats["nodes"], "face_interpolated": face_stats["interpolated"],
                  "face_cells": face_stats["accepted"],
                  "cells_accepted": {str(k): v for k, v in sorted(levels.items(), reverse=True)},
                  "cells_quadratic": {str(k): v for k, v in sorted(quadratic.items(), reverse=True)},
                  "cells_given_up": {str(k): v for k, v in sorted(given_cells.items(), reverse=True)},
                  "cells_source_detail": {str(k): v for k, v in sorted(sourced_cells.items(), reverse=True) if v},
                  "cells_source_split": {str(k): v for k, v in sorted(split_cells.items(), reverse=True)},
                  "given_up": int(given_up.sum()), "rim": rim_n,
                  "evaluated_outside_cells": int(rest.size), "evaluation_calls": store.calls},
    }


def _source_detail(classical: Callable, flat_f: np.ndarray, points: np.ndarray, nodes: np.ndarray,
                   opt: AdaptiveOptions, dtype: torch.dtype) -> np.ndarray:
    """(P,) bool: of the cells with 3×3 ``nodes`` (P, 9) sample indices, those whose classical rays hit the source at
    every node and whose source normals there fail the bilinear test (:func:`_surplus_ok`, on the normals alone:
    ``flat_f`` is (M,) zeros). ``classical``: (sample indices (n,)) → the band's rays, (M,) ``hit`` and (M, 3)
    ``normals`` (unit), valid at those samples and every one cast before (each cast once)."""
    mark = np.zeros(len(flat_f), bool)  # each node once (a mask, not np.unique: no sort)
    mark[nodes.reshape(-1)] = True
    rays = classical(np.flatnonzero(mark))
    source = _Store(values=flat_f, normals=rays.normals, valid=rays.hit)
    return rays.hit[nodes].all(axis=1) & ~_surplus_ok(source, points, nodes, opt, dtype)


def _next_to(candidates: np.ndarray, given_up: np.ndarray, index: np.ndarray, texels, gr: np.ndarray,
             gc: np.ndarray, r_base: int, reach: int) -> np.ndarray:
    """Those of ``candidates`` (sample indices) within ``reach`` sample-grid positions (a square) of a given-up
    sample (``given_up`` (M,) bool): on the grid at their position, off it (border samples) at their texel's
    centre. ``index``: the band's (hg, wg) sample-grid image of sample indices (-1: none), its row 0 at grid row
    ``r_base``; ``gr``, ``gc``: the samples' grid positions (-1 off the grid)."""
    hg, wg = index.shape
    on = index >= 0
    image = np.zeros((hg, wg), dtype=bool)
    image[on] = given_up[index[on]]
    counts = _integral(image)
    s = int(texels.supersample)
    pix = np.asarray(texels.pixel, dtype=np.int64)[candidates]
    r = np.where(gr[candidates] >= 0, gr[candidates], pix[:, 0] * s + s // 2) - r_base
    c = np.where(gc[candidates] >= 0, gc[candidates], pix[:, 1] * s + s // 2)
    top, bottom = np.clip(r - reach, 0, hg), np.clip(r + reach + 1, 0, hg)
    left, right = np.clip(c - reach, 0, wg), np.clip(c + reach + 1, 0, wg)
    near = counts[bottom, right] - counts[top, right] - counts[bottom, left] + counts[top, left] > 0
    return candidates[near]


def _weights(corners: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """(4, n) bilinear weights of ``points`` (3, n) in the quads ``corners`` (3, 4, n) (corner order (0,0),
    (0,1), (1,0), (1,1); coordinates first, so that every operation runs on contiguous rows of n), from
    the points' coordinates (t, u) in the quads' least-squares parallelogram in 3-D; in the tensors' dtype.

    The coordinates are measured in space, not in UV: a chart's UV map stretches each face differently, so
    a field smooth on the surface has kinks along face edges in UV but not in these coordinates.
    """
    t, u, _ = _coordinates(corners, points)
    return torch.stack([(1 - t) * (1 - u), (1 - t) * u, t * (1 - u), t * u])


def _coordinates(corners: torch.Tensor, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(t, u, ok), each (n,): the coordinates of ``points`` (3, n) in the least-squares parallelogram of the
    quads ``corners`` (3, 4, n) (:func:`_weights`), clamped to :data:`_EXTRAPOLATE` outside; ``ok`` False
    where the quad is no parallelogram (a segment or a point: t = u = 0.5)."""
    c0, c1, c2, c3 = corners.unbind(1)
    e_t = 0.5 * (c2 - c0 + c3 - c1)
    e_u = 0.5 * (c1 - c0 + c3 - c2)
    d = points - 0.25 * (c0 + c1 + c2 + c3) + 0.5 * (e_t + e_u)
    a, b, c = (e_t * e_t).sum(0), (e_t * e_u).sum(0), (e_u * e_u).sum(0)
    r_t, r_u = (e_t * d).sum(0), (e_u * d).sum(0)
    det = a * c - b * b
    eps = torch.finfo(det.dtype).eps
    ok = det > 64 * eps * torch.clamp(a * c, min=DIRECTION_EPS)  # a parallelogram, not a segment or a point
    det = torch.where(ok, det, torch.ones_like(det))
    half = torch.full_like(det, 0.5)
    t = torch.where(ok, (c * r_t - b * r_u) / det, half).clamp_(-_EXTRAPOLATE, 1 + _EXTRAPOLATE)
    u = torch.where(ok, (a * r_u - b * r_t) / det, half).clamp_(-_EXTRAPOLATE, 1 + _EXTRAPOLATE)
    return t, u, ok


#: How far outside its quad (in quad sides) a sample's spatial coordinates may reach before they are clamped.
_EXTRAPOLATE = 0.5


def _pack(store: "_Store", points: np.ndarray, rows: np.ndarray | None, dtype: torch.dtype) -> torch.Tensor:
    """(7 + C, n) tensor of ``dtype``: point (3), unit normal (3), value (1) and colour (C) of the samples
    ``rows`` (None: all), one column per sample: a cell's corners are gathered in one pass, and the
    arithmetic runs on contiguous rows."""
    cols = [points, store.normals, store.values[:, None]] + ([] if store.colors is None else [store.colors])
    sel = None if rows is None else torch.from_numpy(np.ascontiguousarray(rows))
    out = torch.empty((sum(c.shape[1] for c in cols), len(points) if sel is None else len(sel)), dtype=dtype)
    at = 0
    for c in cols:
        t = torch.from_numpy(c)
        out[at: at + c.shape[1]] = (t if sel is None else t.index_select(0, sel)).t()
        at += c.shape[1]
    return out


def _interp(packed: torch.Tensor, corners: torch.Tensor, at: torch.Tensor) -> tuple:
    """Unit normals (n, 3), values (n,) and colours (n, C) or None interpolated at the columns ``at`` (n,)
    of ``packed`` (:func:`_pack`) from its columns ``corners`` (n, 4), with the spatial weights of
    :func:`_weights`.

    f is interpolated from each corner's first-order extrapolation ``f_i + n_i · (p − p_i)`` (an SDF's
    gradient is its unit normal): the sample points lie on flat faces that bend at edges, where f of the
    points kinks but f of space does not."""
    n = len(corners)
    g = packed.index_select(1, corners.t().reshape(-1)).view(packed.shape[0], 4, n)  # (7 + C, 4, n)
    pc, nc = g[:3], g[3:6]
    pa = packed[:3].index_select(1, at)  # (3, n)
    w = _weights(pc, pa)  # (4, n)
    nrm = (w * nc).sum(1)  # (3, n)
    nrm /= (nrm * nrm).sum(0).sqrt_().clamp_(min=DIRECTION_EPS)  # not vector_norm: slow across rows
    val = (w * (g[6] + ((pa[:, None, :] - pc) * nc).sum(0))).sum(0)
    col = None if packed.shape[0] == 7 else (w * g[7:]).sum(1).t()
    return nrm.t(), val, col


def _surplus_ok(store: _Store, points: np.ndarray, nodes: np.ndarray, opt: AdaptiveOptions,
                dtype: torch.dtype) -> np.ndarray:
    """(P,) bool: the cells whose 3×3 ``nodes`` (P, 9) sample indices pass every field's tolerance: the
    midpoints' and centre's values against their interpolation from the cell's four corners (angles as chord
    lengths |a − b| = 2·sin(θ/2), exact near 0° in float32 too). By the C kernel in float64 where it builds, else in
    ``dtype`` by torch."""
    chord = 2.0 * np.sin(np.radians(ADAPTIVE_SAFETY * opt.tolerance_deg) / 2.0)
    value_tol, color_tol = ADAPTIVE_SAFETY * opt.value_tol, ADAPTIVE_SAFETY * opt.color_tol
    lib = KERNEL.lib()
    if lib is not None:
        pts, colors, n_colors = _native_fields(store, points)
        cells = np.ascontiguousarray(nodes, dtype=np.int64)
        out = np.zeros(len(cells), dtype=np.uint8)
        lib.nb_surplus_test(cells.ctypes.data, len(cells), pts.ctypes.data, store.normals.ctypes.data,
                            store.values.ctypes.data, colors, n_colors, store.valid.view(np.uint8).ctypes.data,
                            float(chord), float(value_tol), float(color_tol), float(_EXTRAPOLATE),
                            float(DIRECTION_EPS), out.ctypes.data, threads())
        return out.view(bool)
    ok = store.valid[nodes].all(axis=1)
    packed = _pack(store, points, nodes.reshape(-1), dtype)
    local = torch.arange(nodes.size).view(nodes.shape)
    mids = local[:, [1, 3, 4, 5, 7]].t().reshape(-1)  # (5P,): the five non-corner nodes, one after another
    nrm, val, col = _interp(packed, local[:, [0, 2, 6, 8]].repeat(5, 1), mids)
    own = packed.index_select(1, mids)
    diff = nrm.t() - own[3:6]
    good = (diff * diff).sum(0) <= chord * chord
    good &= (val - own[6]).abs() <= value_tol
    if col is not None:
        good &= ((col.t() - own[7:]).abs() <= color_tol).all(dim=0)
    return ok & good.view(5, -1).all(dim=0).numpy()


def _colour_first(r0: np.ndarray, c0: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The cells (top-left positions ``r0``, ``c0``, side ``k``) with those whose (r0 / k + c0 / k) is even first (the
    black ones of a checkerboard of cells, which share no sample but nodes with each other), each colour in its own
    order: the edge two cells share goes to the black one, in any order of the cells."""
    order = np.argsort((np.asarray(r0) // k + np.asarray(c0) // k) & 1, kind="stable")
    return np.asarray(r0)[order], np.asarray(c0)[order]


def _interpolate(store: _Store, packed: torch.Tensor, index: np.ndarray, r0: np.ndarray, c0: np.ndarray,
                 k: int) -> None:
    """Interpolation from the 3×3 nodes of accepted cells (side ``k``) to their other samples, each from the
    four nodes of its quarter of the cell (:func:`_weights`); ``packed``: :func:`_pack` of every sample. A sample
    two cells share takes the interpolation of the cell :func:`_colour_first` puts first, as the C kernel does."""
    r0, c0 = _colour_first(r0, c0, k)
    h = k // 2
    d = np.arange(k + 1)
    dr, dc = (a.reshape(-1) for a in np.meshgrid(d, d, indexing="ij"))
    other = (dr % h != 0) | (dc % h != 0)  # the nodes themselves were evaluated
    dr, dc = dr[other], dc[other]
    a, b = np.minimum(dr // h, 1), np.minimum(dc // h, 1)  # quarter of each offset
    wg = index.shape[1]
    flat_index = index.reshape(-1)  # flat positions: 1-D takes, several times faster than 2-D fancy indexing
    offset = dr * wg + dc  # (O,)
    corner_offset = (np.stack([a, a, a + 1, a + 1], axis=1) * wg + np.stack([b, b + 1, b, b + 1], axis=1)) * h
    done = store.evaluated | store.interpolated
    per = max(1, _INTERP_CHUNK // len(dr))
    for s in range(0, len(r0), per):
        base = r0[s: s + per] * wg + c0[s: s + per]
        idx = np.take(flat_index, (base[:, None] + offset).reshape(-1))  # (P·O,)
        fresh = np.flatnonzero(~np.take(done, idx))
        if fresh.size == 0:
            continue
        # a sample on the edge two cells share takes the first cell's interpolation, as the C kernel does
        fresh = fresh[np.sort(np.unique(idx[fresh], return_index=True)[1])]
        cell, off = np.divmod(fresh, len(dr))
        corners = np.take(flat_index, base[cell, None] + corner_offset[off])  # (n, 4)
        idx = idx[fresh]
        nrm, val, col = _interp(packed, torch.from_numpy(corners), torch.from_numpy(idx))
        store.normals[idx] = nrm.double().numpy()
        store.values[idx] = val.double().numpy()
        store.valid[idx] = True
        if col is not None:
            store.colors[idx] = col.double().numpy()
        store.interpolated[idx] = True
        done[idx] = True


def _interpolate_native(lib, store: _Store, points: np.ndarray, index: np.ndarray, r0: np.ndarray, c0: np.ndarray,
                        k: int, *, quadratic: bool = False) -> None:
    """:func:`_interpolate` (``quadratic``: :func:`_interpolate_quadratic`) by the C kernel (adaptive.c), in float64,
    on the store's arrays in place (all float64 and contiguous, as :func:`adaptive_evaluate` makes them)."""
    pts, colors, n_colors = _native_fields(store, points)
    flat = np.ascontiguousarray(index, dtype=np.int64).reshape(-1)
    r0, c0 = np.ascontiguousarray(r0, dtype=np.int64), np.ascontiguousarray(c0, dtype=np.int64)
    done = (store.evaluated | store.interpolated).view(np.uint8)
    interp, valid = store.interpolated.view(np.uint8), store.valid.view(np.uint8)
    fn = lib.nb_interp_cells_quadratic if quadratic else lib.nb_interp_cells
    fn(flat.ctypes.data, index.shape[1], r0.ctypes.data, c0.ctypes.data, len(r0), int(k), pts.ctypes.data,
       store.normals.ctypes.data, store.values.ctypes.data, colors, n_colors, done.ctypes.data, interp.ctypes.data,
       valid.ctypes.data, float(_EXTRAPOLATE), float(DIRECTION_EPS), threads())


def _native_fields(store: _Store, points: np.ndarray) -> tuple[np.ndarray, int | None, int]:
    """What the C kernels read of a band: its points (float64, contiguous), the address of the store's colours (made
    contiguous in the store; None without colours) and their channels."""
    if store.colors is not None and not store.colors.flags.c_contiguous:
        store.colors = np.ascontiguousarray(store.colors)
    colors = None if store.colors is None else store.colors.ctypes.data
    return np.ascontiguousarray(points, dtype=np.float64), colors, 0 if store.colors is None else store.colors.shape[1]


#: Smallest side of a cell that may be accepted with quadratic interpolation (:func:`_quadratic_ok`): its test
#: points, the quarters' centres, are the next level's nodes (side 8 and more) or samples a side-4 cell that
#: fails evaluates anyway, so a cell that fails costs no evaluation.
_QUADRATIC_SIDE = 4

#: The quadratic test's tolerances as a share of the bilinear test's: it checks four points, not five, so it
#: asks for more (on a fitted (256,3) Spot SDF at 2048², half kept the interpolation's largest error against a
#: full evaluation where it was without the quadratic pass, 0.20°, and 1 let it grow to 0.32°).
_QUADRATIC_SAFETY = 0.5

#: The quarters' centres of a cell as (row, col) multiples of a quarter of its side.
_QUARTERS = np.array([(1, 1), (1, 3), (3, 1), (3, 3)], dtype=np.int64)


def _lagrange(t: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """(..., 9): the tensor-product quadratic Lagrange basis on the nodes {0, ½, 1}² at (t, u) (...,), in the
    order of :data:`_NODES` (row index with t, column index with u)."""
    def basis(x):
        return torch.stack([2 * (x - 0.5) * (x - 1), -4 * x * (x - 1), 2 * x * (x - 0.5)], dim=-1)

    bt, bu = basis(t), basis(u)
    return (bt[..., :, None] * bu[..., None, :]).flatten(-2)


def _quadratic_weights(node_points: torch.Tensor, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(w, ok): weights (n, m, 9) of ``points`` (3, n, m) from the 9 nodes of their cells ``node_points``
    (3, 9, n) (:data:`_NODES` order): the quadratic polynomial in the cells' spatial coordinates (those of
    :func:`_coordinates`, from the cells' corners) through the nodes' values. The basis is the Lagrange basis
    on the ideal nodes {0, ½, 1}², corrected by the inverse of its values at the actual nodes (near the
    identity for a cell that is near a parallelogram), so a quadratic field is reproduced exactly. ``ok`` (n,)
    False for a cell that is no parallelogram or whose nodes do not fix a quadratic."""
    n, m = points.shape[1], points.shape[2]
    corners = node_points[:, [0, 2, 6, 8]]  # (3, 4, n)
    nt, nu, ok = _coordinates(corners.repeat_interleave(9, dim=2),
                              node_points.permute(0, 2, 1).reshape(3, -1))  # node by node, cell-major
    vander = _lagrange(nt.view(n, 9).double(), nu.view(n, 9).double())  # (n, 9 nodes, 9 basis)
    inv, info = torch.linalg.inv_ex(vander)
    good = (info == 0) & torch.isfinite(inv).all(dim=(1, 2)) & ok.view(n, 9).all(dim=1)
    inv = torch.where(good[:, None, None], inv, torch.zeros_like(inv)).to(points.dtype)
    pt, pu, _ = _coordinates(corners.repeat_interleave(m, dim=2), points.permute(0, 1, 2).reshape(3, -1))
    basis = _lagrange(pt.view(n, m), pu.view(n, m))  # (n, m, 9)
    return torch.bmm(basis, inv), good


def _quadratic_values(g: torch.Tensor, w: torch.Tensor, pa: torch.Tensor) -> tuple:
    """Unit normals (3, n, m), values (n, m) and colours (C, n, m) or None at the points ``pa`` (3, n, m) from
    the packed columns of their cells' 9 nodes ``g`` (7 + C, 9, n) with weights ``w`` (n, m, 9); f from each
    node's first-order extrapolation, as :func:`_interp` does."""
    wt = w.permute(2, 0, 1)  # (9, n, m)
    pc, nc = g[:3, :, :, None], g[3:6, :, :, None]  # (3, 9, n, 1)
    nrm = (wt * nc).sum(1)  # (3, n, m)
    nrm /= (nrm * nrm).sum(0).sqrt_().clamp_(min=DIRECTION_EPS)
    val = (wt * (g[6, :, :, None] + ((pa[:, None] - pc) * nc).sum(0))).sum(0)
    col = None if g.shape[0] == 7 else (wt * g[7:, :, :, None]).sum(1)
    return nrm, val, col


def _quadratic_ok(store: _Store, points: np.ndarray, nodes: np.ndarray, tests: np.ndarray, opt: AdaptiveOptions,
                  dtype: torch.dtype) -> np.ndarray:
    """(P,) bool: the cells whose quarters' centres ``tests`` (P, 4) (sample indices, all evaluated) lie within
    every field's tolerance (as :func:`_surplus_ok` tests) of the quadratic interpolation from the cells' 9
    ``nodes`` (P, 9) (:func:`_quadratic_weights`). By the C kernel in float64 where it builds, else in ``dtype``
    by torch."""
    safety = _QUADRATIC_SAFETY * ADAPTIVE_SAFETY
    chord = 2.0 * np.sin(np.radians(safety * opt.tolerance_deg) / 2.0)
    value_tol, color_tol = safety * opt.value_tol, safety * opt.color_tol
    lib = KERNEL.lib()
    if lib is not None:
        return _quadratic_ok_native(lib, store, points, nodes, tests, chord, value_tol, color_tol)
    ok = store.valid[nodes].all(axis=1) & store.valid[tests].all(axis=1)
    n = len(nodes)
    g = _pack(store, points, nodes.T.reshape(-1), dtype).view(-1, 9, n)  # (7 + C, 9, P)
    own = _pack(store, points, tests.T.reshape(-1), dtype).view(-1, 4, n).permute(0, 2, 1)  # (7 + C, P, 4)
    w, good = _quadratic_weights(g[:3], own[:3])
    nrm, val, col = _quadratic_values(g, w, own[:3])
    diff = nrm - own[3:6]
    fine = ((diff * diff).sum(0) <= chord * chord) & ((val - own[6]).abs() <= value_tol)  # (P, 4)
    if col is not None:
        fine &= ((col - own[7:]).abs() <= color_tol).all(dim=0)
    return ok & (good & fine.all(dim=1)).numpy()


def _quadratic_ok_native(lib, store: _Store, points: np.ndarray, nodes: np.ndarray, tests: np.ndarray, chord: float,
                         value_tol: float, color_tol: float) -> np.ndarray:
    """:func:`_quadratic_ok` by the C kernel (adaptive.c), in float64 on the store's arrays."""
    pts, colors, n_colors = _native_fields(store, points)
    nodes = np.ascontiguousarray(nodes, dtype=np.int64)
    tests = np.ascontiguousarray(tests, dtype=np.int64)
    ok = np.zeros(len(nodes), dtype=np.uint8)
    lib.nb_quadratic_test(nodes.ctypes.data, tests.ctypes.data, len(nodes), pts.ctypes.data, store.normals.ctypes.data,
                          store.values.ctypes.data, colors, n_colors, store.valid.view(np.uint8).ctypes.data,
                          float(chord), float(value_tol), float(color_tol), float(_EXTRAPOLATE), float(DIRECTION_EPS),
                          ok.ctypes.data, threads())
    return ok.view(bool)


def _interpolate_quadratic(store: _Store, packed: torch.Tensor, index: np.ndarray, r0: np.ndarray, c0: np.ndarray,
                           k: int) -> None:
    """Interpolation from the 9 nodes of cells (side ``k``) accepted by :func:`_quadratic_ok` to their other
    samples (:func:`_quadratic_weights`); ``packed``: :func:`_pack` of every sample (shared samples as
    :func:`_interpolate`)."""
    r0, c0 = _colour_first(r0, c0, k)
    h = k // 2
    d = np.arange(k + 1)
    dr, dc = (a.reshape(-1) for a in np.meshgrid(d, d, indexing="ij"))
    wg = index.shape[1]
    flat_index = index.reshape(-1)
    offset = dr * wg + dc  # (O,)
    node_offset = h * (_NODES[:, 0] * wg + _NODES[:, 1])  # (9,)
    done = store.evaluated | store.interpolated
    per = max(1, _INTERP_CHUNK // len(dr))
    for s in range(0, len(r0), per):
        base = r0[s: s + per] * wg + c0[s: s + per]
        nodes = np.take(flat_index, base[:, None] + node_offset)  # (n, 9)
        idx = np.take(flat_index, base[:, None] + offset)  # (n, O)
        g = packed.index_select(1, torch.from_numpy(np.ascontiguousarray(nodes.T).reshape(-1))).view(
            packed.shape[0], 9, len(base))
        pa = packed[:3].index_select(1, torch.from_numpy(idx.reshape(-1))).view(3, len(base), len(dr))
        w, good = _quadratic_weights(g[:3], pa)
        nrm, val, col = _quadratic_values(g, w, pa)
        fresh = ~np.take(done, idx) & good.numpy()[:, None]
        rows, cols = np.nonzero(fresh)
        first = np.sort(np.unique(idx[rows, cols], return_index=True)[1])  # a shared edge: the first cell's, as in C
        rows, cols = rows[first], cols[first]
        at = idx[rows, cols]
        sel_r, sel_c = torch.from_numpy(rows), torch.from_numpy(cols)
        store.normals[at] = nrm[:, sel_r, sel_c].t().double().numpy()
        store.values[at] = val[sel_r, sel_c].double().numpy()
        store.valid[at] = True
        if col is not None:
            store.colors[at] = col[:, sel_r, sel_c].t().double().numpy()
        store.interpolated[at] = True
        done[at] = True
