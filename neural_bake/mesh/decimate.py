"""Coarse meshes by decimation: pymeshlab's quadric edge collapse (Garland & Heckbert), after a fast first pass
on large meshes."""

from __future__ import annotations

import math
import threading
import warnings

import numpy as np

from ..constants import DEGENERATE_AREA
from ..errors import MeshError, NeuralBakeError, NeuralBakeWarning
from ..types import Mesh

__all__ = ["decimate", "first_pass_faces", "merge_duplicate_vertices"]

#: A large mesh is first brought to ``max(FIRST_PASS_FACTOR × target, FIRST_PASS_MIN)`` faces by
#: fast-simplification's quadric collapse, when that is at most half its faces; pymeshlab's careful collapse then
#: makes the target from there. On the data folder's 70k–124k-face scans, to 2,000 faces: 3.6–5× faster, and as
#: close to the fine mesh (BENCHMARKS.md, "coarse").
FIRST_PASS_FACTOR = 8
FIRST_PASS_MIN = 16_000

# fast-simplification keeps its mesh in module state: one call at a time
_FIRST_PASS_LOCK = threading.Lock()


def merge_duplicate_vertices(mesh: Mesh) -> tuple[Mesh, np.ndarray]:
    """Weld vertices with bit-identical positions (UV-seam splits of a loaded mesh).

    Returns (mesh, (V,) int64 new index of each old vertex). Faces keep their order, winding and
    per-corner UVs; ``vertex_normals`` are dropped (recomputed by whoever needs them).
    """
    uniq, first, inv = np.unique(mesh.vertices, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1).astype(np.int64)
    order = np.argsort(first)  # keep the original vertex order
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    remap = rank[inv]
    out = Mesh(
        vertices=mesh.vertices[np.sort(first)].copy(),
        faces=remap[mesh.faces],
        uv=None if mesh.uv is None else mesh.uv.copy(),
        texture=mesh.texture,
        vertex_normals=None,
        frame=mesh.frame,
        degenerate=mesh.degenerate,
        uv_policy=mesh.uv_policy,
        watertight=mesh.watertight,
        source=mesh.source,
        warnings=list(mesh.warnings),
    )
    return out, remap


def _load_via_obj(ms, mesh: Mesh) -> None:
    """Load ``mesh`` with its per-corner UVs into the pymeshlab MeshSet ``ms`` through a temporary OBJ."""
    import os
    import tempfile

    uv = mesh.uv.reshape(-1, 2)
    with tempfile.TemporaryDirectory(prefix="neural_bake_") as d:
        path = os.path.join(d, "mesh.obj")
        with open(os.path.join(d, "mesh.mtl"), "w") as fh:
            fh.write("newmtl uv\nmap_Kd uv.png\n")
        idx = np.arange(1, 3 * mesh.n_faces + 1).reshape(-1, 3)
        corners = np.stack([mesh.faces + 1, idx], axis=2).reshape(-1, 6)
        with open(path, "w") as fh:
            fh.write("mtllib mesh.mtl\n")
            np.savetxt(fh, mesh.vertices, fmt="v %.17g %.17g %.17g")
            np.savetxt(fh, uv, fmt="vt %.17g %.17g")
            fh.write("usemtl uv\n")
            np.savetxt(fh, corners, fmt="f %d/%d %d/%d %d/%d")
        ms.load_new_mesh(path)


def _face_target(mesh: Mesh, faces: int | None, ratio: float | None) -> int:
    if (faces is None) == (ratio is None):
        raise NeuralBakeError("decimate: give exactly one of faces= or ratio=")
    if faces is not None:
        if int(faces) != faces or faces < 4:
            raise NeuralBakeError(f"decimate: faces must be an integer >= 4, got {faces!r}")
        return int(faces)
    if not (isinstance(ratio, (int, float)) and math.isfinite(ratio) and 0 < ratio <= 1):
        raise NeuralBakeError(f"decimate: ratio must be in (0, 1], got {ratio!r}")
    return max(4, int(round(mesh.n_faces * ratio)))


def first_pass_faces(n_faces: int, target: int) -> int | None:
    """The face count of the fast first pass for a mesh of ``n_faces`` decimated to ``target``, or None (no first
    pass: the mesh is not at least twice that)."""
    first = max(FIRST_PASS_FACTOR * int(target), FIRST_PASS_MIN)
    return first if 2 * first <= int(n_faces) else None


def _first_pass(vertices: np.ndarray, faces: np.ndarray, target: int, keep_boundary: bool) -> tuple:
    """fast-simplification's collapse of (vertices, faces) to about ``target`` faces (open borders kept)."""
    import fast_simplification

    with _FIRST_PASS_LOCK:
        v, f = fast_simplification.simplify(np.ascontiguousarray(vertices, dtype=np.float64),
                                            np.ascontiguousarray(faces, dtype=np.int64), target_count=int(target),
                                            agg=7, preserve_border=bool(keep_boundary))
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int32)


