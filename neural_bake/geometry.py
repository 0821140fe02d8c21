"""Small geometric measures that loading, fitting, baking and rendering all use (numpy; no stage imports):
angles, frame agreement, area-weighted vertex normals (of arrays, or of a mesh), a mesh's sampleable faces,
the edge report, one cached open3d ray-casting scene per triangle set, and open3d's import itself (its web
visualiser deferred: :func:`import_open3d`)."""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import importlib.util
import re
import sys
import threading
import types
from collections import OrderedDict
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import MeshError
from .constants import DEGENERATE_AREA, DIRECTION_EPS, FRAME_MISMATCH_TOL, RAYCAST_SCENE_CACHE, SDF_MISMATCH_MEDIAN, UNDERFLOW_EPS

__all__ = ["angular_error", "area_weighted_normals", "check_points", "edge_report", "finish_prefetch",
           "frame_mismatch", "import_open3d", "interpolate_corners", "mismatch_problem", "prefetch_raycasting",
           "raycasting_prefetched", "raycasting_scene", "sampleable_faces", "vertex_normals",
           "web_visualiser_deferrable", "welded_edges"]


def angular_error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(M,) float64 angles in degrees between the directions of rows ``a`` and ``b`` (M, 3), any float dtype.

    Measured as atan2(|a × b|, a · b) in float64: accurate at every angle (identical rows give exactly 0°,
    opposite rows exactly 180°), where arccos of the dot product loses digits near 0° and 180°. The rows need
    not be unit; a row shorter than ``DIRECTION_EPS`` has no direction and gives 90°.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    # the cross product by components (np.cross moves axes and copies: several times slower on (M, 3))
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    sin = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    cos = a0 * b0 + a1 * b1 + a2 * b2
    out = np.degrees(np.arctan2(sin, cos))
    eps2 = DIRECTION_EPS * DIRECTION_EPS
    undefined = (a0 * a0 + a1 * a1 + a2 * a2 < eps2) | (b0 * b0 + b1 * b1 + b2 * b2 < eps2)
    return np.where(undefined, 90.0, out)


