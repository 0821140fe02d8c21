"""Mesh files: load (OBJ+MTL, PLY, GLB, glTF), validate, normalise to the unit frame, save.

Conventions of the returned :class:`~neural_bake.types.Mesh`:

- vertices (V, 3) float64 in the unit frame (``Frame.fit``: centred, longest side 1.8) unless
  ``normalise=False`` (source frame, identity Frame). Vertices at the same position (closer than
  ``constants.MERGE_DISTANCE`` in the unit frame) are welded and unreferenced vertices dropped, so a mesh
  whose file splits vertices at UV seams (OBJ ``v/vt`` pairs, glTF) gets its true topology back.
- faces (F, 3) int64, polygons fan-triangulated; faces outward (a closed mesh of negative volume is flipped).
- uv (F, 3, 2) float64 per face corner, v = 0 at the *bottom* of the texture (OBJ and glTF-as-read-by-trimesh
  convention; glTF files store v downward and trimesh flips it on read and write).
- texture (H, W, 3|4) float32 *linear* RGB(A), row 0 = top row of the image file.
- corner_normals (F, 3, 3) of a glTF/GLB with a NORMAL attribute (:func:`~neural_bake.io.asset.file_corner_normals`:
  the asset's own shading, hard edges kept, which the welded vertices' ``vertex_normals`` average away).

OBJ is parsed here (exact line-numbered errors, per-corner UVs, MTL ``map_Kd``); PLY, GLB and glTF are read
with trimesh (``process=False``): any file, whatever wrote it; a multi-geometry scene is concatenated with its
transforms applied. A glTF base-colour texture is multiplied by the material's ``baseColorFactor``; vertex
colours are not read. A GLB is written by :mod:`neural_bake.io.gltf`, the toolkit's one GLB writer.
"""

from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path

import numpy as np

from ..constants import DEGENERATE_AREA, MAX_COORDINATE, MERGE_DISTANCE, UV_POLICIES
from ..geometry import area_weighted_normals, edge_report, vertex_normals
from ..errors import MeshError, NeuralBakeError, NeuralBakeWarning
from ..types import Frame, Mesh
from .atomic import atomic_write_bytes, atomic_write_text

__all__ = ["load_mesh", "mesh_from_arrays", "save_mesh", "MESH_FORMATS", "SAVE_FORMATS"]

#: Extensions :func:`load_mesh` reads (any case).
MESH_FORMATS = (".obj", ".ply", ".glb", ".gltf")
#: Extensions :func:`save_mesh` writes.
SAVE_FORMATS = (".obj", ".ply", ".glb")

#: Start of the warning issued when a closed mesh was wound inward and flipped (inspect looks for it).
INWARD_FLIPPED = "faces were wound inward"

_MAX_REASON = 160


# --------------------------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------------------------


def load_mesh(
    path: str | os.PathLike,
    texture: str | os.PathLike | None = None,
    *,
    uv_policy: str = "wrap",
    normalise: bool = True,
) -> Mesh:
    """Read, validate and normalise a triangle mesh with optional UVs and base-colour texture.

    - ``path``: an OBJ (+MTL), PLY, GLB or glTF file.
    - ``texture``: an image for a mesh whose file names none (or to replace the one it names); read with
      :func:`~neural_bake.io.images.read_image` (8/16-bit images are sRGB, decoded to linear).
    - ``uv_policy``: "wrap" (repeat) or "clamp" for UVs outside [0, 1]; stored in ``Mesh.uv_policy``.
    - ``normalise``: True puts the mesh in the unit frame (``Mesh.frame`` maps back); False keeps the
      source coordinates with an identity frame.

    Raises :class:`~neural_bake.errors.MeshError` (one line, naming the file) for a missing file, unknown
    format, unreadable/corrupt file, empty mesh, non-finite coordinates, out-of-range face indices, faces of
    fewer than 3 corners, all faces degenerate, or a texture given for a mesh without UVs; and
    :class:`~neural_bake.errors.ImageError` naming the image for an unreadable texture. Issues
    :class:`~neural_bake.errors.NeuralBakeWarning` (also kept in ``Mesh.warnings``) for degenerate faces,
    open meshes, inward winding (fixed), UVs outside [0, 1], a named but missing texture.
    """
    _check_uv_policy(uv_policy)
    p = Path(path)
    name = str(path)
    if not p.exists():
        raise MeshError(f"{name}: no such file")
    if not p.is_file():
        raise MeshError(f"{name}: not a file")
    ext = p.suffix.lower()
    if ext not in MESH_FORMATS:
        raise MeshError(f"{name}: unknown mesh format {p.suffix!r} (expected one of {', '.join(MESH_FORMATS)})")
    notes: list[str] = []
    loaded = None
    if ext == ".obj":
        vertices, faces, uv, tex_array, tex_path = _read_obj(p, name, notes, texture is None)
    else:
        vertices, faces, uv, tex_array, tex_path, loaded = _read_with_trimesh(p, name, ext, notes, texture is None)
    tex_label = None
    if texture is not None:
        tex_array, tex_label = None, str(texture)
        tex_path = Path(texture)
    if uv is None and (tex_array is not None or tex_path is not None):
        if tex_label is not None:
            raise MeshError(f"{name}: texture {tex_label} given but the mesh has no UV coordinates")
        _warn(notes, f"{name}: the file names a texture but has no UV coordinates; texture ignored")
        tex_array = tex_path = None
    if tex_array is None and tex_path is not None:
        from .images import read_image

        tex_array = read_image(tex_path)  # ImageError names the image
    mesh = _assemble(vertices, faces, uv, tex_array, name=name, uv_policy=uv_policy, normalise=normalise, notes=notes)
    if ext in (".glb", ".gltf"):  # the asset's own shading normals, hard edges kept
        from .asset import file_corner_normals

        mesh.corner_normals = file_corner_normals(loaded, mesh, name)
    return mesh


