"""What a mesh file holds and what is wrong with it: counts, UVs, texture, topology, warnings."""

from __future__ import annotations

import os
import warnings

import numpy as np

from ..errors import NeuralBakeWarning
from ..types import Mesh
from ..geometry import edge_report
from .mesh_io import INWARD_FLIPPED, load_mesh

__all__ = ["inspect_mesh", "format_report", "topology"]


def topology(faces: np.ndarray, n_vertices: int) -> dict:
    """Connected components, Euler characteristics and genus of a triangle mesh.

    - ``faces``: (F, 3) int vertex indices; faces with a repeated index are left out of the counts.
    - ``n_vertices``: V.

    Returns ``{"components": int, "euler": [χ per component], "genus": int | None, "edges": {...}}``;
    components join faces that share a vertex. The genus (sum over components of (2 - χ) / 2) is only
    defined for a closed manifold mesh: ``None`` otherwise (also when some χ is odd).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = np.asarray(faces, dtype=np.int64)
    edges = edge_report(faces)
    rows = np.concatenate([faces[:, 0], faces[:, 1]])
    cols = np.concatenate([faces[:, 1], faces[:, 2]])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    _, label = connected_components(graph, directed=False)
    used = np.unique(faces)
    comp_ids, comp_of_vertex = np.unique(label[used], return_inverse=True)
    n_comp = len(comp_ids)
    ok = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    f = faces[ok]
    fc = np.searchsorted(comp_ids, label[f[:, 0]])
    pairs = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    keys = np.unique(pairs[:, 0] * np.int64(n_vertices) + pairs[:, 1])
    und = np.stack([keys // n_vertices, keys % n_vertices], axis=1)
    ec = np.searchsorted(comp_ids, label[und[:, 0]])
    vc = np.searchsorted(comp_ids, label[np.unique(f)])
    euler = (np.bincount(vc, minlength=n_comp) - np.bincount(ec, minlength=n_comp) + np.bincount(fc, minlength=n_comp))
    closed = edges["watertight"]
    genus = None
    if closed and np.all(euler % 2 == 0) and np.all(euler <= 2):
        genus = int(((2 - euler) // 2).sum())
    return {"components": int(n_comp), "euler": [int(e) for e in euler], "genus": genus, "edges": edges}


def inspect_mesh(mesh_or_path: Mesh | str | os.PathLike, texture: str | os.PathLike | None = None) -> dict:
    """A JSON-ready report of a mesh (a :class:`Mesh`, or a file read with :func:`load_mesh`).

    Keys: ``source``, ``vertices``, ``faces``, ``degenerate_faces``, ``uv`` (bool), ``uv_range``
    (``{"u": [min, max], "v": [min, max]}`` or None), ``uv_policy``, ``texture`` (``{"width", "height",
    "channels"}`` or None), ``watertight``, ``genus`` (None unless closed), ``euler_characteristic`` (per
    component), ``components``, ``boundary_edges``, ``non_manifold_edges``, ``winding`` ("outward",
    "inward (fixed)", or "n/a (open mesh)"), ``bounding_box`` (``{"min", "max", "size"}`` in source units),
    ``frame`` (centre and scale of the unit frame), ``own_normals`` (the file gives its normals per face corner:
    a glTF's NORMAL attribute, which the fit and a bake onto the asset itself follow, hard edges kept),
    ``warnings`` (the load warnings, one line each).

    Loading a path raises what :func:`load_mesh` raises (MeshError/ImageError naming the file); its warnings
    are not re-issued, they are in the report.
    """
    if isinstance(mesh_or_path, Mesh):
        mesh = mesh_or_path
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NeuralBakeWarning)
            mesh = load_mesh(mesh_or_path, texture)
    topo = topology(mesh.faces, mesh.n_vertices)
    src = mesh.frame.to_source(mesh.vertices)
    lo, hi = src.min(axis=0), src.max(axis=0)
    if not mesh.watertight:
        winding = "n/a (open mesh)"
    elif any(INWARD_FLIPPED in w for w in mesh.warnings):
        winding = "inward (fixed)"
    else:
        winding = "outward"
    uv_range = None
    if mesh.uv is not None:
        uv_range = {"u": [float(mesh.uv[..., 0].min()), float(mesh.uv[..., 0].max())],
                    "v": [float(mesh.uv[..., 1].min()), float(mesh.uv[..., 1].max())]}
    tex = None
    if mesh.texture is not None:
        h, w, c = mesh.texture.shape
        tex = {"width": int(w), "height": int(h), "channels": int(c)}
    degenerate = int(mesh.degenerate.sum()) if mesh.degenerate is not None else 0
    return {
        "source": mesh.name,
        "vertices": mesh.n_vertices,
        "faces": mesh.n_faces,
        "degenerate_faces": degenerate,
        "uv": mesh.uv is not None,
        "uv_range": uv_range,
        "uv_policy": mesh.uv_policy,
        "texture": tex,
        "watertight": bool(mesh.watertight),
        "genus": topo["genus"],
        "euler_characteristic": topo["euler"],
        "components": topo["components"],
        "boundary_edges": topo["edges"]["boundary_edges"],
        "non_manifold_edges": topo["edges"]["non_manifold_edges"],
        "winding": winding,
        "bounding_box": {k: [float(f"{x:.12g}") for x in a] for k, a in (("min", lo), ("max", hi), ("size", hi - lo))},
        "frame": mesh.frame.to_dict(),
        "own_normals": mesh.corner_normals is not None,
        "warnings": list(mesh.warnings),
    }


def _vec(x) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in x) + ")"


def format_report(report: dict) -> str:
    """The human-readable form of an :func:`inspect_mesh` report (one fact per line)."""
    r = report
    if r["uv"]:
        u, v = r["uv_range"]["u"], r["uv_range"]["v"]
        uv = f"yes, u [{u[0]:.4g}, {u[1]:.4g}], v [{v[0]:.4g}, {v[1]:.4g}] (outside [0, 1]: {r['uv_policy']})"
    else:
        uv = "no"
    t = r["texture"]
    tex = f"{t['width']} x {t['height']}, {t['channels']} channels" if t else "none"
    bb = r["bounding_box"]
    rows = [
        ("vertices", f"{r['vertices']:,}"),
        ("faces", f"{r['faces']:,} ({r['degenerate_faces']:,} degenerate)"),
        ("UVs", uv),
        ("texture", tex),
        ("watertight", "yes" if r["watertight"] else
         f"no ({r['boundary_edges']:,} boundary edges, {r['non_manifold_edges']:,} non-manifold edges)"),
        ("genus", "n/a (open mesh)" if r["genus"] is None else str(r["genus"])),
        ("components", f"{r['components']:,}"),
        ("winding", r["winding"]),
        ("normals", "the file's own, per face corner (hard edges kept)" if r["own_normals"] else
         "averaged over the faces at each vertex (the file gives none per corner)"),
        ("bounding box", f"min {_vec(bb['min'])}, max {_vec(bb['max'])}, size {_vec(bb['size'])} (source units)"),
    ]
    lines = [r["source"]] + [f"  {k:<13} {v}" for k, v in rows]
    if r["warnings"]:
        lines.append(f"  {'warnings':<13} {len(r['warnings'])}")
        lines += [f"    - {w}" for w in r["warnings"]]
    else:
        lines.append(f"  {'warnings':<13} none")
    return "\n".join(lines)
