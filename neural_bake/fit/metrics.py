"""Quality of a neural SDF against its source mesh (unit frame): Chamfer-L1, Hausdorff, normal error.

- The network's zero level set is found by marching cubes of f on a ``resolution``³ grid over [-1, 1]³
  (:func:`skimage.measure.marching_cubes`), and each sampled point of that mesh is then projected onto
  f = 0 by ``newton_steps`` steps ``x ← x − f(x) ∇f(x) / |∇f(x)|²`` (GEMM gradients), so the samples lie on
  the network's surface rather than on its piecewise-linear approximation.
- Distances: network samples → source mesh are exact point-to-triangle distances (open3d BVH); source mesh
  samples → the network's surface are distances to actual points of f = 0 (|f| ≤ :data:`ZERO_SET_TOL`): the
  nearer of the closest marching-cubes point projected onto f = 0 and the sample itself projected. The
  marching-cubes mesh alone is off by its own error, O(h²·curvature) with voxel h = 2/(resolution − 1), and
  more at tips thinner than a voxel, which it cuts off; a sample whose projections both fail keeps its
  distance to that mesh (counted in ``mesh_to_net_fallback``).
- ``chamfer_l1`` = ½ (mean d(A→B) + mean d(B→A)) (NGLOD's convention, unit frame),
  ``hausdorff`` = max(max d(A→B), max d(B→A)).
- Normal error: the angle in degrees between ∇f/|∇f| and the mesh's face normal at mesh surface samples
  (median, mean, 95th percentile); points where |∇f| ≈ 0 count as 180°.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from ..constants import DIRECTION_EPS, NEWTON_MIN_GRAD_SQ
from ..errors import FitError, TrainingDivergedError
from ..geometry import angular_error, import_open3d, raycasting_scene
from ..nets.gemm import gemm_gradient, normalized_gradient
from ..types import Mesh

__all__ = ["sdf_metrics", "mesh_distances", "grid_values", "zero_level_mesh", "project_to_zero_set"]


def _closest_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) float64 distance from ``points`` (N, 3) to the triangles (open3d BVH closest point)."""
    return _closest(vertices, faces, points)[0]