def mesh_from_arrays(
    vertices,
    faces,
    uv=None,
    texture=None,
    *,
    source: str = "",
    uv_policy: str = "wrap",
    normalise: bool = True,
) -> Mesh:
    """Build a validated :class:`Mesh` from in-memory arrays (same checks and warnings as :func:`load_mesh`).

    - ``vertices``: (V, 3) float, source frame.
    - ``faces``: (F, K) integer vertex indices, K >= 3 (polygons are fan-triangulated), counter-clockwise
      seen from outside (a closed mesh wound the other way is flipped with a warning).
    - ``uv``: None, (F, K, 2) per face corner or (V, 2) per vertex; v = 0 at the bottom of the texture.
    - ``texture``: None, a (H, W, C) array (float: linear; uint8/uint16: sRGB, decoded; C = 1..4) or an image
      path (read with ``read_image``).
    - ``source``: a name for messages (e.g. the file the arrays came from); "" gives "<generated mesh>".
    - ``uv_policy``, ``normalise``: as in :func:`load_mesh`.

    Note that welding may make ``Mesh.vertices`` shorter than ``vertices`` (see the module docstring).
    """
    _check_uv_policy(uv_policy)
    name = source or "<generated mesh>"
    v = np.asarray(vertices)
    if v.ndim != 2 or v.shape[1] != 3 or v.dtype.kind not in "fiu":
        raise MeshError(f"{name}: vertices must be a numeric (V, 3) array, got shape {v.shape} dtype {v.dtype}")
    f = np.asarray(faces)
    if f.size == 0:
        raise MeshError(f"{name}: empty mesh (no faces)")
    if f.ndim != 2 or f.dtype.kind not in "iuf":
        raise MeshError(f"{name}: faces must be an integer (F, 3) array, got shape {f.shape} dtype {f.dtype}")
    if f.shape[1] < 3:
        raise MeshError(f"{name}: faces have {f.shape[1]} corners (a face needs at least 3), shape {f.shape}")
    if f.dtype.kind == "f":
        if not np.all(np.isfinite(f)) or not np.all(f == np.round(f)):
            raise MeshError(f"{name}: faces must hold integer vertex indices")
    f = f.astype(np.int64)
    k = f.shape[1]
    uv_c = None
    if uv is not None:
        u = np.asarray(uv, dtype=np.float64)
        if u.shape == (f.shape[0], k, 2):
            uv_c = u
        elif u.ndim == 2 and u.shape == (v.shape[0], 2):
            _check_range(f, v.shape[0], name)
            uv_c = u[f]
        else:
            raise MeshError(
                f"{name}: uv must be (F, {k}, 2) per corner or (V, 2) per vertex "
                f"= ({f.shape[0]}, {k}, 2) or ({v.shape[0]}, 2), got shape {u.shape}"
            )
    if k > 3:  # fan triangulation of polygons
        fan = np.array([[0, i, i + 1] for i in range(1, k - 1)])
        f = f[:, fan].reshape(-1, 3)
        if uv_c is not None:
            uv_c = uv_c[:, fan].reshape(-1, 3, 2)
    tex = None
    if texture is not None:
        if isinstance(texture, (str, os.PathLike)):
            if uv_c is None:
                raise MeshError(f"{name}: texture {texture} given but the mesh has no UV coordinates")
            from .images import read_image

            tex = read_image(texture)
        else:
            tex = _texture_array(texture, name)
    return _assemble(v.astype(np.float64), f, uv_c, tex, name=name, uv_policy=uv_policy, normalise=normalise, notes=[])