def interpolate_corners(values: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Per-corner ``values`` (F, 3, C) interpolated at points on faces ``face`` (M,) with barycentric weights
    ``bary`` (M, 3) (corner k of the face weighted by ``bary[:, k]``): (M, C) float64. One gather per corner
    (``np.take``), not an (M, 3, C) gather."""
    values = np.asarray(values, dtype=np.float64)
    face = np.asarray(face, dtype=np.int64)
    bary = np.asarray(bary, dtype=np.float64)
    out = np.take(values[:, 0, :], face, axis=0) * bary[:, 0:1]
    for k in (1, 2):
        out += np.take(values[:, k, :], face, axis=0) * bary[:, k: k + 1]
    return out


def frame_mismatch(a, b) -> float:
    """How far apart two :class:`~neural_bake.types.Frame` s are, in unit-frame terms: the larger of the centre
    offset measured in ``b``'s unit frame and the relative scale difference |s_a / s_b − 1|."""
    offset = float(np.linalg.norm(np.subtract(a.center, b.center))) * float(b.scale)
    return max(offset, abs(float(a.scale) / float(b.scale) - 1.0))


def mismatch_problem(agreement: dict, *, frames, surface) -> str | None:
    """The first failed check of an SDF against what it is meant to describe (a mesh, a texture's surface):
    ``agreement["frame_mismatch"]`` above ``FRAME_MISMATCH_TOL`` gives ``frames()``, else
    ``agreement["median_abs_f"]`` (None: not measured) above ``SDF_MISMATCH_MEDIAN`` gives ``surface()`` (each
    a callable returning the problem in words); None when both pass."""
    if agreement["frame_mismatch"] > FRAME_MISMATCH_TOL:
        return frames()
    median = agreement.get("median_abs_f")
    if median is not None and median > SDF_MISMATCH_MEDIAN:
        return surface()
    return None


def area_weighted_normals(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    exclude: np.ndarray | None = None,
    weld: bool = False,
    fallback: tuple[float, float, float] | None = None,
) -> np.ndarray:
    """(V, 3) float64 unit vertex normals: the sum of the incident faces' cross products (area weighting),
    normalised.

    - ``exclude``: (F,) bool, faces that contribute nothing (degenerate faces).
    - ``weld``: sum over every vertex at the same position, so the copies of a vertex split at a UV seam or
      a hard edge get one normal.
    - A vertex without a usable face gets ``fallback`` (for example +Z), or a zero row when it is None.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    t = v[f]
    fn = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])  # length = 2 × area
    if exclude is not None:
        fn = np.where(np.asarray(exclude, dtype=bool)[:, None], 0.0, fn)
    if weld and len(v):
        _, pid = np.unique(v, axis=0, return_inverse=True)
        pid = pid.reshape(-1)
    else:
        pid = np.arange(len(v))
    acc = np.zeros((int(pid.max()) + 1 if len(pid) else 0, 3))
    for k in range(3):
        np.add.at(acc, pid[f[:, k]], fn)
    n = acc[pid]
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    out = np.divide(n, norm, out=np.zeros_like(n), where=norm > UNDERFLOW_EPS)
    if fallback is not None:
        out[norm[:, 0] <= UNDERFLOW_EPS] = fallback
    return out


def vertex_normals(mesh) -> np.ndarray:
    """(V, 3) float64 unit outward vertex normals of a :class:`~neural_bake.types.Mesh`.

    ``mesh.vertex_normals`` when set (renormalised), otherwise :func:`area_weighted_normals` of its faces. A
    vertex without a usable normal (all its faces degenerate, no face, a zero stored row) gets +Z instead of
    a zero or NaN row.
    """
    if mesh.vertex_normals is None:
        return area_weighted_normals(mesh.vertices, mesh.faces, fallback=(0.0, 0.0, 1.0))
    n = np.asarray(mesh.vertex_normals, dtype=np.float64)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    out = np.divide(n, norm, out=np.zeros_like(n), where=norm > UNDERFLOW_EPS)
    out[norm[:, 0] <= UNDERFLOW_EPS] = (0.0, 0.0, 1.0)
    return out


def sampleable_faces(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Indices (K,) int64 and areas (K,) float64 of the faces of a :class:`~neural_bake.types.Mesh` that can be
    sampled or summed over: not ``mesh.degenerate``, finite area above ``DEGENERATE_AREA``.

    Raises :class:`~neural_bake.errors.MeshError` when there is none.
    """
    areas = mesh.face_areas
    ok = np.isfinite(areas) & (areas > DEGENERATE_AREA)
    if mesh.degenerate is not None:
        ok &= ~np.asarray(mesh.degenerate, dtype=bool)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        raise MeshError(f"{mesh.name}: no non-degenerate faces to sample ({mesh.n_faces} faces, all of zero area)")
    return idx, areas[idx]


def check_points(points, caller: str) -> np.ndarray:
    """``points`` as an (N, 3) float64 array; ``ValueError`` naming ``caller`` for another shape or a NaN or
    infinite coordinate."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{caller}: points must be (N, 3), got shape {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError(f"{caller}: points contain NaN or infinite values")
    return p


def welded_edges(mesh) -> tuple[np.ndarray, np.ndarray]:
    """The undirected edges of a :class:`~neural_bake.types.Mesh` whose vertices at the same position are one
    (a mesh split along its UV seams keeps its edges): ``(edge (3F,) int64, count (E,) int64)``, the edge of
    each face side — sides (0, 1) of every face, then (1, 2), then (2, 0), so side k of face f is row
    k·F + f — and the number of face sides on each edge (2 inside a manifold surface)."""
    _, weld = np.unique(np.asarray(mesh.vertices, dtype=np.float64), axis=0, return_inverse=True)
    f = weld.reshape(-1)[np.asarray(mesh.faces, dtype=np.int64)]
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    lo, hi = e.min(axis=1), e.max(axis=1)
    base = int(hi.max()) + 1 if len(hi) else 1  # one int64 key per undirected edge (a 1-D unique)
    _, edge, count = np.unique(lo * base + hi, return_inverse=True, return_counts=True)
    return edge.reshape(-1).astype(np.int64), count.astype(np.int64)


def edge_report(faces: np.ndarray) -> dict:
    """Edge statistics of a face list (F, 3) int: ``{"edges", "boundary_edges", "non_manifold_edges",
    "inconsistent_edges", "watertight"}``.

    Faces with a repeated corner have no area and no edges; they are left out. A boundary edge has one face,
    a non-manifold edge more than two; an inconsistent edge is shared by two faces that traverse it in the
    same direction (flipped winding). ``watertight``: there are edges, and every edge has exactly two faces
    and consistent winding.
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    distinct = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces = faces[distinct]
    if len(faces) == 0:
        return {"edges": 0, "boundary_edges": 0, "non_manifold_edges": 0, "inconsistent_edges": 0, "watertight": False}
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    lo, hi = e.min(axis=1), e.max(axis=1)
    base = int(hi.max()) + 1  # one int64 key per undirected edge: a 1-D unique, several times faster than rows
    und, inv, cnt = np.unique(lo * base + hi, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    forward = (e[:, 0] < e[:, 1]).astype(np.int64)
    n_forward = np.bincount(inv, weights=forward, minlength=len(und))
    two = cnt == 2
    inconsistent = int((two & (n_forward != 1)).sum())
    return {
        "edges": int(len(und)),
        "boundary_edges": int((cnt == 1).sum()),
        "non_manifold_edges": int((cnt > 2).sum()),
        "inconsistent_edges": inconsistent,
        "watertight": bool(two.all() and inconsistent == 0),
    }


#: open3d's web visualiser: its package imports it unconditionally, and it imports plotly and dash (about 0.75 s
#: of interpreter-bound work a process, beside every other stage's) for functions no stage of ours calls.
_WEB_VISUALISER = "open3d.visualization.draw_plotly"

#: The names open3d's ``visualization`` package imports from it (0.18–0.20): all functions.
_WEB_VISUALISER_NAMES = frozenset({"get_plotly_fig", "draw_plotly", "draw_plotly_server"})

_OPEN3D_LOCK = threading.Lock()


class _DeferredWebVisualiser(types.ModuleType):
    """Holds ``open3d.visualization.draw_plotly``'s place in ``sys.modules`` while open3d imports: each of its
    functions the package asks for is a stand-in that imports the real module on its first call and calls the
    real function (which stays in the module from then on)."""

    def __getattr__(self, name: str):
        if name not in _WEB_VISUALISER_NAMES:
            raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")

        def call(*args, **kwargs):
            return getattr(_web_visualiser(), name)(*args, **kwargs)

        call.__name__ = call.__qualname__ = name
        call.__doc__ = f"open3d.visualization.{name}: open3d's own, imported on its first call."
        return call


def _web_visualiser() -> types.ModuleType:
    """open3d's real web-visualiser module, imported in place of the stand-in if that is still there."""
    with _OPEN3D_LOCK:
        if isinstance(sys.modules.get(_WEB_VISUALISER), _DeferredWebVisualiser):
            del sys.modules[_WEB_VISUALISER]
    return importlib.import_module(_WEB_VISUALISER)


def web_visualiser_deferrable(source: str) -> bool:
    """Whether open3d's ``visualization/__init__.py`` (its ``source``) uses its web visualiser only by importing
    functions the stand-in knows (:data:`_WEB_VISUALISER_NAMES`): every line naming ``draw_plotly`` is a
    ``from .draw_plotly import …`` of those names."""
    lines = [line.strip() for line in source.splitlines() if "draw_plotly" in line]
    names: set[str] = set()
    for line in lines:
        m = re.fullmatch(r"from \.draw_plotly import ([\w, ]+)", line)
        if m is None:
            return False
        names |= {n.strip() for n in m.group(1).split(",") if n.strip()}
    return bool(names) and names <= _WEB_VISUALISER_NAMES


def import_open3d() -> types.ModuleType:
    """``import open3d``, its web visualiser (plotly, dash) imported only if one of its functions is called.

    The stand-in (:class:`_DeferredWebVisualiser`) is put in place only before open3d's first import in the
    process, and only when its ``visualization`` package imports nothing else of that module
    (:func:`web_visualiser_deferrable`); otherwise this is a plain import. Import errors are open3d's own."""
    with _OPEN3D_LOCK:
        deferred = False
        if "open3d" not in sys.modules and _WEB_VISUALISER not in sys.modules:
            spec = importlib.util.find_spec("open3d")
            init = None
            if spec is not None and spec.submodule_search_locations:
                init = Path(list(spec.submodule_search_locations)[0]) / "visualization" / "__init__.py"
            try:
                deferred = init is not None and web_visualiser_deferrable(init.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError):
                deferred = False
            if deferred:
                sys.modules[_WEB_VISUALISER] = _DeferredWebVisualiser(_WEB_VISUALISER)
    try:
        import open3d
    except BaseException:
        if deferred:
            with _OPEN3D_LOCK:
                if isinstance(sys.modules.get(_WEB_VISUALISER), _DeferredWebVisualiser):
                    del sys.modules[_WEB_VISUALISER]
        raise
    return open3d


_SCENES: OrderedDict[bytes, RaycastScene] = OrderedDict()
_SCENES_LOCK = threading.Lock()
_PREFETCH: list[threading.Thread] = []


def prefetch_raycasting() -> None:
    """Start importing open3d (what :func:`raycasting_scene` needs) in a background thread, once per process,
    so a job that will cast rays later pays for the import while it does other work (loading, coarsening,
    rasterising). The first :func:`raycasting_scene` waits for it; an import error surfaces there."""
    with _SCENES_LOCK:
        if _PREFETCH:
            return

        def load():
            try:
                import_open3d()
            except Exception:  # noqa: BLE001 - raycasting_scene imports it again and raises there
                pass

        t = threading.Thread(target=load, name="prefetch-open3d", daemon=True)
        _PREFETCH.append(t)
    t.start()


def finish_prefetch() -> None:
    """Wait for :func:`prefetch_raycasting`'s import to end (if one was started): a process must not exit while
    an extension module is half-loaded in another thread (open3d's exit then fails)."""
    for t in list(_PREFETCH):
        t.join()


@contextlib.contextmanager
def raycasting_prefetched() -> Iterator[None]:
    """:func:`prefetch_raycasting` for the block, and :func:`finish_prefetch` on leaving it, however it ends."""
    prefetch_raycasting()
    try:
        yield
    finally:
        finish_prefetch()


#: The queries of open3d's ``RaycastingScene`` that take ``nthreads`` (0: every core).
SCENE_QUERIES = ("cast_rays", "compute_closest_points", "compute_distance", "compute_signed_distance",
                 "compute_occupancy", "count_intersections", "list_intersections", "test_occlusions")


def query_threads() -> int:
    """The threads an open3d query runs with when its caller names none: torch's thread count (what the thread
    probe or ``--threads`` set), so a query shares the cores the run chose instead of taking every core (which
    slows it many times when another program holds one); 0 (open3d's every core) where torch is not loaded."""
    torch = sys.modules.get("torch")
    return max(1, int(torch.get_num_threads())) if torch is not None else 0


class RaycastScene:
    """An open3d ``RaycastingScene`` whose queries (:data:`SCENE_QUERIES`) run with :func:`query_threads`
    unless given ``nthreads``; everything else is the scene's own (``scene.scene``: the open3d object)."""

    __slots__ = ("scene",)

    def __init__(self, scene) -> None:
        self.scene = scene

    def __getattr__(self, name: str):
        if name == "scene":  # not set yet (a copy being built): no recursion through it
            raise AttributeError(name)
        attr = getattr(self.scene, name)
        if name not in SCENE_QUERIES:
            return attr

        def query(*args, nthreads: int | None = None, **kwargs):
            return attr(*args, nthreads=query_threads() if nthreads is None else int(nthreads), **kwargs)

        return query


def raycasting_scene(vertices: np.ndarray, faces: np.ndarray) -> RaycastScene:
    """open3d ``RaycastingScene`` of the triangles ``vertices[faces]`` (float32 BVH) as a :class:`RaycastScene`
    (its queries on the run's threads), built once per triangle set: scenes are cached by the content of both
    arrays (the last ``RAYCAST_SCENE_CACHE`` sets), so every stage that queries the same mesh shares one BVH.
    Query it; do not add geometry to it."""
    o3d = import_open3d()

    v = np.ascontiguousarray(vertices, dtype=np.float32)
    f = np.ascontiguousarray(faces, dtype=np.uint32).reshape(-1, 3)
    h = hashlib.blake2b(str((v.shape, f.shape)).encode(), digest_size=16)
    h.update(v.tobytes())
    h.update(f.tobytes())
    digest = h.digest()
    with _SCENES_LOCK:
        scene = _SCENES.get(digest)
        if scene is not None:
            _SCENES.move_to_end(digest)
            return scene
    built = o3d.t.geometry.RaycastingScene()
    built.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(f))
    scene = RaycastScene(built)
    with _SCENES_LOCK:
        _SCENES[digest] = scene
        while len(_SCENES) > RAYCAST_SCENE_CACHE:
            _SCENES.popitem(last=False)
    return scene
