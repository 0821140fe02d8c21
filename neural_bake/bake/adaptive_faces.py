"""Adaptive evaluation inside the coarse mesh's faces: the samples the texel lattice could not interpolate.

The lattice of :mod:`neural_bake.bake.adaptive` interpolates inside squares of the sample grid that one chart
fills. What it leaves (a band along every chart's border, the samples placed at a triangle's closest point,
the texels around the mesh's vertices) grows with the number of charts: on a scan decimated to a few thousand
faces it is a quarter of all samples. Those samples all lie inside faces, and a face is flat: the fields along
it are smooth, whatever the chart around it does. So they are interpolated per face.

A face is split into ``m × m`` sub-triangles in its barycentric coordinates (``m`` a power of two; the first
``m`` makes a sub-triangle's longest edge at most :data:`FACE_START_SIDE` sample-grid positions). For a
sub-triangle holding at least :data:`FACE_MIN_SAMPLES` of the samples, the fields are evaluated at its three
corners and three edge midpoints (points of the face, not samples: shared with its neighbours, evaluated
once), and it is accepted when each midpoint's values lie within ``ADAPTIVE_SAFETY`` times the tolerances of
what its edge's two corners predict (the same hierarchical surplus as the lattice's). Its samples are then
interpolated linearly from the three nodes of the quarter (of the four the midpoints cut) they lie in, normals
renormalised, f from each node's first-order extrapolation. A sub-triangle that fails splits into its four
quarters, down to an edge of :data:`FACE_MIN_SIDE` positions; samples left in smaller or emptier
sub-triangles are evaluated.

Points of faces are not samples, so evaluating them for a sub-triangle that then fails is pure cost. A
sub-triangle is tried only when it holds at least twice as many samples as it has nodes not yet evaluated,
and each level first tests every :data:`FACE_PROBE_STRIDE`-th sub-triangle: when the samples interpolated so
far are fewer than the points evaluated, the pass stops.

The hybrid decides at evaluated samples; an accepted sub-triangle has none of its own, so the samples closest
to its corners and to its centre are returned as its decision points (``decide``), at most
:data:`FACE_START_SIDE` positions from any of its samples, within the hybrid's reach.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..constants import ADAPTIVE_SAFETY, DIRECTION_EPS

__all__ = ["FaceGeometry", "face_geometry", "face_pass", "group_argmax", "FACE_START_SIDE", "FACE_MIN_SIDE",
           "FACE_MIN_SAMPLES"]

#: Longest edge (sample-grid positions) of a face's first sub-triangles; at most the hybrid's reach.
FACE_START_SIDE = 16.0
#: A sub-triangle whose longest edge is shorter than this (positions) is not split again: its samples are evaluated.
FACE_MIN_SIDE = 3.0
#: A sub-triangle is interpolated only when it holds at least this many samples (it costs up to six evaluations).
FACE_MIN_SAMPLES = 8

#: Each level of the pass first tests every this-many-th sub-triangle, and stops when, over the whole pass, the
#: samples interpolated are fewer than the evaluations made at points of faces.
FACE_PROBE_STRIDE = 8

#: Faces a pass handles: the packed keys of nodes and sub-triangles hold a face index below 2^21 (a larger
#: mesh's leftover samples are evaluated).
_MAX_FACES = (1 << 21) - 1

#: Resolution of the barycentric lattice the nodes are keyed on (2^20 steps per face edge).
_RES_BITS = 20


@dataclass(frozen=True)
class FaceGeometry:
    """What the face pass needs of the coarse mesh: its faces' corner points and their sizes on the sample grid."""

    corners: np.ndarray
    """(F, 3, 3) float64 corner points of each face (the frame of the texel samples' points)."""
    side: np.ndarray
    """(F,) float64 longest edge of each face's UV triangle, in sample-grid positions."""


def face_geometry(mesh, size: tuple[int, int], supersample: int) -> FaceGeometry:
    """:class:`FaceGeometry` of a UV-mapped ``mesh`` baked at ``size`` (H, W) with ``supersample``."""
    h, w = size
    s = int(supersample)
    corners = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces, dtype=np.int64)]
    uv = np.asarray(mesh.uv, dtype=np.float64) * np.array([w * s, h * s], dtype=np.float64)  # (F, 3, 2)
    edges = uv - np.roll(uv, 1, axis=1)
    side = np.sqrt((edges * edges).sum(axis=2)).max(axis=1)
    return FaceGeometry(corners=corners, side=side)