def save_mesh(mesh: Mesh, path: str | os.PathLike, *, frame: str = "source") -> Path:
    """Write ``mesh`` to an OBJ (+ MTL + PNG texture), PLY or GLB file, atomically; return the path.

    - ``frame``: "source" (default) writes source-frame coordinates (``mesh.frame.to_source``), so
      ``load_mesh(save_mesh(load_mesh(p), q))`` has the geometry of ``p``; "unit" writes unit-frame ones.
    - OBJ: ``<stem>.mtl`` and ``<stem>_basecolor.png`` (8-bit sRGB) beside it when the mesh has a texture;
      per-corner UVs as ``vt``. PLY (binary): double positions, float normals, per-vertex ``s t`` (vertices
      split at UV seams) and ``comment TextureFile`` naming the PNG. GLB (:mod:`neural_bake.io.gltf`): unit
      vertex normals, UVs (vertices split at seams) and the sRGB base-colour texture embedded.

    Every file goes through :func:`~neural_bake.io.atomic.atomic_path`; the mesh file is written last so it
    never names a missing texture. Raises :class:`MeshError` for an unknown format or a missing folder.
    """
    if frame not in ("source", "unit"):
        raise ValueError(f"save_mesh: frame must be 'source' or 'unit', got {frame!r}")
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in SAVE_FORMATS:
        raise MeshError(f"{p}: cannot write mesh format {p.suffix!r} (can write {', '.join(SAVE_FORMATS)})")
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.is_dir():
        raise MeshError(f"{p}: folder {folder} does not exist")
    vertices = mesh.frame.to_source(mesh.vertices) if frame == "source" else np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    uv = None if mesh.uv is None else np.asarray(mesh.uv, dtype=np.float64)
    normals = mesh.vertex_normals if mesh.vertex_normals is not None else area_weighted_normals(vertices, faces)
    tex_name = f"{p.stem}_basecolor.png"
    if ext == ".obj":
        if mesh.texture is not None and uv is not None:
            from .images import write_image

            write_image(p.with_name(tex_name), mesh.texture, colour="srgb", bits=8)
            atomic_write_text(p.with_suffix(".mtl"), _mtl_text(tex_name))
        atomic_write_text(p, _obj_text(vertices, faces, uv, p.with_suffix(".mtl").name if mesh.texture is not None and uv is not None else None))
    elif ext == ".ply":
        has_tex = mesh.texture is not None and uv is not None
        if has_tex:
            from .images import write_image

            write_image(p.with_name(tex_name), mesh.texture, colour="srgb", bits=8)
        atomic_write_bytes(p, _ply_bytes(vertices, faces, uv, normals, tex_name if has_tex else None))
    else:
        atomic_write_bytes(p, _glb_bytes(vertices, faces, uv, vertex_normals(mesh), mesh.texture, p))
    return p


# --------------------------------------------------------------------------------------------------------------
# validation, welding, normalisation
# --------------------------------------------------------------------------------------------------------------


def _check_uv_policy(uv_policy: str) -> None:
    if uv_policy not in UV_POLICIES:
        raise NeuralBakeError(f"uv_policy must be one of {UV_POLICIES}, got {uv_policy!r}")


_PACKAGE_DIR = str(Path(__file__).resolve().parent.parent)


def _warn(notes: list[str], message: str) -> None:
    """Record ``message`` in ``notes`` and issue it, attributed to the first caller outside neural_bake."""
    notes.append(message)
    frame, level = sys._getframe(0), 1
    while frame is not None and str(Path(frame.f_code.co_filename).resolve()).startswith(_PACKAGE_DIR):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, NeuralBakeWarning, stacklevel=level)


def _check_range(faces: np.ndarray, n_vertices: int, name: str) -> None:
    bad = (faces < 0) | (faces >= n_vertices)
    if bad.any():
        i = int(np.flatnonzero(bad.any(axis=1))[0])
        idx = int(faces[i][bad[i]][0])
        raise MeshError(f"{name}: face {i}: vertex index {idx} out of range (mesh has {n_vertices} vertices)")


def _texture_array(texture, name: str) -> np.ndarray:
    """An in-memory texture as (H, W, 3|4) float32 linear; integer arrays are sRGB-encoded."""
    from .colour import srgb_to_linear

    t = np.asarray(texture)
    if t.ndim == 2:
        t = t[:, :, None]
    if t.ndim != 3 or not 1 <= t.shape[2] <= 4 or t.shape[0] == 0 or t.shape[1] == 0 or t.dtype.kind not in "fiub":
        raise MeshError(f"{name}: texture must be a (H, W, C) array with C in 1..4, got shape {np.shape(texture)}")
    if t.dtype.kind in "iub":
        scale = 255.0 if t.dtype.itemsize == 1 else 65535.0
        t = t.astype(np.float32) / scale
        k = 1 if t.shape[2] <= 2 else 3
        t[..., :k] = srgb_to_linear(t[..., :k])
    t = t.astype(np.float32)
    if not np.isfinite(t).all():
        raise MeshError(f"{name}: texture has non-finite values")
    return t


def _rgb_texture(t: np.ndarray) -> np.ndarray:
    """Grey -> RGB, grey+alpha -> RGBA (Mesh.texture holds 3 or 4 channels)."""
    t = np.asarray(t, dtype=np.float32)
    if t.shape[2] == 1:
        return np.repeat(t, 3, axis=2)
    if t.shape[2] == 2:
        return np.concatenate([np.repeat(t[..., :1], 3, axis=2), t[..., 1:]], axis=2)
    return t[..., :4]


def _first_of_equal_rows(a: np.ndarray) -> np.ndarray:
    """For each row of ``a`` (N, K), the index of the first row equal to it (a lexsort, no void views)."""
    n = len(a)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.lexsort(a.T[::-1])  # stable: equal rows keep index order
    s = a[order]
    new_group = np.ones(n, dtype=bool)
    new_group[1:] = np.any(s[1:] != s[:-1], axis=1)
    group = np.cumsum(new_group) - 1
    first = order[new_group]  # first (smallest) index of each group
    out = np.empty(n, dtype=np.int64)
    out[order] = first[group]
    return out


