"""Mesh clean-up for coarse meshes: weld duplicates, drop degenerate/duplicate faces and small components,
report non-manifold and boundary edges."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..constants import DEGENERATE_AREA
from ..errors import NeuralBakeError
from ..geometry import edge_report
from ..types import Mesh

__all__ = ["clean_mesh", "edge_report"]


def clean_mesh(
    mesh: Mesh,
    *,
    min_component_faces: int | None = None,
    min_component_fraction: float = 0.01,
    keep_largest: bool = False,
    merge_tolerance: float = 0.0,
    remove_degenerate: bool = True,
    remove_zero_area: bool = False,
) -> tuple[Mesh, dict]:
    """Clean a (coarse) mesh; returns ``(mesh, report)``.

    Steps, in order:
    1. weld vertices whose positions agree exactly (``merge_tolerance = 0``) or on a grid of that step
       (unit frame);
    2. remove faces with a repeated vertex (``remove_degenerate``), faces of three distinct vertices with an
       area below ``DEGENERATE_AREA`` only with ``remove_zero_area`` (a sliver inside a closed surface — as
       marching cubes makes — shares its three edges with neighbours, so deleting it opens a hole; kept, it
       is flagged in ``mesh.degenerate`` and every consumer skips it), and duplicate faces (same three
       vertices, any order; the first is kept);
    3. remove connected components (faces sharing a vertex) with fewer than ``min_component_faces`` faces
       (default: ``min_component_fraction`` × the largest component's faces), or all but the largest
       (``keep_largest``);
    4. drop unreferenced vertices.
    Non-manifold edges (more than two faces), boundary edges and inconsistent windings are counted in the
    report, not repaired. Faces keep their order and winding, per-corner UVs, texture and ``frame`` follow;
    vertex normals are carried over (recomputed if the input had none).

    Report keys: ``vertices_in, faces_in, vertices_out, faces_out, vertices_merged, degenerate_faces_removed,
    duplicate_faces_removed, components, components_removed, small_component_faces_removed,
    unreferenced_vertices_removed, edges, boundary_edges, non_manifold_edges, inconsistent_edges, watertight``.
    """
    if min_component_faces is not None and (int(min_component_faces) != min_component_faces or min_component_faces < 0):
        raise NeuralBakeError(
            f"clean_mesh: min_component_faces must be a non-negative integer, got {min_component_faces!r}"
        )
    if not (np.isfinite(min_component_fraction) and 0 <= min_component_fraction <= 1):
        raise NeuralBakeError(f"clean_mesh: min_component_fraction must be in [0, 1], got {min_component_fraction!r}")
    if not (np.isfinite(merge_tolerance) and merge_tolerance >= 0):
        raise NeuralBakeError(f"clean_mesh: merge_tolerance must be >= 0, got {merge_tolerance!r}")
    report = {"vertices_in": mesh.n_vertices, "faces_in": mesh.n_faces}
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    uv = None if mesh.uv is None else np.asarray(mesh.uv, dtype=np.float64)
    normals = None if mesh.vertex_normals is None else np.asarray(mesh.vertex_normals, dtype=np.float64)

    # 1. weld
    key = np.round(v / merge_tolerance) if merge_tolerance > 0 else v
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    remap = rank[inv]
    keep_v = np.sort(first)
    v = v[keep_v]
    normals = None if normals is None else normals[keep_v]
    f = remap[f] if len(f) else f
    report["vertices_merged"] = int(mesh.n_vertices - len(v))

    # 2. degenerate and duplicate faces
    keep = np.ones(len(f), bool)
    if remove_degenerate and len(f):
        t = v[f]
        area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
        repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
        keep &= ~(repeated | ((area < DEGENERATE_AREA) & remove_zero_area))
    report["degenerate_faces_removed"] = int((~keep).sum())
    if len(f):
        idx = np.flatnonzero(keep)
        _, firsts = np.unique(np.sort(f[idx], axis=1), axis=0, return_index=True)
        dup = np.ones(len(idx), bool)
        dup[firsts] = False
        keep[idx[dup]] = False
        report["duplicate_faces_removed"] = int(dup.sum())
    else:
        report["duplicate_faces_removed"] = 0
    f = f[keep]
    uv = None if uv is None else uv[keep]

    # 3. small components
    if len(f):
        rows = np.repeat(np.arange(len(f)), 3)
        inc = coo_matrix((np.ones(rows.size), (rows, f.ravel())), shape=(len(f), len(v))).tocsr()
        n_comp, label = connected_components(inc @ inc.T, directed=False)
        sizes = np.bincount(label, minlength=n_comp)
        if keep_largest:
            small = np.arange(n_comp) != np.argmax(sizes)
        else:
            limit = min_component_faces if min_component_faces is not None else min_component_fraction * sizes.max()
            small = sizes < limit
        drop = small[label]
        report["components"] = int(n_comp)
        report["components_removed"] = int(small.sum())
        report["small_component_faces_removed"] = int(drop.sum())
        f = f[~drop]
        uv = None if uv is None else uv[~drop]
    else:
        report.update(components=0, components_removed=0, small_component_faces_removed=0)

    # 4. unreferenced vertices
    used = np.zeros(len(v), bool)
    used[f.ravel()] = True
    new_index = np.cumsum(used) - 1
    report["unreferenced_vertices_removed"] = int((~used).sum())
    v = v[used]
    normals = None if normals is None else normals[used]
    f = new_index[f]
    out = Mesh(
        vertices=v,
        faces=f.astype(np.int64).reshape(-1, 3),
        uv=uv,
        texture=mesh.texture,
        vertex_normals=normals,
        frame=mesh.frame,
        uv_policy=mesh.uv_policy,
        source=mesh.source,
        warnings=list(mesh.warnings),
    )
    if out.vertex_normals is None and out.n_vertices:
        from ..geometry import vertex_normals

        out.vertex_normals = vertex_normals(out)
    out.degenerate = out.face_areas < DEGENERATE_AREA
    edges = edge_report(out.faces)
    out.watertight = edges["watertight"]
    report.update(edges)
    report["vertices_out"], report["faces_out"] = out.n_vertices, out.n_faces
    return out, report