class _Nodes:
    """Field values at points of the faces keyed by (face, i, j) on the barycentric lattice, each evaluated once.
    The values are appended in evaluation order (a node's position never moves); ``_sorted`` and ``_where``
    (the keys in order and their positions) answer lookups."""

    def __init__(self, geometry: FaceGeometry, evaluate_points: Callable[[np.ndarray, np.ndarray], dict]):
        self.geometry = geometry
        self.evaluate_points = evaluate_points
        self._sorted = np.zeros(0, dtype=np.int64)
        self._where = np.zeros(0, dtype=np.int64)
        self.points = np.zeros((0, 3))
        self.values = np.zeros(0)
        self.normals = np.zeros((0, 3))
        self.valid = np.zeros(0, dtype=bool)
        self.colors: np.ndarray | None = None

    @property
    def count(self) -> int:
        """Points evaluated."""
        return len(self.values)

    @staticmethod
    def key(face: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return (face << (2 * (_RES_BITS + 1))) | (i << (_RES_BITS + 1)) | j

    def _find(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(known, position) of ``keys`` (any shape); the position is meaningless where not known."""
        if not len(self._sorted):
            return np.zeros(keys.shape, dtype=bool), np.zeros(keys.shape, dtype=np.int64)
        at = np.minimum(np.searchsorted(self._sorted, keys), len(self._sorted) - 1)
        return self._sorted[at] == keys, self._where[at]

    def known(self, keys: np.ndarray) -> np.ndarray:
        """Which of ``keys`` (any shape) are evaluated already."""
        return self._find(keys)[0]

    def get(self, keys: np.ndarray) -> np.ndarray:
        """Positions in the store of the nodes ``keys`` (any shape), evaluating the new ones."""
        known, _ = self._find(keys)
        new = np.unique(keys[~known])
        if new.size:
            self._add(new)
        return self._find(keys)[1]

    def _add(self, new: np.ndarray) -> None:
        mask = (1 << (_RES_BITS + 1)) - 1
        face = new >> (2 * (_RES_BITS + 1))
        b1 = ((new >> (_RES_BITS + 1)) & mask).astype(np.float64) / (1 << _RES_BITS)
        b2 = (new & mask).astype(np.float64) / (1 << _RES_BITS)
        c = self.geometry.corners[face]
        pts = c[:, 0] + b1[:, None] * (c[:, 1] - c[:, 0]) + b2[:, None] * (c[:, 2] - c[:, 0])
        ev = self.evaluate_points(pts, face)
        nrm = np.asarray(ev["normals"], dtype=np.float64)
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.divide(nrm, length, out=np.zeros_like(nrm), where=length > DIRECTION_EPS)
        start = self.count
        keys = np.concatenate([self._sorted, new])
        where = np.concatenate([self._where, start + np.arange(len(new))])
        order = np.argsort(keys, kind="stable")
        self._sorted, self._where = keys[order], where[order]
        self.points = np.concatenate([self.points, pts])
        self.values = np.concatenate([self.values, np.asarray(ev["values"], dtype=np.float64)])
        self.normals = np.concatenate([self.normals, nrm])
        self.valid = np.concatenate([self.valid, np.asarray(ev["valid"], dtype=bool)])
        col = ev.get("colors")
        if col is not None:
            col = np.asarray(col, dtype=np.float64)
            old = self.colors if self.colors is not None else np.zeros((start, col.shape[1]))
            self.colors = np.concatenate([old, col])


def group_argmax(groups: np.ndarray, scores: list[np.ndarray]) -> list[np.ndarray]:
    """For each score array (n,), the position of its largest value within every group of equal ``groups`` (n,)
    ints, the first such position where several tie: ``np.lexsort((-score, groups))``'s first element per group,
    from one stable sort of the groups shared by every score. Positions in the order of the groups' values."""
    order = np.argsort(groups, kind="stable")
    g = groups[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]]) if len(g) else np.zeros(0, dtype=np.int64)
    member = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(g)]))
    out = []
    for score in scores:
        sc = score[order]
        if not len(sc):
            out.append(np.zeros(0, dtype=np.int64))
            continue
        hit = np.flatnonzero(sc == np.maximum.reduceat(sc, starts)[member])
        first = hit[np.r_[True, member[hit][1:] != member[hit][:-1]]]
        out.append(order[first])
    return out


def _blend(nodes: _Nodes, at: np.ndarray, weights: np.ndarray, points: np.ndarray):
    """Normals (n, 3, unit), values (n,) and colours (n, C) or None at ``points`` (n, 3) from the nodes ``at``
    (n, K) with weights (n, K) summing to 1; f from each node's first-order extrapolation."""
    nrm = np.einsum("nk,nkd->nd", weights, nodes.normals[at])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), DIRECTION_EPS)
    ext = nodes.values[at] + np.einsum("nkd,nkd->nk", points[:, None, :] - nodes.points[at], nodes.normals[at])
    val = (weights * ext).sum(axis=1)
    col = None if nodes.colors is None else np.einsum("nk,nkc->nc", weights, nodes.colors[at])
    return nrm, val, col