def _may_have_close_pairs(points: np.ndarray, tol: float) -> bool:
    """False only when no two of the distinct ``points`` (N, 3) lie within ``tol`` of each other (then a weld has
    nothing to merge and the KD-tree, and scipy's import, are not needed); True when two of them share a cell of
    one of four grids of side 4.5·tol shifted by a quarter side along every axis (or their cells' hashes collide:
    then the KD-tree decides). Two points within tol of each other straddle a cell border of at most one of the
    four grids per axis, so of at least one grid on none: they share a cell there. One sort of N hashes per grid
    (a 1M-vertex mesh: about 0.5 s, against 0.8 s for the KD-tree's pairs)."""
    side = 4.5 * tol
    lo = points.min(axis=0)
    if not float((points.max(axis=0) - lo).max()) / side < 2.0**52:  # cells beyond exact integers: the KD-tree
        return True
    primes = np.array([73856093, 19349663, 83492791], dtype=np.int64)
    for shift in range(4):
        cells = np.floor((points - lo) / side + shift / 4.0).astype(np.int64)
        keys = np.sort((cells[:, 0] * primes[0]) ^ (cells[:, 1] * primes[1]) ^ (cells[:, 2] * primes[2]))
        if (keys[1:] == keys[:-1]).any():
            return True
    return False


def _weld(vertices: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices closer than ``tol``; returns (kept indices in original order, old -> new index map)."""
    n = len(vertices)
    rep = _first_of_equal_rows(vertices)  # exact duplicates -> first occurrence
    uniq = np.unique(rep)
    if tol > 0 and len(uniq) > 1 and _may_have_close_pairs(vertices[uniq], tol):
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components
        from scipy.spatial import cKDTree

        pairs = cKDTree(vertices[uniq]).query_pairs(r=tol, output_type="ndarray")
        if len(pairs):
            m = len(uniq)
            graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
            _, label = connected_components(graph, directed=False)
            first_of_label = np.full(label.max() + 1, n, dtype=np.int64)
            np.minimum.at(first_of_label, label, uniq)
            rep_u = first_of_label[label]  # uniq position -> representative original index
            lookup = np.empty(n, dtype=np.int64)
            lookup[uniq] = rep_u
            rep = lookup[rep]
    kept = np.unique(rep)
    new_index = np.full(n, -1, dtype=np.int64)
    new_index[kept] = np.arange(len(kept))
    return kept, new_index[rep]


def _assemble(vertices, faces, uv, texture, *, name, uv_policy, normalise, notes) -> Mesh:
    """Shared validation + normalisation of triangle data (source frame) into a Mesh."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        raise MeshError(f"{name}: empty mesh (no faces)")
    _check_range(faces, len(vertices), name)
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise MeshError(f"{name}: vertex {i} has a non-finite coordinate {tuple(vertices[i].tolist())}")
    if uv is not None:
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 3, 2)
        badf = ~np.isfinite(uv).all(axis=(1, 2))
        if badf.any():
            raise MeshError(f"{name}: face {int(np.flatnonzero(badf)[0])} has a non-finite texture coordinate")
    if texture is not None and uv is None:
        raise MeshError(f"{name}: a texture was given but the mesh has no UV coordinates")
    # drop unreferenced vertices, fit the frame, weld
    used = np.unique(faces)
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    vertices, faces = vertices[used], remap[faces]
    magnitude = np.abs(vertices).max(axis=1)
    if not magnitude.max() <= MAX_COORDINATE:
        i = int(used[np.argmax(magnitude)])
        raise MeshError(f"{name}: vertex {i} has a coordinate of magnitude {magnitude.max():.3g}, beyond "
                        f"{MAX_COORDINATE:g} (distances would overflow); rescale the mesh")
    unit = Frame.fit(vertices)
    kept, new_index = _weld(vertices, MERGE_DISTANCE / unit.scale)
    vertices, faces = vertices[kept], new_index[faces]
    # degenerate faces (area measured in the unit frame)
    t = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1) * unit.scale**2
    degenerate = area < DEGENERATE_AREA
    if degenerate.all():
        raise MeshError(f"{name}: all {len(faces)} faces are degenerate (zero area)")
    if degenerate.any():
        _warn(notes, f"{name}: {int(degenerate.sum())} degenerate faces (area < {DEGENERATE_AREA:g} in the unit frame); "
              "kept but excluded from sampling")
    # topology and winding
    edges = edge_report(faces)
    watertight = edges["watertight"]
    if not watertight:
        parts = [f"{edges[k]} {label}" for k, label in (("boundary_edges", "boundary edges"), ("non_manifold_edges", "non-manifold edges"),
                 ("inconsistent_edges", "edges with inconsistent winding")) if edges[k]]
        _warn(notes, f"{name}: mesh is not watertight ({', '.join(parts)}); inside/outside is ill-defined")
    else:
        c = Frame(unit.center, 1.0).to_unit(vertices)[faces]
        volume = float(np.einsum("ij,ij->i", c[:, 0], np.cross(c[:, 1], c[:, 2])).sum() / 6.0)
        if volume < 0:
            faces = faces[:, ::-1].copy()
            if uv is not None:
                uv = uv[:, ::-1].copy()
            _warn(notes, f"{name}: {INWARD_FLIPPED} (negative volume); flipped all faces to face outward")
    # UV range
    if uv is not None:
        outside = (uv < 0) | (uv > 1)
        if outside.any():
            n_out = int(outside.any(axis=2).sum())
            _warn(notes, f"{name}: {n_out} face corners have UVs outside [0, 1] (u in [{uv[..., 0].min():.4g}, {uv[..., 0].max():.4g}], "
                  f"v in [{uv[..., 1].min():.4g}, {uv[..., 1].max():.4g}]); policy {uv_policy!r}")
    frame = unit if normalise else Frame()
    out_vertices = frame.to_unit(vertices) if normalise else vertices.copy()
    return Mesh(
        vertices=out_vertices,
        faces=np.ascontiguousarray(faces, dtype=np.int64),
        uv=None if uv is None else np.ascontiguousarray(uv, dtype=np.float64),
        texture=None if texture is None else np.ascontiguousarray(_rgb_texture(texture)),
        vertex_normals=area_weighted_normals(out_vertices, faces, exclude=degenerate),
        frame=frame,
        degenerate=degenerate,
        uv_policy=uv_policy,
        watertight=watertight,
        source=name if name != "<generated mesh>" else "",
        warnings=list(notes),
    )


