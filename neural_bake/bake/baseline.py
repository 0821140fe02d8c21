"""The classical baseline: a mesh-to-mesh bake from the coarse surface to the high-resolution mesh.

What a user would otherwise do in a DCC tool: from each texel point of the coarse mesh, cast rays along
± its interpolated normal within a cage distance to the fine mesh (open3d's ``RaycastingScene``), take the
nearest hit, fall back to the closest point of the fine mesh when no ray hits, and read the fine mesh's
interpolated vertex normal and texture colour there.
"""

from __future__ import annotations

import ctypes
import time
from pathlib import Path

import numpy as np

from ..constants import DIRECTION_EPS
from ..errors import MeshError, NeuralBakeError
from ..geometry import import_open3d, interpolate_corners
from ..geometry import raycasting_scene as _shared_scene
from ..nets.native import Kernel, threads
from ..types import Mesh

__all__ = ["baseline_bake", "closest_surface", "raycasting_scene", "kernel_status", "ENV_SWITCH"]

#: Default cage distance in unit-frame units (the unit frame's longest side is 1.8).
DEFAULT_CAGE = 0.05

#: 0/off/false: the numpy path even where the C kernel (baseline.c) builds (A/B checks).
ENV_SWITCH = "NEURAL_BAKE_NATIVE_BASELINE"


def _declare(lib) -> None:
    p, i64, f64 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
    lib.nb_rays.argtypes = [p, p, p, i64, p, i64]
    lib.nb_rays.restype = None
    lib.nb_pick_hits.argtypes = [p, p, p, i64, f64, p, p, p, i64]
    lib.nb_pick_hits.restype = None
    lib.nb_shade.argtypes = [p, p, p, p, p, i64, f64, p, p, i64]
    lib.nb_shade.restype = None


#: The C kernel (baseline.c, :class:`neural_bake.nets.native.Kernel`; the samples on torch's OpenMP team where it
#: shares it); numpy where it does not build.
KERNEL = Kernel(Path(__file__).with_name("baseline.c"), switch=ENV_SWITCH, declare=_declare, openmp=True)


def kernel_status() -> str:
    """Which ray set-up, hit choice and shading of the classical bake run here: the C kernel (and its file), or why
    numpy does."""
    return KERNEL.status()


def _ptr(a: np.ndarray) -> int:
    return a.ctypes.data


def _rays(lib, points: np.ndarray, normals: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
    """(2n, 6) float32 rays of the rows ``index`` (n,) of ``points`` (M, 3) (None: all of them, n = M): along +
    ``normals`` (M, 3) for the first n, − for the next n; the rows read by the C kernel itself where it builds."""
    if lib is None:
        if index is not None:
            points, normals = points[index], normals[index]
        return np.concatenate([np.concatenate([points, normals], axis=1),
                               np.concatenate([points, -normals], axis=1)]).astype(np.float32)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    nrm = np.ascontiguousarray(normals, dtype=np.float64)
    rows = None if index is None else np.ascontiguousarray(index, dtype=np.int64)
    n = len(pts) if rows is None else len(rows)
    rays = np.empty((2 * n, 6), dtype=np.float32)
    lib.nb_rays(_ptr(pts), _ptr(nrm), None if rows is None else _ptr(rows), n, _ptr(rays), threads())
    return rays


def _pick_hits(lib, t_hit: np.ndarray, prim: np.ndarray, uvs: np.ndarray, m: int,
               cage: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(distance (M,), face (M,) int64, barycentrics (M, 2)) of each sample's nearer hit of its two rays (open3d's
    ``t_hit``, ``primitive_ids``, ``primitive_uvs`` of :func:`_rays`' 2M rays) finite and within ``cage``, the + ray's
    on a tie; (inf, 0, 0) where neither hits."""
    best_t = np.full(m, np.inf)
    best_prim = np.zeros(m, dtype=np.int64)
    best_uv = np.zeros((m, 2))
    if lib is not None:
        t = np.ascontiguousarray(t_hit, dtype=np.float32)
        ids = np.ascontiguousarray(prim, dtype=np.uint32)
        uv = np.ascontiguousarray(uvs, dtype=np.float32)
        lib.nb_pick_hits(_ptr(t), _ptr(ids), _ptr(uv), m, float(cage), _ptr(best_t), _ptr(best_prim), _ptr(best_uv),
                         threads())
        return best_t, best_prim, best_uv
    for side in (0, 1):
        t = np.asarray(t_hit[side * m: (side + 1) * m], dtype=np.float64)
        better = np.isfinite(t) & (t <= cage) & (t < best_t)
        best_t[better] = t[better]
        best_prim[better] = prim[side * m: (side + 1) * m][better]
        best_uv[better] = uvs[side * m: (side + 1) * m][better]
    return best_t, best_prim, best_uv


def raycasting_scene(fine: Mesh):
    """open3d ``RaycastingScene`` of ``fine`` (its unit frame), shared with every stage that queries the same
    triangles (:func:`neural_bake.geometry.raycasting_scene`)."""
    return _shared_scene(fine.vertices, fine.faces)


def _interp(fine: Mesh, prim: np.ndarray, uvs: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Interpolate per-corner ``values`` (F, 3, C) at open3d barycentrics: (1−u−v)·v0 + u·v1 + v·v2."""
    w = np.stack([1.0 - uvs[:, 0] - uvs[:, 1], uvs[:, 0], uvs[:, 1]], axis=1)
    return interpolate_corners(values, prim, w)


def closest_surface(fine: Mesh, points: np.ndarray, *, scene=None) -> dict:
    """Closest points of ``fine`` to ``points`` (M, 3) (both unit frame of ``fine``); ``scene``: a
    :func:`raycasting_scene` of ``fine`` to reuse (default: built here).

    Returns ``{"points" (M, 3), "face" (M,), "bary" (M, 3) (weights of the face's corners),
    "normals" (M, 3) interpolated unit vertex normals, "distance" (M,)}``.
    """
    from ..geometry import vertex_normals

    if scene is None:
        scene = raycasting_scene(fine)
    o3d = import_open3d()

    q = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))
    res = scene.compute_closest_points(q, nthreads=threads())  # the bake's thread choice, not every core
    prim = res["primitive_ids"].numpy().astype(np.int64)
    uvs = res["primitive_uvs"].numpy().astype(np.float64)
    pts = res["points"].numpy().astype(np.float64)
    n = _interp(fine, prim, uvs, vertex_normals(fine)[fine.faces])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), DIRECTION_EPS)
    bary = np.stack([1.0 - uvs[:, 0] - uvs[:, 1], uvs[:, 0], uvs[:, 1]], axis=1)
    return {"points": pts, "face": prim, "bary": bary, "normals": n, "distance": np.linalg.norm(pts - points, axis=1)}


