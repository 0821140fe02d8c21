"""Texel rasterisation: every covered texel centre of a UV layout -> its 3-D point and tangent frame."""

from __future__ import annotations

import ctypes
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import torch

from ..constants import (TEXEL_INSIDE_EPS, TEXEL_OVERLAP_EPS, TEXEL_SPAN_TOL, TEXEL_STRICT_EPS, UNDERFLOW_EPS,
                         UV_AREA_EPS, UV_FLAT_EDGE_EPS)
from ..errors import MeshError, NeuralBakeError, NeuralBakeWarning
from ..types import Mesh
from ..geometry import vertex_normals
from ..nets.native import Kernel
from .tangents import tangent_frames, vertex_uv

__all__ = ["TexelSet", "rasterize_texels", "iter_texels", "texel_grid_points", "texel_centres", "texel_counts",
           "face_uv_areas", "kernel_status", "ENV_SWITCH"]

#: Candidate (sample, face) pairs processed at once; bounds the working memory (~40 bytes x this x 10).
_MAX_CANDIDATES = 1 << 21

#: 0/off/false: the numpy rasteriser even where the C kernel (texels.c) builds (A/B checks).
ENV_SWITCH = "NEURAL_BAKE_NATIVE_RASTER"


def _declare(lib) -> None:
    p, i64, f64 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
    lib.nb_sample_owners.argtypes = [p, p, p, i64, p, p, i64, i64, f64, f64, f64, f64, p, p]
    lib.nb_sample_owners.restype = None
    lib.nb_collect_hits.argtypes = [p, p, p, i64, i64, i64, i64, p, p, p, p]
    lib.nb_collect_hits.restype = i64
    lib.nb_border_hits.argtypes = [p, p, p, p, i64, p, p, p, p, i64, i64, p, f64, f64, p, p, p]
    lib.nb_border_hits.restype = None
    lib.nb_interpolate_corners.argtypes = [p, i64, p, p, i64, f64, p, p, p, p]
    lib.nb_interpolate_corners.restype = None
    lib.nb_signed_cross.argtypes = [p, p, p, i64, p]
    lib.nb_signed_cross.restype = None


#: The C kernel (texels.c, :class:`neural_bake.nets.native.Kernel`); numpy where it does not build.
KERNEL = Kernel(Path(__file__).with_name("texels.c"), switch=ENV_SWITCH, declare=_declare)
_kernel = KERNEL.lib


def kernel_status() -> str:
    """Which rasteriser runs here: the C kernel (and its file), or why the numpy one does."""
    return KERNEL.status()


def _ptr(a: np.ndarray) -> int:
    return a.ctypes.data


@dataclass
class TexelSet:
    """Samples of a UV layout on a texel grid, with the 3-D point and shading frame of each.

    M samples; with ``supersample = s`` a texel has up to s² samples (each texel's weights sum to 1).
    All arrays are numpy; float arrays are float64.

    The frame is what a glTF renderer reconstructs at that point from the exported mesh:
    ``normal = normalize(interp vertex normal)``, ``tangent = normalize(interp TANGENT.xyz)``,
    ``bitangent = w · cross(normal, tangent)`` with ``w`` the sign of the interpolated handedness.
    Tangent-space normal map convention: glTF / OpenGL, +Y (green) along the bitangent, v up.
    """

    size: tuple[int, int]
    """(H, W) of the texel grid."""
    pixel: np.ndarray
    """(M, 2) int64 (row from the TOP, column) of the texel each sample belongs to."""
    points: np.ndarray
    """(M, 3) float64 sample points on the mesh, unit frame."""
    normal: np.ndarray
    """(M, 3) float64 unit interpolated vertex normal (outward)."""
    tangent: np.ndarray
    """(M, 3) float64 unit interpolated tangent (towards increasing u)."""
    bitangent: np.ndarray
    """(M, 3) float64 ``w · cross(normal, tangent)`` (towards increasing v)."""
    face: np.ndarray
    """(M,) int64 face of the mesh each sample lies on."""
    bary: np.ndarray
    """(M, 3) float64 barycentric coordinates in that face (non-negative, sum 1)."""
    weight: np.ndarray
    """(M,) float64 supersampling weight; the weights of one texel sum to 1."""
    texel: np.ndarray
    """(M,) int64 index ``row * W + col`` of the sample's texel in the flattened (H * W) grid."""
    coverage: np.ndarray
    """(H, W) bool: texels that received at least one sample (border texels included)."""
    border: np.ndarray
    """(M,) bool: sample assigned by the conservative rule (texel touched by a triangle but no sample
    inside one): its point is the closest point of the nearest triangle (clamped barycentrics)."""
    supersample: int = 1
    """s: samples per texel along each axis."""
    overlaps: int = 0
    """Samples strictly inside more than one UV triangle (overlapping charts); the lowest face index wins."""

    @property
    def n_samples(self) -> int:
        return int(self.face.shape[0])

    @property
    def n_texels(self) -> int:
        return int(self.coverage.sum())

    def resolve(self, values: np.ndarray) -> np.ndarray:
        """Weighted average of per-sample ``values`` (M, C) per texel -> (H, W, C) float64 image (0 where
        not covered). Works for any float values (colours, normals before renormalisation, …)."""
        values = np.asarray(values, dtype=np.float64)
        flat = values.reshape(self.n_samples, -1)
        h, w = self.size
        out = np.zeros((h * w, flat.shape[1]))
        np.add.at(out, self.texel, flat * self.weight[:, None])
        return out.reshape(h, w, *values.shape[1:])