# --------------------------------------------------------------------------------------------------------------
# OBJ + MTL
# --------------------------------------------------------------------------------------------------------------


def _read_obj(p: Path, name: str, notes: list[str], want_texture: bool = True, simple: bool = True):
    """Parse an OBJ file: (vertices, faces, uv or None, texture array or None, texture path or None).

    ``want_texture=False`` (a texture is given by the caller) skips the MTL files and their warnings. A plain
    file is read by :func:`_read_simple_obj` (``simple=False``: always by the line parser)."""
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise MeshError(f"{name}: unreadable file ({exc.strerror})") from None
    if b"\x00" in data[:65536]:
        raise MeshError(f"{name}: unreadable OBJ file (binary data, not OBJ text)")
    text = data.decode("utf-8-sig", errors="replace").replace("\\\r\n", " ").replace("\\\n", " ")
    fast = _read_simple_obj(text) if simple else None
    if fast is not None:  # a plain file (most scans and exports): parsed by numpy, no line loop
        vertices, faces, uv, libs, used = fast
        tex_path = _obj_texture(p, name, libs, used, notes) if want_texture else None
        return vertices, faces, uv, None, tex_path
    verts: list[tuple[float, float, float]] = []
    vert_line: list[int] = []
    tcs: list[tuple[float, float]] = []
    tri_v: list[tuple[int, int, int]] = []
    tri_t: list[tuple[int, int, int] | None] = []
    tri_line: list[int] = []
    tri_mat: list[str | None] = []
    mtllibs: list[str] = []
    material = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        head, _, rest = line.replace("\t", " ").partition(" ")
        if head == "v":
            tok = rest.split()
            try:
                verts.append((float(tok[0]), float(tok[1]), float(tok[2])))
                vert_line.append(lineno)
            except (ValueError, IndexError):
                raise MeshError(f"{name}:{lineno}: cannot parse vertex {line!r}") from None
        elif head == "vt":
            tok = rest.split()
            try:
                tcs.append((float(tok[0]), float(tok[1]) if len(tok) > 1 else 0.0))
            except (ValueError, IndexError):
                raise MeshError(f"{name}:{lineno}: cannot parse texture coordinate {line!r}") from None
        elif head == "f":
            tok = rest.split()
            if len(tok) < 3:
                raise MeshError(f"{name}:{lineno}: face with {len(tok)} vertices (a face needs at least 3)")
            vi, ti = [], []
            try:
                for t in tok:
                    parts = t.split("/")
                    a = int(parts[0])
                    vi.append(a + len(verts) + 1 if a < 0 else a)
                    if len(parts) > 1 and parts[1]:
                        b = int(parts[1])
                        ti.append(b + len(tcs) + 1 if b < 0 else b)
            except ValueError:
                raise MeshError(f"{name}:{lineno}: cannot parse face {line!r}") from None
            has_t = len(ti) == len(vi)
            for i in range(1, len(vi) - 1):
                tri_v.append((vi[0], vi[i], vi[i + 1]))
                tri_t.append((ti[0], ti[i], ti[i + 1]) if has_t else None)
                tri_line.append(lineno)
                tri_mat.append(material)
        elif head == "mtllib":
            mtllibs.append(rest.strip())
        elif head == "usemtl":
            material = rest.strip()
    if not tri_v:
        what = f"{len(verts)} vertices but no faces" if verts else "no vertices or faces"
        raise MeshError(f"{name}: empty mesh ({what})")
    faces = np.asarray(tri_v, dtype=np.int64) - 1
    nv = len(verts)
    bad = (faces < 0) | (faces >= nv)
    if bad.any():
        i = int(np.flatnonzero(bad.any(axis=1))[0])
        raise MeshError(f"{name}:{tri_line[i]}: face index {int(faces[i][bad[i]][0]) + 1} out of range "
                        f"(file has {nv} vertices)")
    vertices = np.asarray(verts, dtype=np.float64)
    bad_v = ~np.isfinite(vertices).all(axis=1)
    if bad_v.any():
        i = int(np.flatnonzero(bad_v)[0])
        raise MeshError(f"{name}:{vert_line[i]}: vertex {i + 1} has a non-finite coordinate {tuple(vertices[i].tolist())}")
    uv = None
    has = np.array([t is not None for t in tri_t])
    if has.any():
        nt = len(tcs)
        tidx = np.zeros((len(tri_t), 3), dtype=np.int64)
        tidx[has] = np.asarray([t for t in tri_t if t is not None], dtype=np.int64) - 1
        badt = has[:, None] & ((tidx < 0) | (tidx >= nt))
        if badt.any():
            i = int(np.flatnonzero(badt.any(axis=1))[0])
            raise MeshError(f"{name}:{tri_line[i]}: texture coordinate index {int(tidx[i][badt[i]][0]) + 1} out of "
                            f"range (file has {nt} texture coordinates)")
        uv = np.asarray(tcs, dtype=np.float64).reshape(-1, 2)[np.where(has[:, None], tidx, 0)]
        if not has.all():
            uv[~has] = 0.0
            _warn(notes, f"{name}: {int((~has).sum())} faces have no texture coordinates; they get uv (0, 0)")
    tex_path = None
    if want_texture:
        tex_path = _obj_texture(p, name, mtllibs, [m for m in dict.fromkeys(tri_mat) if m is not None], notes)
    return vertices, faces, uv, None, tex_path