def baseline_bake(coarse: Mesh, fine: Mesh, texels, *, cage: float | None = None, scene=None,
                  fine_normals: np.ndarray | None = None, index: np.ndarray | None = None, colors: bool = True) -> dict:
    """Mesh-to-mesh bake of ``fine`` onto the texel samples of ``coarse``.

    - ``coarse``: the mesh ``texels`` were rasterised on (``Baker.mesh``); its frame maps the texel points
      into ``fine``'s unit frame if the two differ.
    - ``fine``: the high-resolution mesh (with ``uv`` and ``texture`` for colours).
    - ``texels``: a :class:`~neural_bake.mesh.texels.TexelSet` (``points``, ``normal`` (M, 3); ``face`` and
      ``bary`` where ``coarse`` is ``fine``).
    - ``cage``: ray length on each side of the coarse surface, unit frame of ``fine``
      (default :data:`DEFAULT_CAGE`).
    - ``scene``: a :func:`raycasting_scene` of ``fine`` to reuse (e.g. over the bands of a streamed bake);
      default: built here (its time is ``seconds["setup"]``).
    - ``fine_normals``: ``fine``'s (V, 3) unit vertex normals (:func:`~neural_bake.geometry.vertex_normals`) to
      reuse; default: computed here.
    - ``index``: (n,) the samples of ``texels`` to bake (default: all; the result then holds n rows).
    - ``colors``: read ``fine``'s texture at the chosen points (where it has one); False: ``"colors"`` is None
      (a bake of normals alone skips the texture reads).

    When ``coarse`` is ``fine`` itself (:func:`same_surface`: a bake onto the source, ``--coarse keep``), each
    sample's own face and barycentrics are its point of ``fine``: no rays, and no neighbouring or coincident face
    (boards back to back) can take its place.

    Returns ``{"normals": (M, 3) unit object-space normals of the fine mesh, "colors": (M, C) linear or
    None, "points": (M, 3) the chosen points on the fine mesh (its unit frame), "hit": (M,) bool (a ray hit
    within the cage), "fallback": misses resolved by the closest point, "distance": (M,) distance to the
    chosen point, "cage", "seconds": {"setup", "rays", "closest", "shade", "total"}}``.
    """
    if cage is None:
        cage = DEFAULT_CAGE
    if not (np.isfinite(cage) and cage > 0):
        raise NeuralBakeError(f"baseline cage must be a positive distance, got {cage!r}")
    if fine.n_faces == 0:
        raise MeshError(f"{fine.name}: baseline: the fine mesh has no faces")
    t_all = time.perf_counter()
    pick = (lambda a: a) if index is None else (lambda a: a[index])
    if getattr(texels, "face", None) is not None and getattr(texels, "bary", None) is not None \
            and same_surface(coarse, fine):
        bary = pick(np.asarray(texels.bary, dtype=np.float64))
        m = len(bary)
        return _shade(fine, pick(np.asarray(texels.face, dtype=np.int64)), bary[:, 1:3], np.ones(m, dtype=bool),
                      np.zeros(m), cage, t_all, {"setup": 0.0, "rays": 0.0, "closest": 0.0}, fine_normals, colors)
    o3d = import_open3d()
    lib = KERNEL.lib()
    if scene is None:
        scene = raycasting_scene(fine)
    t_setup = time.perf_counter() - t_all

    t0 = time.perf_counter()
    all_points = np.asarray(texels.points, dtype=np.float64)
    pts: np.ndarray | None = None
    if index is not None and lib is not None and coarse.frame == fine.frame:
        index = np.ascontiguousarray(index, dtype=np.int64)
        m = len(index)
        rays = _rays(lib, all_points, np.asarray(texels.normal, dtype=np.float64), index)  # rows read in C
    else:
        pts = pick(all_points)
        if coarse.frame != fine.frame:
            pts = fine.frame.to_unit(coarse.frame.to_source(pts))
        m = len(pts)
        rays = _rays(lib, pts, pick(np.asarray(texels.normal, dtype=np.float64)))
    # both directions in one cast, on the bake's threads (measured or fixed), not open3d's default of every core
    res = scene.cast_rays(o3d.core.Tensor(rays), nthreads=threads())
    best_t, prim, uvs = _pick_hits(lib, res["t_hit"].numpy(), res["primitive_ids"].numpy(),
                                   res["primitive_uvs"].numpy(), m, cage)
    hit = np.isfinite(best_t)
    t_rays = time.perf_counter() - t0

    t0 = time.perf_counter()
    dist = best_t.copy()
    if (~hit).any():
        if pts is None:
            pts = np.zeros((m, 3))
            pts[~hit] = all_points[index[~hit]]
        q = o3d.core.Tensor(np.ascontiguousarray(pts[~hit], dtype=np.float32))
        res = scene.compute_closest_points(q, nthreads=threads())
        prim[~hit] = res["primitive_ids"].numpy()
        uvs[~hit] = res["primitive_uvs"].numpy()
        dist[~hit] = np.linalg.norm(res["points"].numpy() - pts[~hit], axis=1)
    t_closest = time.perf_counter() - t0
    return _shade(fine, prim, uvs, hit, dist, cage, t_all, {"setup": t_setup, "rays": t_rays, "closest": t_closest},
                  fine_normals, colors)