def _parse_size(size) -> tuple[int, int]:
    if isinstance(size, (int, np.integer)):
        h = w = int(size)
    else:
        try:
            h, w = (int(s) for s in size)
        except (TypeError, ValueError):
            raise NeuralBakeError(f"size: expected an int or (H, W), got {size!r}") from None
    if h < 1 or w < 1:
        raise NeuralBakeError(f"size: texel grid must be at least 1x1, got {h}x{w}")
    return h, w


def _face_uv_copies(mesh: Mesh, stacklevel: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(K,) face index and (K, 3, 2) UVs of the face copies to rasterise.

    ``uv_policy == "wrap"``: a face is moved by the integer offset that brings its centroid into [0, 1)²,
    and a face that still crosses the border is also rasterised shifted by ±1 (the texture repeats).
    ``"clamp"``: UVs are used as they are; parts outside [0, 1]² cover no texel.
    A :class:`NeuralBakeWarning` says how many faces have UVs outside [0, 1].
    """
    uv = np.asarray(mesh.uv, dtype=np.float64)
    nf = uv.shape[0]
    outside = ((uv < 0) | (uv > 1)).any(axis=(1, 2))
    if not outside.any():
        return np.arange(nf), uv
    if mesh.uv_policy == "wrap":
        uv = uv - np.floor(uv.mean(axis=1, keepdims=True))
        faces, uvs = [np.arange(nf)], [uv]
        lo, hi = uv.min(axis=1), uv.max(axis=1)  # (F, 2)
        for du in (-1, 0, 1):
            for dv in (-1, 0, 1):
                if du == dv == 0:
                    continue
                d = np.array([du, dv], dtype=np.float64)
                hit = ((lo + d) < 1).all(axis=1) & ((hi + d) > 0).all(axis=1)
                if hit.any():
                    faces.append(np.flatnonzero(hit))
                    uvs.append(uv[hit] + d)
        warnings.warn(
            f"{mesh.name}: {int(outside.sum())} faces have UVs outside [0, 1]; wrapped (uv_policy 'wrap')",
            NeuralBakeWarning,
            stacklevel=stacklevel,
        )
        return np.concatenate(faces), np.concatenate(uvs)
    warnings.warn(
        f"{mesh.name}: {int(outside.sum())} faces have UVs outside [0, 1]; the parts outside cover no texel"
        " (uv_policy 'clamp')",
        NeuralBakeWarning,
        stacklevel=stacklevel,
    )
    return np.arange(nf), uv


def _enumerate(r0, nr, c0, nc):
    """All (row, col) of the per-face boxes [r0, r0+nr) x [c0, c0+nc): returns (face_slot, row, col)."""
    nb = nr * nc
    total = int(nb.sum())
    slot = np.repeat(np.arange(len(nb)), nb)
    start = np.cumsum(nb) - nb
    local = np.arange(total, dtype=np.int64) - np.repeat(start, nb)
    ncs = nc[slot]
    return slot, r0[slot] + local // ncs, c0[slot] + local % ncs


def _chunks_by_budget(counts: np.ndarray, budget: int) -> Iterator[slice]:
    """Consecutive slices of ``counts`` whose sums stay under ``budget`` (a slice holds at least one)."""
    csum = np.cumsum(counts)
    i, n = 0, len(counts)
    while i < n:
        base = csum[i - 1] if i else 0
        j = int(np.searchsorted(csum, base + budget, side="right"))
        j = max(j, i + 1)
        yield slice(i, j)
        i = j


def _bary(x, y, px, py):
    """Barycentrics of points (px, py) (K,) in triangles x, y (K, 3); (K, 3), and 2 x signed area (K,)."""
    x0, y0 = x[:, 0], y[:, 0]
    e1x, e1y = x[:, 1] - x0, y[:, 1] - y0
    e2x, e2y = x[:, 2] - x0, y[:, 2] - y0
    d = e1x * e2y - e2x * e1y
    qx, qy = px - x0, py - y0
    with np.errstate(divide="ignore", invalid="ignore"):
        b1 = (qx * e2y - e2x * qy) / d
        b2 = (e1x * qy - qx * e1y) / d
    return np.stack([1.0 - b1 - b2, b1, b2], axis=1), d


def _row_spans(x, y, py):
    """x-extent [xl, xr] of triangles x, y (K, 3) on the horizontal lines y = py (K,); xl > xr: empty."""
    xl = np.full(len(py), np.inf)
    xr = np.full(len(py), -np.inf)
    for i in range(3):
        j = (i + 1) % 3
        xi, xj, yi, yj = x[:, i], x[:, j], y[:, i], y[:, j]
        dy = yj - yi
        on = (py >= np.minimum(yi, yj) - TEXEL_SPAN_TOL) & (py <= np.maximum(yi, yj) + TEXEL_SPAN_TOL)
        flat = np.abs(dy) < UV_FLAT_EDGE_EPS
        t = np.clip(np.divide(py - yi, dy, out=np.zeros_like(dy), where=~flat), 0.0, 1.0)
        xa = xi + t * (xj - xi)
        lo = np.where(flat, np.minimum(xi, xj), xa)
        hi = np.where(flat, np.maximum(xi, xj), xa)
        xl = np.where(on, np.minimum(xl, lo), xl)
        xr = np.where(on, np.maximum(xr, hi), xr)
    return xl, xr


def _sample_hits(xs, ys, hs, ws, rows):
    """Sample centres inside UV triangles for sample rows ``rows`` = [a, b).

    ``xs, ys`` (K, 3) triangle corners in sample-pixel coordinates (sample (r, c) centre at x = c, y = r).
    Returns (copy index (N,), sample row, sample col, bary (N, 3), overlaps) with one hit per sample.
    """
    a, b = rows
    xmin, xmax = xs.min(axis=1), xs.max(axis=1)
    ymin, ymax = ys.min(axis=1), ys.max(axis=1)
    c0 = np.maximum(np.ceil(xmin), 0).astype(np.int64)
    c1 = np.minimum(np.floor(xmax), ws - 1).astype(np.int64)
    r0 = np.maximum(np.ceil(ymin), a).astype(np.int64)
    r1 = np.minimum(np.floor(ymax), b - 1).astype(np.int64)
    area2 = (xs[:, 1] - xs[:, 0]) * (ys[:, 2] - ys[:, 0]) - (xs[:, 2] - xs[:, 0]) * (ys[:, 1] - ys[:, 0])
    live = np.flatnonzero((c1 >= c0) & (r1 >= r0) & (np.abs(area2) > UV_AREA_EPS))
    if live.size == 0:
        e = np.zeros(0, np.int64)
        return e, e, e, np.zeros((0, 3)), 0
    # scanlines: for every (face, sample row) the exact x-span of the triangle on that row, then only the
    # sample centres inside the span are enumerated (no rejected bounding-box candidates). Each sample keeps
    # the lowest copy index whose triangle holds it (``owner``); samples strictly inside several triangles
    # are counted as overlaps.
    n_samples = (b - a) * ws
    none = np.iinfo(np.int64).max
    owner = np.full(n_samples, none, dtype=np.int64)
    strict_count = np.zeros(n_samples, dtype=np.int64)
    lib = _kernel()
    if lib is not None:
        xs, ys = np.ascontiguousarray(xs, dtype=np.float64), np.ascontiguousarray(ys, dtype=np.float64)
        live = np.ascontiguousarray(live, dtype=np.int64)
        lib.nb_sample_owners(_ptr(xs), _ptr(ys), _ptr(live), len(live), _ptr(r0), _ptr(r1), a, ws, TEXEL_SPAN_TOL,
                             UV_FLAT_EDGE_EPS, TEXEL_INSIDE_EPS, TEXEL_STRICT_EPS, _ptr(owner), _ptr(strict_count))
        m = int(np.count_nonzero(owner != none))
        k, rr, cc = (np.empty(m, dtype=np.int64) for _ in range(3))
        bary = np.empty((m, 3))
        if m:
            lib.nb_collect_hits(_ptr(xs), _ptr(ys), _ptr(owner), n_samples, none, a, ws, _ptr(k), _ptr(rr), _ptr(cc),
                                _ptr(bary))
        return k, rr, cc, bary, int(np.count_nonzero(strict_count > 1))
    nr = r1[live] - r0[live] + 1
    for sl in _chunks_by_budget(nr, _MAX_CANDIDATES // 4):
        ids = live[sl]
        slot = np.repeat(np.arange(len(ids)), nr[sl])
        start = np.cumsum(nr[sl]) - nr[sl]
        rowv = r0[ids][slot] + np.arange(len(slot), dtype=np.int64) - np.repeat(start, nr[sl])
        kr = ids[slot]
        xl, xr = _row_spans(xs[kr], ys[kr], rowv.astype(np.float64))
        cl = np.maximum(np.ceil(xl - TEXEL_SPAN_TOL), 0).astype(np.int64)
        cr = np.minimum(np.floor(xr + TEXEL_SPAN_TOL), ws - 1).astype(np.int64)
        ncol = np.maximum(cr - cl + 1, 0)
        for sl2 in _chunks_by_budget(ncol, _MAX_CANDIDATES):
            n2 = ncol[sl2]
            slot2 = np.repeat(np.arange(sl2.start, sl2.stop), n2)
            st2 = np.cumsum(n2) - n2
            cc = cl[slot2] + np.arange(len(slot2), dtype=np.int64) - np.repeat(st2, n2)
            rr = rowv[slot2]
            k = kr[slot2]
            bary, _ = _bary(xs[k], ys[k], cc.astype(np.float64), rr.astype(np.float64))
            b0, b1, b2 = bary.T  # column tests: .all(axis=1) on (N, 3) is several times slower
            inside = (b0 >= -TEXEL_INSIDE_EPS) & (b1 >= -TEXEL_INSIDE_EPS) & (b2 >= -TEXEL_INSIDE_EPS)
            strict = (b0 > TEXEL_STRICT_EPS) & (b1 > TEXEL_STRICT_EPS) & (b2 > TEXEL_STRICT_EPS)
            sid = (rr - a) * ws + cc
            np.minimum.at(owner, sid[inside], k[inside])
            strict_count += np.bincount(sid[strict], minlength=n_samples)
    hit = np.flatnonzero(owner != none)  # ascending sample index: row-major order
    if hit.size == 0:
        e = np.zeros(0, np.int64)
        return e, e, e, np.zeros((0, 3)), 0
    k = owner[hit]
    rr, cc = hit // ws + a, hit % ws
    bary, _ = _bary(xs[k], ys[k], cc.astype(np.float64), rr.astype(np.float64))
    overlaps = int(np.count_nonzero(strict_count > 1))
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    return k, rr, cc, bary, overlaps


def _closest_on_triangles(x, y, px, py):
    """Closest point of 2-D triangles (K, 3) to points (K,): (distance (K,), clamped bary (K, 3))."""
    bary, d = _bary(x, y, px, py)
    inside = (bary >= 0).all(axis=1) & (np.abs(d) > UV_AREA_EPS)
    best_d = np.full(len(px), np.inf)
    best_b = np.zeros((len(px), 3))
    for i in range(3):
        j = (i + 1) % 3
        ex, ey = x[:, j] - x[:, i], y[:, j] - y[:, i]
        ll = ex * ex + ey * ey
        t = np.divide((px - x[:, i]) * ex + (py - y[:, i]) * ey, ll, out=np.zeros_like(ll), where=ll > 0)
        t = np.clip(t, 0.0, 1.0)
        dist = np.hypot(x[:, i] + t * ex - px, y[:, i] + t * ey - py)
        better = dist < best_d
        best_d = np.where(better, dist, best_d)
        bb = np.zeros((len(px), 3))
        bb[:, i], bb[:, j] = 1.0 - t, t
        best_b[better] = bb[better]
    best_d[inside] = 0.0
    best_b[inside] = bary[inside]
    return best_d, best_b


def _border_hits(xs, ys, h, w, rows, covered):
    """Conservative pass on the texel grid: uncovered texels in rows [a, b) that some UV triangle overlaps
    (separating-axis test, touching excluded) get the nearest such triangle and its clamped closest point.
    ``xs, ys`` (K, 3) in texel-pixel coordinates; ``covered`` (b - a, W) bool. Returns (copy, row, col, bary)."""
    a, b = rows
    c0 = np.maximum(np.ceil(xs.min(axis=1) - 0.5), 0).astype(np.int64)
    c1 = np.minimum(np.floor(xs.max(axis=1) + 0.5), w - 1).astype(np.int64)
    r0 = np.maximum(np.ceil(ys.min(axis=1) - 0.5), a).astype(np.int64)
    r1 = np.minimum(np.floor(ys.max(axis=1) + 0.5), b - 1).astype(np.int64)
    area2 = (xs[:, 1] - xs[:, 0]) * (ys[:, 2] - ys[:, 0]) - (xs[:, 2] - xs[:, 0]) * (ys[:, 1] - ys[:, 0])
    live = np.flatnonzero((c1 >= c0) & (r1 >= r0) & (np.abs(area2) > UV_AREA_EPS))
    lib = _kernel()
    if lib is not None:
        xs, ys = np.ascontiguousarray(xs, dtype=np.float64), np.ascontiguousarray(ys, dtype=np.float64)
        cov = np.ascontiguousarray(covered, dtype=np.uint8)
        best_d = np.full(cov.size, np.inf)
        best_k = np.full(cov.size, -1, dtype=np.int64)
        best_b = np.zeros((cov.size, 3))
        lib.nb_border_hits(_ptr(xs), _ptr(ys), _ptr(area2), _ptr(live), len(live), _ptr(r0), _ptr(r1), _ptr(c0),
                           _ptr(c1), a, w, _ptr(cov), TEXEL_OVERLAP_EPS, UV_AREA_EPS, _ptr(best_d), _ptr(best_k),
                           _ptr(best_b))
        tid = np.flatnonzero(best_k >= 0)
        return best_k[tid], tid // w + a, tid % w, best_b[tid]
    ks, rs, cs, ds, bs = [], [], [], [], []
    if live.size:
        nr, nc = r1[live] - r0[live] + 1, c1[live] - c0[live] + 1
        for sl in _chunks_by_budget(nr * nc, _MAX_CANDIDATES):
            ids = live[sl]
            slot, rr, cc = _enumerate(r0[ids], nr[sl], c0[ids], nc[sl])
            free = ~covered[rr - a, cc]
            k, rr, cc = ids[slot][free], rr[free], cc[free]
            if k.size == 0:
                continue
            x, y = xs[k], ys[k]
            px, py = cc.astype(np.float64), rr.astype(np.float64)
            sgn = np.sign(area2[k])
            overlap = (np.maximum(x.min(1), px - 0.5) < np.minimum(x.max(1), px + 0.5)) & (
                np.maximum(y.min(1), py - 0.5) < np.minimum(y.max(1), py + 0.5)
            )
            for i in range(3):
                j = (i + 1) % 3
                ex, ey = x[:, j] - x[:, i], y[:, j] - y[:, i]
                # edge function, positive inside; its largest value over the texel square must be > 0
                e = sgn * (ex * (py - y[:, i]) - ey * (px - x[:, i]))
                overlap &= e + 0.5 * (np.abs(ex) + np.abs(ey)) > TEXEL_OVERLAP_EPS
            k, rr, cc = k[overlap], rr[overlap], cc[overlap]
            if k.size == 0:
                continue
            dist, bary = _closest_on_triangles(xs[k], ys[k], cc.astype(np.float64), rr.astype(np.float64))
            ks.append(k), rs.append(rr), cs.append(cc), ds.append(dist), bs.append(bary)
    if not ks:
        e = np.zeros(0, np.int64)
        return e, e, e, np.zeros((0, 3))
    k, rr, cc, dist, bary = (np.concatenate(v) for v in (ks, rs, cs, ds, bs))
    tid = (rr - a) * w + cc
    order = np.lexsort((k, dist, tid))
    first = np.ones(len(order), bool)
    first[1:] = tid[order][1:] != tid[order][:-1]
    keep = order[first]
    return k[keep], rr[keep], cc[keep], bary[keep]


def _prepare_tangents(mesh: Mesh, tangents) -> np.ndarray:
    """Per-corner (F, 3, 4) tangents from ``tangents`` (V, 4) / (F, 3, 4) or computed from the mesh."""
    if tangents is None:
        try:
            vertex_uv(mesh)
            return tangent_frames(mesh)[mesh.faces]
        except MeshError:
            if mesh.uv is None:
                raise
            from .unwrap import split_uv_seams

            split, _ = split_uv_seams(mesh)
            return tangent_frames(split)[split.faces]
    t = np.asarray(tangents, dtype=np.float64)
    if t.shape == (mesh.n_vertices, 4):
        return t[mesh.faces]
    if t.shape == (mesh.n_faces, 3, 4):
        return t
    raise NeuralBakeError(
        f"tangents: expected shape ({mesh.n_vertices}, 4) or ({mesh.n_faces}, 3, 4), got {t.shape}"
    )


def _interpolate_corners(table: torch.Tensor, face: np.ndarray, bary: np.ndarray):
    """Points (M, 3), unit normals (M, 3), unit tangents (M, 3) and handedness signs (M,) interpolated from
    the per-corner ``table`` (3, F, 10) of :func:`iter_texels` (corner, face, attribute) at the samples'
    faces and barycentrics (torch, float64, on the CPU's threads). Normals and tangents too short to
    normalise are NaN rows."""
    lib = _kernel()
    if lib is not None and table.is_contiguous() and table.dtype == torch.float64:
        face = np.ascontiguousarray(face, dtype=np.int64)
        bary = np.ascontiguousarray(bary, dtype=np.float64)
        m = len(face)
        points, normal, tangent = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
        sign = np.empty(m)
        lib.nb_interpolate_corners(table.data_ptr(), table.shape[1], _ptr(face), _ptr(bary), m, UNDERFLOW_EPS,
                                   _ptr(points), _ptr(normal), _ptr(tangent), _ptr(sign))
        return points, normal, tangent, sign
    f = torch.from_numpy(np.ascontiguousarray(face, dtype=np.int64))
    b = torch.from_numpy(np.ascontiguousarray(bary, dtype=np.float64))
    acc = table[0].index_select(0, f).mul_(b[:, 0:1])
    for k in (1, 2):
        acc.add_(table[k].index_select(0, f).mul_(b[:, k: k + 1]))
    out = []
    for lo in (3, 6):  # normal, tangent: unit, NaN where too short
        x, y, z = acc[:, lo], acc[:, lo + 1], acc[:, lo + 2]
        length = (x * x + y * y + z * z).sqrt_()[:, None]  # not .sum(1): slow across a row of 3
        v = acc[:, lo: lo + 3]
        out.append(torch.where(length > UNDERFLOW_EPS, v / length, torch.full_like(v, float("nan"))).numpy())
    sign = torch.where(acc[:, 9] < 0, -1.0, 1.0).numpy()
    return acc[:, :3].contiguous().numpy(), out[0], out[1], sign


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (M, 3) arrays (np.cross, without its overhead on long arrays)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _signed_cross(sign: np.ndarray, n: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``sign[:, None] * cross(n, t)`` for (M, 3) float64 rows (the bitangents), by the C kernel where it builds
    (the same operations in the same order: equal bit for bit)."""
    lib = _kernel()
    if lib is not None:
        n, t = np.ascontiguousarray(n, dtype=np.float64), np.ascontiguousarray(t, dtype=np.float64)
        sign = np.ascontiguousarray(sign, dtype=np.float64)
        out = np.empty_like(n)
        lib.nb_signed_cross(_ptr(n), _ptr(t), _ptr(sign), len(n), _ptr(out))
        return out
    return sign[:, None] * _cross(n, t)


def texel_centres(mesh: Mesh, size) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(face (N,) int64, row (N,), col (N,), bary (N, 3) float64) of the texel centres of an (H, W) grid that
    lie inside a UV triangle of ``mesh``: the samples :func:`rasterize_texels` places at one sample per texel
    (the lowest face where triangles overlap, UVs outside [0, 1] as ``mesh.uv_policy`` says), without their
    frames, border samples or points."""
    return _centres(mesh, size)[:4]


def _centres(mesh: Mesh, size):
    """:func:`texel_centres`' arrays and the number of texel centres strictly inside several triangles."""
    if mesh.uv is None:
        raise MeshError(f"{mesh.name}: mesh has no UVs; unwrap it first (neural_bake.unwrap)")
    h, w = _parse_size(size)
    uv_faces, uv = _face_uv_copies(mesh, stacklevel=4)  # the warning names the public function's caller
    k, rr, cc, bary, overlaps = _sample_hits(uv[..., 0] * w - 0.5, (1.0 - uv[..., 1]) * h - 0.5, h, w, (0, h))
    return uv_faces[k].astype(np.int64, copy=False), rr, cc, bary, overlaps


def texel_counts(mesh: Mesh, size) -> tuple[np.ndarray, int]:
    """(F,) int64: the texel centres of an (H, W) map that each face holds, as :func:`texel_centres` assigns
    them (the lowest face where triangles overlap, UVs outside [0, 1] as ``mesh.uv_policy`` says: the texels a
    bake writes from the face), and the number of texel centres strictly inside several triangles. Without
    the warning about UVs outside [0, 1] (the bake gives it)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NeuralBakeWarning)
        face, _, _, _, overlaps = _centres(mesh, size)
    return np.bincount(face, minlength=len(mesh.faces)).astype(np.int64, copy=False), overlaps


def face_uv_areas(uv) -> np.ndarray:
    """(F,) float64 areas of (F, 3, 2) per-corner UV triangles, in UV units; 0 where not finite."""
    uv = np.asarray(uv, dtype=np.float64)
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return np.nan_to_num(0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]), nan=0.0, posinf=0.0)


def iter_texels(
    mesh: Mesh,
    size,
    *,
    supersample: int = 1,
    tangents=None,
    conservative: bool = True,
    max_samples: int = 1 << 20,
) -> Iterator[TexelSet]:
    """:func:`rasterize_texels` in bands of texel rows, for maps too large for one :class:`TexelSet`.

    Yields one :class:`TexelSet` per band of about ``max_samples`` sample positions; each one's
    ``coverage`` is the full (H, W) grid but only its own rows are set. ``pixel`` and ``texel`` are
    global. Concatenating the bands gives exactly :func:`rasterize_texels`' result.
    """
    if mesh.uv is None:
        raise MeshError(f"{mesh.name}: mesh has no UVs; unwrap it first (neural_bake.unwrap)")
    h, w = _parse_size(size)
    if int(supersample) != supersample or supersample < 1:
        raise NeuralBakeError(f"supersample: must be a positive integer, got {supersample!r}")
    s = int(supersample)
    uv_faces, uv = _face_uv_copies(mesh)
    corner_t = _prepare_tangents(mesh, tangents)
    fnorm = mesh.face_normals
    # per face corner: position, vertex normal, tangent and handedness, gathered once per sample
    corner_table = torch.from_numpy(np.ascontiguousarray(np.concatenate(
        [mesh.triangles, vertex_normals(mesh)[mesh.faces], corner_t], axis=2).transpose(1, 0, 2), dtype=np.float64))
    # texel-pixel coordinates: u right, v up; texel (r, c) centre at x = c, y = r
    xt = uv[..., 0] * w - 0.5
    yt = (1.0 - uv[..., 1]) * h - 0.5
    # sample-pixel coordinates (s x s samples per texel)
    xs = uv[..., 0] * (w * s) - 0.5
    ys = (1.0 - uv[..., 1]) * (h * s) - 0.5
    band = max(1, int(max_samples) // (w * s * s))
    ymin_t, ymax_t = yt.min(axis=1), yt.max(axis=1)
    for a in range(0, h, band):
        b = min(h, a + band)
        sel = np.flatnonzero((ymax_t >= a - 1) & (ymin_t <= b))  # copies that may touch rows [a, b)
        k, rr, cc, bary, overlaps = _sample_hits(xs[sel], ys[sel], h * s, w * s, (a * s, b * s))
        k = sel[k]
        tr, tc = (rr, cc) if s == 1 else (rr // s, cc // s)
        border = np.zeros(len(k), bool)
        if conservative:
            covered = np.zeros((b - a, w), bool)
            covered[tr - a, tc] = True
            kb, rb, cb, bb = _border_hits(xt[sel], yt[sel], h, w, (a, b), covered)
            k = np.concatenate([k, sel[kb]])
            tr, tc = np.concatenate([tr, rb]), np.concatenate([tc, cb])
            bary = np.concatenate([bary, bb])
            border = np.concatenate([border, np.ones(len(kb), bool)])
        face = uv_faces[k]
        texel = tr * w + tc
        order = np.argsort(texel, kind="stable")
        face, bary, texel, border, tr, tc = (v[order] for v in (face, bary, texel, border, tr, tc))
        new = np.ones(len(texel), bool)  # texel is sorted: runs of equal values are one texel's samples
        new[1:] = texel[1:] != texel[:-1]
        starts = np.flatnonzero(new)
        uniq = texel[starts]
        cnt = np.diff(np.append(starts, len(texel)))
        weight = np.repeat(1.0 / cnt, cnt)
        points, n, t, wsign = _interpolate_corners(corner_table, face, bary)
        ok = ~np.isnan(n[:, 0])
        if not ok.all():
            fb = fnorm[face[~ok]]
            fb[np.abs(fb).sum(1) == 0] = (0.0, 0.0, 1.0)
            n[~ok] = fb
        ok = ~np.isnan(t[:, 0])
        if not ok.all():
            from .tangents import _orthonormal_fallback

            t[~ok] = _orthonormal_fallback(n[~ok])
        coverage = np.zeros((h, w), bool)
        coverage.reshape(-1)[uniq] = True
        yield TexelSet(
            size=(h, w),
            pixel=np.stack([tr, tc], axis=1).astype(np.int64, copy=False),
            points=points,
            normal=n,
            tangent=t,
            bitangent=_signed_cross(wsign, n, t),
            face=face.astype(np.int64, copy=False),
            bary=bary,
            weight=weight,
            texel=texel.astype(np.int64, copy=False),
            coverage=coverage,
            border=border,
            supersample=s,
            overlaps=overlaps,
        )


def rasterize_texels(
    mesh: Mesh,
    size,
    *,
    supersample: int = 1,
    tangents=None,
    conservative: bool = True,
) -> TexelSet:
    """Rasterise the UV layout of ``mesh`` on an (H, W) texel grid.

    Every texel centre (or each of its s × s subsample centres with ``supersample = s``) inside a UV
    triangle becomes a sample with its 3-D point (unit frame) and the glTF shading frame there (see
    :class:`TexelSet`). UV -> pixel follows glTF: u right, v up; texel (row, col) has its centre at
    ``u = (col + 0.5) / W``, ``v = 1 - (row + 0.5) / H`` (row 0 is the top of the image).

    ``conservative``: a texel that a triangle overlaps but whose samples are all outside every triangle
    (chart borders) gets one sample at the closest point of the nearest overlapping triangle (clamped
    barycentrics), flagged in ``border``. UVs outside [0, 1] are wrapped or clamped by ``mesh.uv_policy``
    (with a :class:`NeuralBakeWarning`). Faces with degenerate UVs cover nothing; degenerate normals or
    tangents fall back to the face normal / any orthogonal vector: the output never holds NaN.

    ``tangents``: (V, 4) or per-corner (F, 3, 4) glTF tangents; default :func:`tangent_frames` (on a copy
    split at UV seams if the mesh is not split). For maps above ~2048² use :func:`iter_texels`.
    Raises :class:`MeshError` if the mesh has no UVs, :class:`NeuralBakeError` for a bad size.
    """
    h, w = _parse_size(size)
    s = int(supersample) if isinstance(supersample, (int, np.integer)) and supersample >= 1 else 1
    # one band of every sample position: the candidate work is chunked inside, and no band is concatenated
    parts = list(iter_texels(mesh, size, supersample=supersample, tangents=tangents, conservative=conservative,
                             max_samples=h * w * s * s))
    if len(parts) == 1:
        return parts[0]
    cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    coverage = np.zeros(parts[0].size, bool)
    for p in parts:
        coverage |= p.coverage
    return TexelSet(
        size=parts[0].size,
        pixel=cat("pixel"),
        points=cat("points"),
        normal=cat("normal"),
        tangent=cat("tangent"),
        bitangent=cat("bitangent"),
        face=cat("face"),
        bary=cat("bary"),
        weight=cat("weight"),
        texel=cat("texel"),
        coverage=coverage,
        border=cat("border"),
        supersample=parts[0].supersample,
        overlaps=sum(p.overlaps for p in parts),
    )


def texel_grid_points(size) -> np.ndarray:
    """(H, W, 2) float64 UV coordinates of every texel centre of an (H, W) grid (glTF: v up, row 0 top)."""
    h, w = _parse_size(size)
    u = (np.arange(w) + 0.5) / w
    v = 1.0 - (np.arange(h) + 0.5) / h
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu, vv], axis=-1)