#: Line heads a plain OBJ may hold (:func:`_read_simple_obj`); any other line sends the file to the line parser.
_SIMPLE_HEADS = ("v ", "vt ", "vn ", "f ", "o ", "g ", "s ", "mtllib ", "usemtl ")


def _numbers(text: str, dtype, count: int) -> np.ndarray | None:
    """``count`` numbers of ``dtype`` from whitespace-separated ``text``, or None when it holds another count
    or something that is not a number."""
    if count == 0:
        return np.zeros(0, dtype=dtype)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpy warns where it stops early: the count then tells
        try:
            out = np.fromstring(text, dtype=dtype, sep=" ")
        except ValueError:
            return None
    return out if out.size == count else None


def _read_simple_obj(text: str):
    """A plain OBJ parsed without a line loop: ``(vertices, faces, uv or None, mtllibs, used materials)``, or
    None when the file is not plain, so that the line parser reads it (and names the line of any error).

    Plain: every line empty, a whole-line comment or one of :data:`_SIMPLE_HEADS` at its start; ``v`` lines of
    three numbers, ``vt`` lines of two; triangles only, every corner written alike (``a``, ``a/b``, ``a/b/c`` or
    ``a//c``) with positive indices in range; finite positions; at most one ``usemtl``."""
    lines = text.splitlines()
    v, vt, f, libs, mats = [], [], [], [], []
    hashes = 0  # of whole-line comments: any other "#" is a comment after data, for the line parser
    for line in lines:
        if line.startswith("v "):
            v.append(line[2:])
        elif line.startswith("f "):
            f.append(line[2:])
        elif line.startswith("vt "):
            vt.append(line[3:])
        elif line.startswith("#"):
            hashes += line.count("#")
        elif line.startswith("mtllib "):
            libs.append(line[7:].strip())
        elif line.startswith("usemtl "):
            mats.append(line[7:].strip())
        elif line.strip() and not line.startswith(_SIMPLE_HEADS):
            return None
    if not f or not v or len(mats) > 1 or "\t" in text or text.count("#") != hashes:
        return None
    vertices = _numbers(" ".join(v), np.float64, 3 * len(v))
    if vertices is None or not np.isfinite(vertices).all():
        return None
    first = f[0].split()
    if len(first) != 3:
        return None
    corner = first[0]
    slashes, normal_only = corner.count("/"), "//" in corner
    per = 2 if normal_only else slashes + 1  # numbers a corner holds
    face_text = " ".join(f)
    if face_text.count("/") != 3 * slashes * len(f):
        return None
    if normal_only:
        face_text = face_text.replace("//", " ")
    elif slashes:
        face_text = face_text.replace("/", " ")
    idx = _numbers(face_text, np.int64, 3 * per * len(f))
    if idx is None:
        return None
    idx = idx.reshape(len(f), 3, per) - 1
    faces = np.ascontiguousarray(idx[:, :, 0])
    if (faces < 0).any() or (faces >= len(v)).any():
        return None
    uv = None
    if slashes and not normal_only:
        tcs = _numbers(" ".join(vt), np.float64, 2 * len(vt))
        t = idx[:, :, 1]
        if tcs is None or (t < 0).any() or (t >= len(vt)).any():
            return None
        uv = tcs.reshape(-1, 2)[t]
    return vertices.reshape(-1, 3), faces, uv, libs, mats


_MAP_OPTIONS_ONE = {"-blendu", "-blendv", "-cc", "-clamp", "-imfchan", "-type"}
_MAP_OPTIONS_NUM = {"-bm", "-boost", "-mm", "-o", "-s", "-t", "-texres"}


def _map_file(args: str) -> str:
    """File name of an MTL ``map_Kd`` statement, skipping its options."""
    tok = args.split()
    i = 0
    while i < len(tok) and tok[i].startswith("-") and tok[i] in _MAP_OPTIONS_ONE | _MAP_OPTIONS_NUM:
        opt = tok[i]
        i += 1
        if opt in _MAP_OPTIONS_ONE:
            i += 1
        else:
            while i < len(tok) - 1:
                try:
                    float(tok[i])
                except ValueError:
                    break
                i += 1
    return " ".join(tok[i:])