def _shade_points(lib, fine: Mesh, prim: np.ndarray, uvs: np.ndarray,
                  fine_normals: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(unit normals (M, 3), points (M, 3)) of ``fine`` at faces ``prim`` (M,) and open3d barycentrics ``uvs``
    (M, 2): its vertex normals (``fine_normals``, or computed) and corners blended, the normals renormalised."""
    from ..geometry import vertex_normals

    vn = vertex_normals(fine) if fine_normals is None else fine_normals
    if lib is None:
        normals = _interp(fine, prim, uvs, vn[fine.faces])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), DIRECTION_EPS)
        return normals, _interp(fine, prim, uvs, fine.triangles)
    m = len(prim)
    vert = np.ascontiguousarray(fine.vertices, dtype=np.float64)
    vn = np.ascontiguousarray(vn, dtype=np.float64)
    faces = np.ascontiguousarray(fine.faces, dtype=np.int64)
    ids = np.ascontiguousarray(prim, dtype=np.int64)
    uv = np.ascontiguousarray(uvs, dtype=np.float64)
    normals, points = np.empty((m, 3)), np.empty((m, 3))
    lib.nb_shade(_ptr(vert), _ptr(vn), _ptr(faces), _ptr(ids), _ptr(uv), m, float(DIRECTION_EPS), _ptr(normals),
                 _ptr(points), threads())
    return normals, points


def same_surface(coarse: Mesh, fine: Mesh) -> bool:
    """Whether ``coarse`` is ``fine`` itself: the same object, or the same frame and the same triangles in the same
    order (its vertices may be split where its UVs are, as a bake's layout splits them)."""
    if coarse is fine:
        return True
    return (coarse.frame == fine.frame and np.shape(coarse.faces) == np.shape(fine.faces)
            and np.array_equal(coarse.triangles, fine.triangles))


def _shade(fine: Mesh, prim: np.ndarray, uvs: np.ndarray, hit: np.ndarray, dist: np.ndarray, cage: float,
           t_all: float, seconds: dict, fine_normals: np.ndarray | None = None, colors: bool = True) -> dict:
    """:func:`baseline_bake`'s result from each sample's face ``prim`` and barycentrics ``uvs`` (open3d's)."""
    from ..io.colour import sample_texture

    t0 = time.perf_counter()
    normals, points = _shade_points(KERNEL.lib(), fine, prim, uvs, fine_normals)
    read = None
    if colors and fine.uv is not None and fine.texture is not None:
        uv = _interp(fine, prim, uvs, np.asarray(fine.uv, dtype=np.float64))
        read = sample_texture(fine.texture, uv, fine.uv_policy).astype(np.float64)
    return {
        "normals": normals,
        "colors": read,
        "points": points,
        "hit": hit,
        "fallback": int((~hit).sum()),
        "distance": dist,
        "cage": float(cage),
        "seconds": {**seconds, "shade": time.perf_counter() - t0, "total": time.perf_counter() - t_all},
    }
