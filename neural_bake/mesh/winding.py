"""The generalised winding number of a triangle mesh (Jacobson et al. 2013), exact and accelerated.

w(p) = Σ_f Ω_f(p) / 4π over the non-degenerate faces, Ω_f the signed solid angle of face f seen from p (Van
Oosterom–Strackee formula): 1 inside a closed outward-wound mesh, 0 outside, and a robust inside test for open
meshes (threshold 1/2).

The accelerated sum is two-level: faces are grouped into compact clusters (k-d median splits) of
:data:`CLUSTER_SIZE` faces; a cluster seen from farther than :data:`FAR_FACTOR` × its radius contributes its
dipole term (Barill et al. 2018, first order), nearer clusters their exact solid angles; points whose
approximate winding number lies within :data:`AMBIGUOUS` of 1/2 are recomputed exactly, so the sign is the
exact sum's. The exact sum, O(N·F), is the slow reference.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..constants import DIPOLE_MIN_DISTANCE
from ..geometry import check_points, sampleable_faces
from ..types import Mesh

__all__ = ["winding_number", "CLUSTER_SIZE", "FAR_FACTOR", "AMBIGUOUS"]

#: Faces per cluster of the accelerated winding number.
CLUSTER_SIZE = 16
#: A cluster farther than this many times its radius contributes its dipole term only.
FAR_FACTOR = 2.5
#: Points whose approximate winding number is within this of 1/2 are recomputed exactly.
AMBIGUOUS = 0.1
#: Elements (points × faces) per block of the winding-number kernels (bounds their memory to ~1 GB at most).
_CHUNK_ELEMENTS = 4_000_000


def _solid_angles(p: torch.Tensor, tri: torch.Tensor) -> torch.Tensor:
    """Signed solid angles (P, F) of triangles ``tri`` (F, 3, 3) seen from points ``p`` (P, 3).

    Van Oosterom & Strackee (1983): tan(Ω/2) = det[a b c] / (|a||b||c| + (a·b)|c| + (b·c)|a| + (c·a)|b|),
    with a, b, c the corners relative to the point. Positive when the point sees the back (inner) side.
    """
    a = tri[None, :, 0, :] - p[:, None, :]
    b = tri[None, :, 1, :] - p[:, None, :]
    c = tri[None, :, 2, :] - p[:, None, :]
    la, lb, lc = a.norm(dim=-1), b.norm(dim=-1), c.norm(dim=-1)
    det = (a * torch.linalg.cross(b, c, dim=-1)).sum(-1)
    den = la * lb * lc + (a * b).sum(-1) * lc + (b * c).sum(-1) * la + (c * a).sum(-1) * lb
    return 2.0 * torch.atan2(det, den)


class _FaceTerms:
    """Per-face constants of the expanded Van Oosterom–Strackee formula, so that a (points × faces) block
    needs only matrix products: with a = A - p (and b, c alike),

    - |a|² = |A|² - 2 p·A + |p|², a·b = A·B - p·(A + B) + |p|²,
    - det[a b c] = det[A B C] - p·(A×B + B×C + C×A).

    float64; the cancellation error is ~1e-16 × |A|², far below what the sign needs.
    """

    def __init__(self, tri: torch.Tensor):
        A, B, C = tri[:, 0], tri[:, 1], tri[:, 2]
        self.corners = torch.stack([A, B, C], 0)  # (3, F, 3)
        self.sq = (self.corners**2).sum(-1)  # (3, F)
        self.pair_sum = torch.stack([A + B, B + C, C + A], 0)  # (3, F, 3)
        self.pair_dot = torch.stack([(A * B).sum(-1), (B * C).sum(-1), (C * A).sum(-1)], 0)  # (3, F)
        self.det = (A * torch.linalg.cross(B, C, dim=-1)).sum(-1)  # (F,)
        self.nrm = torch.linalg.cross(A, B, dim=-1) + torch.linalg.cross(B, C, dim=-1) + torch.linalg.cross(C, A, dim=-1)

    def winding(self, p: torch.Tensor, lo: int = 0, hi: int | None = None) -> torch.Tensor:
        """Σ_f Ω_f(p) / 4π over faces lo:hi for points (P, 3): (P,)."""
        s = slice(lo, hi)
        pp = (p * p).sum(-1, keepdim=True)  # (P, 1)
        lens = [(self.sq[k, s] - 2.0 * p @ self.corners[k, s].T + pp).clamp_min(0.0).sqrt() for k in range(3)]
        dots = [self.pair_dot[k, s] - p @ self.pair_sum[k, s].T + pp for k in range(3)]
        la, lb, lc = lens
        ab, bc, ca = dots
        det = self.det[s] - p @ self.nrm[s].T
        den = la * lb * lc + ab * lc + bc * la + ca * lb
        return torch.atan2(det, den).sum(1) / (2 * math.pi)


def _exact_winding(p: torch.Tensor, tri: torch.Tensor) -> torch.Tensor:
    terms = _FaceTerms(tri.to(torch.float64))
    p = p.to(torch.float64)
    out = torch.empty(p.shape[0], dtype=torch.float64)
    step = max(1, _CHUNK_ELEMENTS // max(1, tri.shape[0]))
    for i in range(0, p.shape[0], step):
        out[i : i + step] = terms.winding(p[i : i + step])
    return out


def _cluster_order(x: np.ndarray, leaf: int) -> np.ndarray:
    """Order of points (F, 3) that makes every run of ``leaf`` consecutive points a compact cluster:
    recursive median splits along the longest side of the bounding box (a k-d tree), at multiples of ``leaf``."""
    order = np.arange(x.shape[0])
    stack = [(0, x.shape[0])]
    while stack:
        lo, hi = stack.pop()
        if hi - lo <= leaf:
            continue
        sub = order[lo:hi]
        pts = x[sub]
        axis = int(np.argmax(pts.max(0) - pts.min(0)))
        n_left = -(-((hi - lo) // 2) // leaf) * leaf  # half, rounded up to a multiple of leaf
        part = np.argpartition(pts[:, axis], n_left - 1) if n_left < hi - lo else np.arange(hi - lo)
        order[lo:hi] = sub[part]
        stack += [(lo, lo + n_left), (lo + n_left, hi)]
    return order


def _fast_winding(p: torch.Tensor, tri_np: np.ndarray) -> torch.Tensor:
    """Two-level winding number (module docstring); float64."""
    f = tri_np.shape[0]
    order = _cluster_order(tri_np.mean(1), CLUSTER_SIZE)
    k = -(-f // CLUSTER_SIZE)
    pad = k * CLUSTER_SIZE - f
    tri_sorted = tri_np[order]
    if pad:  # zero-area padding triangles subtend no solid angle
        tri_sorted = np.concatenate([tri_sorted, np.repeat(tri_sorted[-1:, :1, :], 3, axis=1).repeat(pad, 0)])
    clusters = tri_sorted.reshape(k, CLUSTER_SIZE, 3, 3)
    cross = 0.5 * np.cross(clusters[:, :, 1] - clusters[:, :, 0], clusters[:, :, 2] - clusters[:, :, 0])
    area = np.linalg.norm(cross, axis=-1)  # (k, B)
    cent = clusters.mean(2)  # (k, B, 3)
    wsum = area.sum(1, keepdims=True)
    center = np.where(wsum > 0, (area[..., None] * cent).sum(1) / np.where(wsum > 0, wsum, 1), cent.mean(1))
    radius = np.linalg.norm(clusters - center[:, None, None, :], axis=-1).reshape(k, -1).max(1)
    dipole = cross.sum(1)  # (k, 3): Σ area · normal

    # coordinates first: every operation below runs on contiguous (points × clusters) or (pairs × faces)
    # arrays (reductions over a trailing axis of 3 are several times slower in torch)
    T = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))  # noqa: E731
    cx, cy, cz = (T(center[:, i]) for i in range(3))  # (k,)
    dx_, dy_, dz_ = (T(dipole[:, i]) for i in range(3))
    far_r = FAR_FACTOR * T(radius)
    corner = [[T(clusters[:, :, v, i]) for i in range(3)] for v in range(3)]  # [vertex][coord]: (k, B)
    out = torch.empty(p.shape[0], dtype=torch.float64)
    step = max(1, 2_000_000 // k)
    for i in range(0, p.shape[0], step):
        q = p[i : i + step]
        qx, qy, qz = (q[:, j : j + 1] for j in range(3))  # (P, 1)
        ex, ey, ez = cx - qx, cy - qy, cz - qz  # (P, k)
        r = (ex * ex + ey * ey + ez * ez).sqrt_()
        far = r > far_r
        term = (ex * dx_ + ey * dy_ + ez * dz_) / (4 * math.pi * r.clamp_min_(DIPOLE_MIN_DISTANCE) ** 3)
        w = torch.where(far, term, torch.zeros_like(term)).sum(1)
        pi, ki = torch.nonzero(~far, as_tuple=True)
        if pi.numel():
            # exact solid angles of the near clusters' faces, per (point, cluster) pair, in sub-chunks
            sub = max(1, _CHUNK_ELEMENTS // (CLUSTER_SIZE * 9))
            for j in range(0, pi.numel(), sub):
                pj, kj = pi[j : j + sub], ki[j : j + sub]
                px, py, pz = (q[pj, m : m + 1] for m in range(3))  # (M, 1)
                (ax, ay, az), (bx, by, bz), (gx, gy, gz) = (
                    (c[0].index_select(0, kj) - px, c[1].index_select(0, kj) - py, c[2].index_select(0, kj) - pz)
                    for c in corner)  # (M, B) each: the corners relative to the point
                la = (ax * ax + ay * ay + az * az).sqrt_()
                lb = (bx * bx + by * by + bz * bz).sqrt_()
                lc = (gx * gx + gy * gy + gz * gz).sqrt_()
                det = ax * (by * gz - bz * gy) + ay * (bz * gx - bx * gz) + az * (bx * gy - by * gx)
                den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * gx + by * gy + bz * gz) * la
                       + (gx * ax + gy * ay + gz * az) * lb)
                w.index_add_(0, pj, torch.atan2(det, den).sum(1) / (2 * math.pi))
        out[i : i + step] = w
    return out


def winding_number(mesh: Mesh, points, *, exact: bool = False) -> np.ndarray:
    """(N,) float64 generalised winding number of the mesh at ``points`` (N, 3), unit frame.

    Jacobson et al. 2013: w(p) = Σ_f Ω_f(p) / 4π over the non-degenerate faces, Ω_f the signed solid angle
    (Van Oosterom–Strackee). 1 inside and 0 outside a closed, outward-wound mesh; a smooth inside measure
    for open meshes. ``exact=True`` sums every face (O(N·F)); otherwise far clusters use their dipole
    approximation and points within ``AMBIGUOUS`` of 1/2 are recomputed exactly, so the sign (w > 1/2) is
    that of the exact sum while the value away from 1/2 may differ by a few percent.
    """
    p = check_points(points, "winding_number")
    idx, _ = sampleable_faces(mesh)
    tri_np = np.asarray(mesh.vertices, dtype=np.float64)[mesh.faces[idx]]
    pt = torch.from_numpy(p)
    if p.shape[0] == 0:
        return np.zeros(0)
    if exact or tri_np.shape[0] <= 4 * CLUSTER_SIZE:
        return _exact_winding(pt, torch.from_numpy(tri_np)).numpy()
    w = _fast_winding(pt, tri_np)
    redo = torch.nonzero((w - 0.5).abs() < AMBIGUOUS, as_tuple=True)[0]
    if redo.numel():
        w[redo] = _exact_winding(pt[redo], torch.from_numpy(tri_np))
    return w.numpy()