def _obj_texture(p: Path, name: str, mtllibs: list[str], used: list[str], notes: list[str]) -> Path | None:
    """The base-colour texture path of the first used material that has a ``map_Kd`` (warn when missing)."""
    maps: dict[str, tuple[str, Path]] = {}  # material -> (map name as written, mtl file)
    for lib in mtllibs:
        # one statement may name several libraries; a single name may contain spaces
        names = [lib] if (p.parent / lib.replace("\\", "/")).is_file() else lib.split()
        for c in names:
            mtl = p.parent / c.replace("\\", "/")
            if not mtl.is_file():
                _warn(notes, f"{name}: material library {c} not found; loading without its textures")
                continue
            current = None
            for raw in mtl.read_text(encoding="utf-8", errors="replace").splitlines():
                line = raw.split("#", 1)[0].strip()
                head, _, rest = line.replace("\t", " ").partition(" ")
                if head == "newmtl":
                    current = rest.strip()
                elif head.lower() == "map_kd" and current is not None and current not in maps:
                    maps[current] = (_map_file(rest), mtl)
    order = [m for m in used if m in maps] or list(maps)
    if not order:
        return None
    files = {maps[m][0] for m in order}
    if len(files) > 1:
        _warn(notes, f"{name}: materials use {len(files)} different textures; only {maps[order[0]][0]} is used")
    written, mtl = maps[order[0]]
    rel = written.replace("\\", "/")
    for cand in (mtl.parent / rel, mtl.parent / Path(rel).name):
        if cand.is_file():
            return cand
    _warn(notes, f"{name}: texture {written} named by {mtl.name} not found; loading without texture")
    return None


