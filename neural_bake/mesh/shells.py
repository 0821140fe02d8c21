"""Faces buried inside the solid: the parts of a mesh's shells that lie inside another of its shells.

Sculpts, scans and game assets are often several shells that overlap: teeth set into gums, a belt pushed into a
body, a lid sitting inside a pot. The solid they describe is the union (the generalised winding number counts
2 where two closed shells overlap, and the inside test is w > 1/2), so a face inside another shell is not on
the solid's boundary: its distance is not the solid's signed distance, and a zero-level target on it asks the
field for a surface where the solid is inside on both sides.

A face is *buried* when the mesh's winding number is above 1/2 just off its centroid on both sides
(:data:`BURIED_OFFSET` along its normal). Only meshes of more than one connected shell are tested, and only the
faces whose centroid lies in the bounding box of another shell; a single shell that passes through itself is
taken as it is.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..geometry import sampleable_faces, welded_edges
from ..types import Mesh
from .winding import winding_number

__all__ = ["buried_faces", "shell_labels", "BURIED_OFFSET"]

#: How far off a face's centroid, along its normal, the winding number is read on each side (unit frame):
#: far below the thinnest wall a fit resolves, far above the float32 error of the faces' positions.
BURIED_OFFSET = 1e-4
#: Meshes whose buried faces are kept (by their faces' and vertices' content), most recent last.
_CACHE_SIZE = 4
_CACHE: OrderedDict[bytes, np.ndarray] = OrderedDict()
_LOCK = threading.Lock()


def shell_labels(mesh: Mesh) -> tuple[int, np.ndarray]:
    """(number of shells, (F,) int64 shell of each face): the connected components of the faces joined by
    shared edges, an edge being its two corners' positions (a mesh split along its UV seams is one shell; two
    shells that touch at a corner are two)."""
    edge, count = welded_edges(mesh)
    n_f = mesh.n_faces
    # faces and edges as one bipartite graph: its components, read at the faces
    face = np.tile(np.arange(n_f), 3)
    size = n_f + len(count)
    graph = coo_matrix((np.ones(face.size, dtype=np.int8), (face, n_f + edge)), shape=(size, size))
    _, labels = connected_components(graph, directed=False)
    used, face_labels = np.unique(labels[:n_f], return_inverse=True)
    return int(used.size), face_labels.astype(np.int64)


def buried_faces(mesh: Mesh) -> np.ndarray:
    """(F,) bool: the faces of ``mesh`` inside the solid on both sides (module docstring). Degenerate faces are
    never buried (they are excluded from sampling already). Computed once per mesh content and kept."""
    key = _digest(mesh)
    with _LOCK:
        hit = _CACHE.get(key)
        if hit is not None:
            _CACHE.move_to_end(key)
            return hit.copy()
    out = _buried(mesh)
    with _LOCK:
        _CACHE[key] = out
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    return out.copy()


def _digest(mesh: Mesh) -> bytes:
    h = hashlib.blake2b(str((mesh.vertices.shape, mesh.faces.shape)).encode(), digest_size=16)
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    return h.digest()


def _buried(mesh: Mesh) -> np.ndarray:
    out = np.zeros(mesh.n_faces, dtype=bool)
    n_shells, label = shell_labels(mesh)
    if n_shells < 2:
        return out
    idx, _ = sampleable_faces(mesh)
    corners = mesh.vertices[mesh.faces]
    centroid = corners[idx].mean(axis=1)
    shell = label[idx]
    lo = np.full((n_shells, 3), np.inf)
    hi = np.full((n_shells, 3), -np.inf)
    np.minimum.at(lo, label, corners.min(axis=1))
    np.maximum.at(hi, label, corners.max(axis=1))
    # the winding number of the other shells at each centroid (a centroid outside a shell's box is outside it)
    others = np.zeros(idx.size)
    sampleable = np.bincount(shell, minlength=n_shells) > 0  # a shell of degenerate faces only bounds nothing
    for s in np.flatnonzero(sampleable):
        near = np.flatnonzero(np.all((centroid >= lo[s]) & (centroid <= hi[s]), axis=1) & (shell != s))
        if near.size:
            others[near] += winding_number(_shell(mesh, label, s), centroid[near])
    # a face with the other shells' count above 1/4 may be inside on both sides: its own shell's winding number
    # just off it on each side decides (1 and 0 for a closed shell, 0 and -1 for a cavity's, anything for an
    # open one); the other shells' count is taken as constant across the offset
    for s in np.unique(shell[others > 0.25]):
        pick = np.flatnonzero((shell == s) & (others > 0.25))
        c, n = centroid[pick], mesh.face_normals[idx[pick]]
        own = winding_number(_shell(mesh, label, s), np.concatenate([c + BURIED_OFFSET * n, c - BURIED_OFFSET * n]))
        k = pick.size
        out[idx[pick]] = (others[pick] + own[:k] > 0.5) & (others[pick] + own[k:] > 0.5)
    return out


def _shell(mesh: Mesh, label: np.ndarray, s: int) -> Mesh:
    """The faces of shell ``s`` as a mesh of their own (the winding number of that shell alone)."""
    mine = label == s
    degenerate = None if mesh.degenerate is None else np.asarray(mesh.degenerate, dtype=bool)[mine]
    return Mesh(mesh.vertices, mesh.faces[mine], degenerate=degenerate, watertight=False, source=mesh.source)