def decimate(
    mesh: Mesh,
    *,
    faces: int | None = None,
    ratio: float | None = None,
    keep_boundary: bool = True,
    keep_uv: bool = False,
    quality_threshold: float = 0.3,
    preserve_normal: bool = True,
    preserve_topology: bool = False,
    boundary_weight: float = 1.0,
    first_pass: bool = True,
) -> Mesh:
    """Decimate ``mesh`` to ``faces`` triangles (or ``ratio`` × its face count) by quadric edge collapse.

    Vertices with identical positions are welded first (so UV seams of a loaded mesh do not become
    holes). ``keep_boundary``: open boundaries are preserved (pymeshlab ``preserveboundary``).
    ``keep_uv`` and the mesh has UVs: the texture-aware variant
    (``meshing_decimation_quadric_edge_collapse_with_texture``) keeps per-corner UVs, and the result is
    split at UV seams (one UV per vertex) with its texture; otherwise UVs are dropped (unwrap the result).
    The result is in the same unit frame with the same ``frame``; vertex normals are recomputed
    (area-weighted); ``watertight`` is recomputed; ``degenerate`` marks faces below ``DEGENERATE_AREA``.
    The face count reached may be a little off the target (the collapse stops when no valid collapse is left).
    ``first_pass`` (without ``keep_uv`` or ``preserve_topology``): a mesh of at least twice
    :func:`first_pass_faces` is first collapsed there by fast-simplification, which is several times faster.

    Raises :class:`NeuralBakeError` for a bad target, :class:`MeshError` for an empty mesh. Asking for at
    least as many faces as the mesh has returns the welded mesh with a :class:`NeuralBakeWarning`.
    """
    import pymeshlab

    target = _face_target(mesh, faces, ratio)
    if mesh.n_faces == 0:
        raise MeshError(f"{mesh.name}: mesh has no faces to decimate")
    with_uv = bool(keep_uv) and mesh.uv is not None
    if keep_uv and mesh.uv is None:
        warnings.warn(f"{mesh.name}: keep_uv asked but the mesh has no UVs", NeuralBakeWarning, stacklevel=2)
    welded, _ = merge_duplicate_vertices(mesh)
    if target >= welded.n_faces:
        warnings.warn(
            f"{mesh.name}: target of {target} faces >= the mesh's {welded.n_faces}; not decimated",
            NeuralBakeWarning,
            stacklevel=2,
        )
        result_v, result_f = welded.vertices, welded.faces
        result_uv = welded.uv if with_uv else None
    else:
        ms = pymeshlab.MeshSet()
        if with_uv:
            # pymeshlab.Mesh(w_tex_coords_matrix=...) leaves the wedges without a texture index, which the
            # texture-aware filter rejects; an OBJ with a material gives every wedge one.
            _load_via_obj(ms, welded)
        else:
            vertices, faces_in = welded.vertices, welded.faces
            first = first_pass_faces(welded.n_faces, target) if first_pass and not preserve_topology else None
            if first is not None:
                vertices, faces_in = _first_pass(vertices, faces_in, first, keep_boundary)
            ms.add_mesh(
                pymeshlab.Mesh(
                    vertex_matrix=np.ascontiguousarray(vertices, dtype=np.float64),
                    face_matrix=np.ascontiguousarray(faces_in, dtype=np.int32),
                )
            )
        common = dict(
            targetfacenum=target,
            qualitythr=float(quality_threshold),
            preserveboundary=bool(keep_boundary),
            boundaryweight=float(boundary_weight),
            preservenormal=bool(preserve_normal),
            optimalplacement=True,
        )
        if with_uv:
            ms.meshing_decimation_quadric_edge_collapse_with_texture(**common)
        else:
            ms.meshing_decimation_quadric_edge_collapse(
                **common, preservetopology=bool(preserve_topology), autoclean=True
            )
        ms.meshing_remove_unreferenced_vertices()
        cm = ms.current_mesh()
        result_v = np.asarray(cm.vertex_matrix(), dtype=np.float64)
        result_f = np.asarray(cm.face_matrix(), dtype=np.int64)
        result_uv = np.asarray(cm.wedge_tex_coord_matrix(), dtype=np.float64).reshape(-1, 3, 2) if with_uv else None
        if result_f.shape[0] == 0:
            raise MeshError(f"{mesh.name}: decimation to {target} faces left no faces")
    out = Mesh(
        vertices=result_v,
        faces=result_f,
        uv=result_uv,
        texture=mesh.texture if with_uv else None,
        vertex_normals=None,
        frame=mesh.frame,
        uv_policy=mesh.uv_policy,
        source=mesh.source,
        warnings=list(mesh.warnings),
    )
    from ..geometry import edge_report
    from ..geometry import vertex_normals

    out.watertight = edge_report(out.faces)["watertight"]

    out.vertex_normals = vertex_normals(out)
    out.degenerate = out.face_areas < DEGENERATE_AREA
    if with_uv:
        from .unwrap import split_uv_seams

        out, _ = split_uv_seams(out)
    return out