def _fmt_rows(prefix: str, rows: np.ndarray, fmt: str) -> str:
    if len(rows) == 0:
        return ""
    line = prefix + " " + " ".join([fmt] * (rows.shape[1] // fmt.count("%")))
    return "\n".join(line % tuple(r) for r in rows.tolist()) + "\n"


def _obj_text(vertices, faces, uv, mtl_name) -> str:
    from .. import __version__

    out = [f"# written by neural_bake {__version__}\n"]
    if mtl_name:
        out.append(f"mtllib {mtl_name}\nusemtl material0\n")
    out.append(_fmt_rows("v", vertices, "%.17g"))
    if uv is None:
        out.append(_fmt_rows("f", faces + 1, "%d"))
    else:
        uniq, inv = np.unique(uv.reshape(-1, 2), axis=0, return_inverse=True)
        out.append(_fmt_rows("vt", uniq, "%.17g"))
        pairs = np.stack([faces + 1, inv.reshape(-1, 3) + 1], axis=2).reshape(-1, 6)
        out.append(_fmt_rows("f", pairs, "%d/%d"))
    return "".join(out)


def _mtl_text(tex_name: str) -> str:
    return f"# written by neural_bake\nnewmtl material0\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\nmap_Kd {tex_name}\n"


# --------------------------------------------------------------------------------------------------------------
# PLY, GLB, glTF (trimesh)
# --------------------------------------------------------------------------------------------------------------


def _short(exc: BaseException) -> str:
    msg = " ".join(str(exc).split()) or type(exc).__name__
    return msg if len(msg) <= _MAX_REASON else msg[: _MAX_REASON - 3] + "..."


def _pil_to_linear(img) -> np.ndarray:
    from .colour import srgb_to_linear

    has_alpha = img.mode in ("RGBA", "LA", "PA") or "transparency" in getattr(img, "info", {})
    arr = np.asarray(img.convert("RGBA" if has_alpha else "RGB"), dtype=np.float32) / 255.0
    arr[..., :3] = srgb_to_linear(arr[..., :3])
    return arr


def _ply_header(p: Path) -> dict:
    """``{"texture": comment TextureFile or None, "faces": declared face count or None}`` of a PLY header."""
    with open(p, "rb") as fh:
        head = fh.read(65536)
    end = head.find(b"end_header")
    out: dict = {"texture": None, "faces": None}
    for raw in head[: end if end >= 0 else len(head)].decode("latin-1").splitlines():
        tok = raw.strip().split(None, 2)
        if len(tok) == 3 and tok[0] == "comment" and tok[1] == "TextureFile":
            out["texture"] = tok[2].strip()
        elif len(tok) == 3 and tok[0] == "element" and tok[1] == "face":
            try:
                out["faces"] = int(tok[2])
            except ValueError:
                pass
    return out


def _gltf_missing_images(p: Path) -> list[str]:
    """External image URIs of a .gltf file that do not exist (trimesh silently drops them)."""
    import json
    from urllib.parse import unquote

    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
        uris = [im.get("uri") for im in doc.get("images", []) if isinstance(im, dict)]
    except (ValueError, OSError, AttributeError):
        return []
    return [u for u in uris if isinstance(u, str) and not u.startswith("data:") and not (p.parent / unquote(u)).is_file()]


def _image_key(image) -> tuple:
    """A key equal for images of equal content (mode, size and pixels), whichever objects hold them."""
    import hashlib

    arr = np.asarray(image)
    return arr.shape, str(arr.dtype), hashlib.blake2b(np.ascontiguousarray(arr).tobytes(), digest_size=16).digest()


def _read_with_trimesh(p: Path, name: str, ext: str, notes: list[str], want_texture: bool = True):
    import trimesh

    kind = ext[1:].upper()
    header = _ply_header(p) if ext == ".ply" else {"texture": None, "faces": None}
    named_texture = header["texture"]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(str(p), file_type=ext[1:], process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise MeshError(f"{name}: unreadable {kind} file ({_short(exc)})") from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump(concatenate=False) if isinstance(g, trimesh.Trimesh)]
    elif isinstance(loaded, trimesh.Trimesh):
        geoms = [loaded]
    else:
        geoms = []
    geoms = [g for g in geoms if len(g.faces)]
    if not geoms:
        if header["faces"]:
            raise MeshError(f"{name}: unreadable PLY file (header declares {header['faces']} faces but none could "
                            "be read; truncated?)")
        raise MeshError(f"{name}: empty mesh (no faces)")
    vs, fs, uvs, images = [], [], [], []
    offset = 0
    for g in geoms:
        v = np.asarray(g.vertices, dtype=np.float64)
        f = np.asarray(g.faces, dtype=np.int64)
        _check_range(f, len(v), name)
        guv = getattr(g.visual, "uv", None) if getattr(g.visual, "kind", None) == "texture" else None
        guv = None if guv is None or len(guv) != len(v) else np.asarray(guv, dtype=np.float64)[:, :2]
        uvs.append(None if guv is None else guv[f])
        # PLY: the texture is the header's ``comment TextureFile``, read below with read_image (trimesh puts
        # a placeholder image in when that file is missing); glTF: the material's base-colour image
        mat = getattr(g.visual, "material", None) if ext != ".ply" else None
        img = getattr(mat, "baseColorTexture", None) if mat is not None else None
        if img is None and mat is not None:
            img = getattr(mat, "image", None)
        factor = getattr(mat, "baseColorFactor", None) if img is not None else None
        images.append((img, None if factor is None else np.asarray(factor, dtype=np.float32).reshape(-1)[:4] / 255.0))
        vs.append(v)
        fs.append(f + offset)
        offset += len(v)
    vertices, faces = np.concatenate(vs), np.concatenate(fs)
    uv = None
    if any(u is not None for u in uvs):
        missing = sum(len(f) for f, u in zip(fs, uvs) if u is None)
        uv = np.concatenate([u if u is not None else np.zeros((len(f), 3, 2)) for f, u in zip(fs, uvs)])
        if missing:
            _warn(notes, f"{name}: {missing} faces have no texture coordinates; they get uv (0, 0)")
    texture = None
    imgs = [im for im, _ in images if im is not None]
    if imgs:
        texture = _pil_to_linear(imgs[0])
        factor = next(fa for im, fa in images if im is not None)
        if factor is not None and len(factor) == 4 and not np.all(factor == 1.0):
            # glTF: base colour = texture (linear) * baseColorFactor (linear; trimesh keeps it as 8-bit)
            texture[..., :3] *= factor[:3]
            if texture.shape[2] == 4:
                texture[..., 3] *= factor[3]
        distinct = len({_image_key(im) for im in imgs})  # by content: a reader may copy one image per geometry
        if distinct > 1:
            _warn(notes, f"{name}: geometries use {distinct} different base-colour textures; only the first is used")
    if not want_texture:
        return vertices, faces, uv, None, None, loaded
    if ext == ".gltf":
        for uri in _gltf_missing_images(p):
            _warn(notes, f"{name}: texture {uri} named by the file not found; loading without it")
    tex_path = None
    if named_texture is not None:
        cand = p.parent / named_texture.replace("\\", "/")
        if cand.is_file():
            tex_path = cand
        else:
            _warn(notes, f"{name}: texture {named_texture} named by the file not found; loading without texture")
    return vertices, faces, uv, texture, tex_path, loaded


def _split_seams(vertices, faces, uv, normals=None):
    """One output vertex per distinct (vertex, uv) corner: (vertices, faces, per-vertex uv, normals)."""
    if uv is None:
        return vertices, faces, None, normals
    keys = np.column_stack([faces.reshape(-1).astype(np.float64), uv.reshape(-1, 2)])
    uniq, inv = np.unique(keys, axis=0, return_inverse=True)
    vid = uniq[:, 0].astype(np.int64)
    n = None if normals is None else normals[vid]
    return vertices[vid], inv.reshape(-1, 3), uniq[:, 1:], n


def _ply_bytes(vertices, faces, uv, normals, tex_name) -> bytes:
    from .. import __version__

    v, f, u, n = _split_seams(vertices, faces, uv, normals)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if u is not None:
        fields += [("s", "<f4"), ("t", "<f4")]
    vert = np.zeros(len(v), dtype=fields)
    vert["x"], vert["y"], vert["z"] = v.T
    vert["nx"], vert["ny"], vert["nz"] = n.T
    if u is not None:
        vert["s"], vert["t"] = u.T
    face = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, f
    types = {"<f8": "double", "<f4": "float"}
    header = ["ply", "format binary_little_endian 1.0", f"comment written by neural_bake {__version__}"]
    if tex_name:
        header.append(f"comment TextureFile {tex_name}")
    header.append(f"element vertex {len(v)}")
    header += [f"property {types[t]} {k}" for k, t in fields]
    header += [f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(header) + "\n").encode("ascii") + vert.tobytes() + face.tobytes()


def _glb_bytes(vertices, faces, uv, normals, texture, path: Path) -> bytes:
    """The GLB of a mesh (vertices split at UV seams, glTF's v down) with its sRGB base-colour texture."""
    from .gltf import glb_bytes, png_bytes

    v, f, u, n = _split_seams(vertices, faces, uv, normals)
    attributes = [("POSITION", v), ("NORMAL", n)]
    images, material = [], None
    if u is not None:
        attributes.append(("TEXCOORD_0", np.stack([u[:, 0], 1.0 - u[:, 1]], axis=1)))
        if texture is not None:
            images.append(png_bytes(texture, "srgb", path))
            material = {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0,
                                                 "roughnessFactor": 1.0}}
            if np.asarray(texture).shape[2] == 4:
                material["alphaMode"] = "BLEND"
    return glb_bytes(attributes, f, images=images, material=material, name=path.stem)