def face_pass(
    idx: np.ndarray,
    face: np.ndarray,
    bary: np.ndarray,
    points: np.ndarray,
    geometry: FaceGeometry,
    evaluate_points: Callable[[np.ndarray, np.ndarray], dict],
    *,
    tolerance_deg: float,
    value_tol: float,
    color_tol: float,
) -> dict:
    """Interpolate what it can of the samples ``idx`` (n,) (module docstring).

    ``face`` (n,), ``bary`` (n, 3) and ``points`` (n, 3): each sample's face, barycentric coordinates and point;
    ``evaluate_points``: (points (k, 3), their faces (k,)) → ``{"values", "normals", "valid", "colors" (or
    None)}`` (the faces for fields that read the mesh's normal there).

    Returns ``{"done": (n,) bool interpolated, "normals", "values", "colors" (rows of the done samples; None
    without colours), "decide": (n,) bool decision points, "nodes": evaluations made, "accepted":
    sub-triangles accepted}``.
    """
    n = len(idx)
    out_nrm, out_val = np.zeros((n, 3)), np.zeros(n)
    out_col: np.ndarray | None = None
    done = np.zeros(n, dtype=bool)
    decide = np.zeros(n, dtype=bool)
    nodes = _Nodes(geometry, evaluate_points)
    accepted = saved = 0
    if n == 0 or len(geometry.side) > _MAX_FACES:  # more faces than the packed keys hold: evaluated instead
        return {"done": done, "normals": out_nrm, "values": out_val, "colors": None, "decide": decide, "nodes": 0,
                "accepted": 0}
    chord = 2.0 * np.sin(np.radians(ADAPTIVE_SAFETY * tolerance_deg) / 2.0)
    vtol, ctol = ADAPTIVE_SAFETY * value_tol, ADAPTIVE_SAFETY * color_tol
    side = geometry.side[face]
    level = np.maximum(0, np.ceil(np.log2(np.maximum(side, 1e-12) / FACE_START_SIDE))).astype(np.int64)
    level = np.minimum(level, _RES_BITS - 2)
    active = np.flatnonzero(side / (1 << level) >= FACE_MIN_SIDE)
    b = np.clip(np.asarray(bary, dtype=np.float64), 0.0, 1.0)
    while active.size:
        lv = level[active]
        m = (1 << lv).astype(np.float64)
        x, y = b[active, 1] * m, b[active, 2] * m
        i = np.minimum(np.floor(x), m - 1)
        j = np.minimum(np.floor(y), m - 1 - i)
        fx, fy = x - i, y - j
        upper = (fx + fy > 1.0) & (i + j < m - 1)
        # (face, level, i, j, upper) of each sample's sub-triangle, packed in one int64 (i, j < 2^18)
        key = (((face[active] << 5) | lv) << 37) | (i.astype(np.int64) << 19) | (j.astype(np.int64) << 1) \
            | upper.astype(np.int64)
        tri, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        inverse = inverse.reshape(-1)
        big = counts >= FACE_MIN_SAMPLES
        # the six nodes of each sub-triangle on the lattice of twice its resolution: corners A, B, C, then
        # the midpoints of BC, CA, AB
        f_t, l_t = tri >> 42, (tri >> 37) & 31
        i_t, j_t, u_t = (tri >> 19) & ((1 << 18) - 1), (tri >> 1) & ((1 << 18) - 1), tri & 1
        scale = np.left_shift(1, _RES_BITS - 1 - l_t)  # lattice steps per half sub-triangle edge
        ci, cj = 2 * i_t, 2 * j_t
        ai = np.where(u_t == 1, ci + 2, ci); aj = np.where(u_t == 1, cj + 2, cj)  # noqa: E702
        bi = np.where(u_t == 1, ci, ci + 2); bj = np.where(u_t == 1, cj + 2, cj)  # noqa: E702
        di = np.where(u_t == 1, ci + 2, ci); dj = np.where(u_t == 1, cj, cj + 2)  # noqa: E702 (corner C)
        ni = np.stack([ai, bi, di, (bi + di) // 2, (di + ai) // 2, (ai + bi) // 2], axis=1) * scale[:, None]
        nj = np.stack([aj, bj, dj, (bj + dj) // 2, (dj + aj) // 2, (aj + bj) // 2], axis=1) * scale[:, None]
        keys = nodes.key(np.repeat(f_t[:, None], 6, axis=1), ni, nj)
        # worth its evaluations: a sub-triangle holds at least twice as many samples as it has nodes not yet
        # evaluated (its neighbours share some), so that even a failure costs less than it could save
        big &= counts >= 2 * (~nodes.known(keys)).sum(axis=1)
        ok = np.zeros(len(tri), dtype=bool)
        at = np.zeros((len(tri), 6), dtype=np.int64)

        def test(sel: np.ndarray) -> None:
            at[sel] = nodes.get(keys[sel])
            a = at[sel]
            good = nodes.valid[a].all(axis=1)
            for mid, (p, q) in zip((3, 4, 5), ((1, 2), (2, 0), (0, 1))):
                pts = nodes.points[a[:, mid]]
                nrm, val, col = _blend(nodes, a[:, [p, q]], np.full((len(a), 2), 0.5), pts)
                d = nrm - nodes.normals[a[:, mid]]
                good &= (d * d).sum(axis=1) <= chord * chord
                good &= np.abs(val - nodes.values[a[:, mid]]) <= vtol
                if col is not None:
                    good &= (np.abs(col - nodes.colors[a[:, mid]]) <= ctol).all(axis=1)
            ok[sel] = good

        t_big = np.flatnonzero(big)
        if t_big.size:
            # a probe first (every FACE_PROBE_STRIDE-th sub-triangle): where the fields vary too fast for
            # sub-triangles this size, the evaluations at points of faces would cost more than they save;
            # then the pass stops, having spent at most the probe's evaluations
            probe = t_big[::FACE_PROBE_STRIDE]
            test(probe)
            saved += int(counts[probe][ok[probe]].sum())
            if saved < nodes.count:
                big[:] = False
            else:
                rest_t = np.setdiff1d(t_big, probe, assume_unique=True)
                if rest_t.size:
                    test(rest_t)
                    saved += int(counts[rest_t][ok[rest_t]].sum())
        accepted += int(ok.sum())
        take = ok[inverse]
        if take.any():
            s = active[take]
            t = inverse[take]
            # the quarter each sample lies in, and its three nodes (positions among the six) and weights
            # local barycentric coordinates (w, u, v) of A, B, C: p = A + u (B − A) + v (C − A), where B − A and
            # C − A are (1, 0) and (0, 1) on the lattice in a lower sub-triangle, (−1, 0) and (0, −1) in an upper
            u = np.where(upper[take], 1.0 - fx[take], fx[take])
            v = np.where(upper[take], 1.0 - fy[take], fy[take])
            w = 1.0 - u - v
            u2, v2, w2 = 2 * u, 2 * v, 2 * w
            q = np.full(len(s), 3)  # 0: at A, 1: at B, 2: at C, 3: the middle quarter
            q[w2 >= 1] = 0
            q[u2 >= 1] = 1
            q[v2 >= 1] = 2
            quarter_nodes = np.array([[0, 5, 4], [5, 1, 3], [4, 3, 2], [3, 4, 5]])
            qw = np.stack([
                np.stack([w2 - 1, u2, v2], axis=1),
                np.stack([w2, u2 - 1, v2], axis=1),
                np.stack([w2, u2, v2 - 1], axis=1),
                np.stack([1 - w2, 1 - u2, 1 - v2], axis=1),
            ])  # (4, k, 3): weights of the quarter's nodes in the order of quarter_nodes
            weights = qw[q, np.arange(len(s))]
            np.clip(weights, 0.0, None, out=weights)
            weights /= weights.sum(axis=1, keepdims=True)
            nidx = at[t[:, None], quarter_nodes[q]]
            nrm, val, col = _blend(nodes, nidx, weights, points[s])
            out_nrm[s], out_val[s] = nrm, val
            if col is not None:
                if out_col is None:
                    out_col = np.zeros((n, col.shape[1]))
                out_col[s] = col
            done[s] = True
            # decision points: per accepted sub-triangle, the samples closest to its corners and its centre
            for first in group_argmax(t, [w, u, v, -np.abs(u - 1 / 3) - np.abs(v - 1 / 3)]):
                decide[s[first]] = True
        # the failed sub-triangles' samples go one level finer while their sub-triangles stay large enough
        again = ~take & big[inverse]
        nxt = active[again]
        level[nxt] += 1
        active = nxt[(side[nxt] / (1 << level[nxt]) >= FACE_MIN_SIDE) & (level[nxt] <= _RES_BITS - 2)]
    return {"done": done, "normals": out_nrm, "values": out_val, "colors": out_col, "decide": decide,
            "nodes": nodes.count, "accepted": accepted}