def _closest(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,) float64 distances from ``points`` (N, 3) to the triangles and (N, 3) the closest points."""
    o3d = import_open3d()

    scene = raycasting_scene(vertices, faces)
    closest = scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32)))
    c = closest["points"].numpy().astype(np.float64)
    return np.linalg.norm(points.astype(np.float64) - c, axis=1), c


def _sample_triangles(vertices, faces, n, rng) -> tuple[np.ndarray, np.ndarray]:
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    ok = area > 0
    if not ok.any():
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    prob = np.where(ok, area, 0) / area[ok].sum()
    fi = rng.choice(len(faces), size=n, p=prob)
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    t = tri[fi]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0]), fi


def mesh_distances(a_vertices, a_faces, b_vertices, b_faces, *, n: int = 100_000, seed: int = 0,
                   a_points: np.ndarray | None = None) -> dict:
    """Two-sided surface distances between triangle meshes A and B (same frame).

    ``a_points`` (N, 3) replaces the area-uniform samples of A (e.g. samples projected onto an implicit
    surface). Returns ``{"chamfer_l1", "hausdorff", "a_to_b_mean", "b_to_a_mean", "a_to_b_max",
    "b_to_a_max"}`` (floats).
    """
    rng = np.random.default_rng(seed)
    a_v, a_f = np.asarray(a_vertices, np.float64), np.asarray(a_faces, np.int64)
    b_v, b_f = np.asarray(b_vertices, np.float64), np.asarray(b_faces, np.int64)
    pa = a_points if a_points is not None else _sample_triangles(a_v, a_f, n, rng)[0]
    pb = _sample_triangles(b_v, b_f, n, rng)[0]
    if len(pa) == 0 or len(pb) == 0:
        raise FitError("mesh_distances: a mesh with no non-degenerate triangle has no surface to compare")
    dab = _closest_distance(b_v, b_f, pa)
    dba = _closest_distance(a_v, a_f, pb)
    return {
        "chamfer_l1": 0.5 * (float(dab.mean()) + float(dba.mean())),
        "hausdorff": max(float(dab.max()), float(dba.max())),
        "a_to_b_mean": float(dab.mean()), "b_to_a_mean": float(dba.mean()),
        "a_to_b_max": float(dab.max()), "b_to_a_max": float(dba.max()),
    }


@torch.no_grad()
def grid_values(model, resolution: int, *, bound: float = 1.0, chunk: int = 65536) -> np.ndarray:
    """f on a ``resolution``³ grid over [-bound, bound]³: (R, R, R) float32, index [i, j, k] ↔ (x_i, y_j, z_k)."""
    p = next(model.parameters())
    axis = torch.linspace(-bound, bound, resolution, dtype=p.dtype, device=p.device)
    out = torch.empty(resolution ** 3, dtype=p.dtype, device=p.device)
    gx, gy = torch.meshgrid(axis, axis, indexing="ij")
    xy = torch.stack([gx.reshape(-1), gy.reshape(-1)], dim=1)
    rows = xy.shape[0]
    step = max(1, chunk // resolution)
    for s in range(0, rows, step):
        sub = xy[s:s + step]
        pts = torch.cat([sub.repeat_interleave(resolution, 0), axis.repeat(sub.shape[0])[:, None]], dim=1)
        out[s * resolution:(s + sub.shape[0]) * resolution] = model(pts)[:, 0]
    return out.reshape(resolution, resolution, resolution).float().cpu().numpy()


def zero_level_mesh(model, resolution: int = 128, *, bound: float = 1.0):
    """Marching cubes of f = 0: ``(vertices (V, 3) float64 unit frame, faces (F, 3) int64)``.

    Raises FitError when f has no zero crossing on the grid (nothing to measure).
    """
    from skimage.measure import marching_cubes

    vol = grid_values(model, resolution, bound=bound)
    if not np.isfinite(vol).all():
        raise TrainingDivergedError("sdf_metrics: the network gives non-finite values on the grid")
    if vol.min() >= 0 or vol.max() <= 0:
        raise FitError(f"sdf_metrics: the network's zero level set does not cross the grid "
                       f"(f in [{vol.min():.3g}, {vol.max():.3g}])")
    h = 2 * bound / (resolution - 1)
    verts, faces, _, _ = marching_cubes(vol, level=0.0, spacing=(h, h, h))
    return verts.astype(np.float64) - bound, faces.astype(np.int64)


@torch.no_grad()
def project_to_zero_set(model, x: torch.Tensor, steps: int = 2) -> torch.Tensor:
    """``steps`` Newton steps ``x ← x − f(x) ∇f(x) / |∇f(x)|²`` towards f = 0 (GEMM gradients, no autograd).

    Points where |∇f|² ≤ :data:`~neural_bake.constants.NEWTON_MIN_GRAD_SQ` stay where they are (no NaN); the
    caller checks |f| at the result.
    """
    for _ in range(steps):
        f, g = gemm_gradient(model, x)
        g2 = (g * g).sum(dim=1, keepdim=True)
        ok = g2 > NEWTON_MIN_GRAD_SQ
        x = torch.where(ok, x - f * g / torch.where(ok, g2, torch.ones_like(g2)), x)
    return x


def _project(model, points: np.ndarray, steps: int) -> np.ndarray:
    p = next(model.parameters())
    x = torch.as_tensor(points, dtype=p.dtype, device=p.device)
    return project_to_zero_set(model, x, steps).double().cpu().numpy()


#: |f| below which a Newton-projected point counts as a point of the zero level set (unit frame; 2 % of the
#: 0.005 Hausdorff target).
ZERO_SET_TOL = 1e-4


@torch.no_grad()
def _values(model, points: np.ndarray) -> np.ndarray:
    p = next(model.parameters())
    return model(torch.as_tensor(points, dtype=p.dtype, device=p.device))[:, 0].double().cpu().numpy()


def _distance_to_zero_set(model, points: np.ndarray, mc_closest: np.ndarray, mc_dist: np.ndarray,
                          steps: int) -> tuple[np.ndarray, int]:
    """Distances from ``points`` to the network's zero level set, and how many fell back to the MC mesh.

    Each distance is to an actual point of f = 0 (|f| ≤ :data:`ZERO_SET_TOL`), the nearer of two: the
    closest point of the marching-cubes mesh projected onto f = 0, and the point itself projected. The
    marching-cubes mesh alone can be off by its own error at thin tips (it cuts a tip thinner than a voxel);
    points whose projections both fail keep their distance to that mesh.
    """
    best = np.full(points.shape[0], np.inf)
    for start in (mc_closest, points):
        cand = _project(model, start, steps)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(cand).all(axis=1) & (np.abs(_values(model, cand)) <= ZERO_SET_TOL)
        d = np.linalg.norm(points - cand, axis=1)
        best = np.where(ok & (d < best), d, best)
    fallback = ~np.isfinite(best)
    return np.where(fallback, mc_dist, best), int(fallback.sum())


def sdf_metrics(model, mesh: Mesh, *, n: int = 100_000, seed: int = 0, resolution: int = 128,
                newton_steps: int = 2, truth_normal: Callable[[np.ndarray], np.ndarray] | None = None) -> dict:
    """Chamfer-L1, Hausdorff and normal angular error of the SDF ``model`` against ``mesh`` (unit frame).

    Args:
        model: a :class:`~neural_bake.nets.siren.Siren` f: R³ → R in the mesh's unit frame.
        mesh: the source :class:`~neural_bake.types.Mesh`; its surface faces
            (:func:`~neural_bake.fit.sampling.surface_faces`, not those buried in another shell) are compared.
        n: samples on each surface.
        seed: seeds the samples.
        resolution: marching-cubes grid resolution over [-1, 1]³.
        newton_steps: projection steps of the network samples onto f = 0 (0: use the marching-cubes points).
        truth_normal: the outward unit normals of the smooth surface the mesh approximates, as a callable of
            (N, 3) unit-frame points (e.g. a sample's analytic ``normal`` composed with
            ``mesh.frame.to_source``). The normal error against the mesh (its faces' normals) cannot fall
            below the mesh's own faceting; with ``truth_normal`` the result also holds ∇f's error against the
            smooth surface (``normal_truth_*``) and, for comparison, the mesh's face normals' error against it
            (``mesh_normal_truth_*``: what the mesh itself gives), at the same mesh samples.

    Returns:
        ``{"chamfer_l1", "hausdorff", "normal_median_deg", "normal_mean_deg", "normal_p95_deg",
        "net_to_mesh_mean", "mesh_to_net_mean", "net_to_mesh_max", "mesh_to_net_max", "mesh_to_net_fallback",
        "n", "resolution"}``, plus with ``truth_normal`` ``"normal_truth_median_deg"``,
        ``"normal_truth_p95_deg"``, ``"mesh_normal_truth_median_deg"``, ``"mesh_normal_truth_p95_deg"``
        (distances in unit-frame units; multiply by ``1 / mesh.frame.scale`` for source units).

    Raises:
        FitError: n < 1, a resolution < 8, a network with no zero crossing in [-1, 1]³, or a ``truth_normal``
        that does not return finite (n, 3) non-zero normals.
    """
    if int(n) != n or n < 1:
        raise FitError(f"sdf_metrics: n must be a positive integer, got {n!r}")
    if int(resolution) != resolution or resolution < 8:
        raise FitError(f"sdf_metrics: resolution must be an integer >= 8, got {resolution!r}")
    from .sampling import sample_surface, surface_faces

    rng = np.random.default_rng([seed, 7])
    surf = sample_surface(mesh, int(n), seed=seed)
    surf_pts = surf.points.astype(np.float64)
    truth = _truth_normals(truth_normal, surf_pts) if truth_normal is not None else None  # checked before the work
    mv, mf = zero_level_mesh(model, int(resolution))
    net_pts, _ = _sample_triangles(mv, mf, int(n), rng)
    if newton_steps:
        proj = _project(model, net_pts, int(newton_steps))
        # keep the projection only where it stayed close (a Newton step can jump off near critical points)
        moved = np.linalg.norm(proj - net_pts, axis=1)
        net_pts = np.where((moved < 4 * 2.0 / (resolution - 1))[:, None] & np.isfinite(proj), proj, net_pts)
    keep, _ = surface_faces(mesh)  # the solid's boundary: not the faces buried in another shell
    d_net = _closest_distance(mesh.vertices, mesh.faces[keep], net_pts)
    d_mesh, closest = _closest(mv, mf, surf_pts)
    fallback = int(n)
    if newton_steps:
        d_mesh, fallback = _distance_to_zero_set(model, surf_pts, closest, d_mesh, int(newton_steps))

    p = next(model.parameters())
    _, g = gemm_gradient(model, torch.as_tensor(surf.points, dtype=p.dtype, device=p.device))
    unit, valid = normalized_gradient(g)
    unit, invalid = unit.double().cpu().numpy(), ~valid.cpu().numpy()
    ang = angular_error(unit, surf.normals)
    ang[invalid] = 180.0  # no gradient direction: counted as the worst error
    out = {}
    if truth is not None:
        ours, faces = angular_error(unit, truth), angular_error(surf.normals, truth)
        ours[invalid] = 180.0
        out = {"normal_truth_median_deg": float(np.median(ours)),
               "normal_truth_p95_deg": float(np.percentile(ours, 95)),
               "mesh_normal_truth_median_deg": float(np.median(faces)),
               "mesh_normal_truth_p95_deg": float(np.percentile(faces, 95))}
    return {
        "chamfer_l1": 0.5 * (float(d_net.mean()) + float(d_mesh.mean())),
        "hausdorff": max(float(d_net.max()), float(d_mesh.max())),
        "normal_median_deg": float(np.median(ang)),
        "normal_mean_deg": float(ang.mean()),
        "normal_p95_deg": float(np.percentile(ang, 95)),
        "net_to_mesh_mean": float(d_net.mean()), "mesh_to_net_mean": float(d_mesh.mean()),
        "net_to_mesh_max": float(d_net.max()), "mesh_to_net_max": float(d_mesh.max()),
        "mesh_to_net_fallback": fallback,
        "n": int(n), "resolution": int(resolution),
        **out,
    }


def _truth_normals(truth_normal, points: np.ndarray) -> np.ndarray:
    """``truth_normal(points)`` checked (finite, (N, 3), no zero rows) and normalised; FitError otherwise."""
    t = np.asarray(truth_normal(points), dtype=np.float64)
    if t.shape != points.shape:
        raise FitError(f"sdf_metrics: truth_normal must return ({points.shape[0]}, 3) normals, got {t.shape}")
    norm = np.linalg.norm(t, axis=1, keepdims=True)
    if not np.isfinite(t).all() or (norm < DIRECTION_EPS).any():
        raise FitError("sdf_metrics: truth_normal returned non-finite or zero normals at mesh samples")
    return t / norm
