"""What the mesh renderer draws: a :class:`~neural_bake.types.Mesh` with the attributes a glTF viewer reads
besides.

A :class:`ViewMesh` is a ``Mesh`` (vertices in its frame's unit frame, faces, vertex normals, per-corner UVs,
a linear base-colour texture; :attr:`ViewMesh.positions` maps the vertices back to the source frame, where the
renderer works) plus what a glTF file adds to it: glTF tangents (xyz, handedness in w), a tangent-space normal
map (+Y green up, encoded ``(n + 1) / 2``) and vertex colours. :func:`view_mesh_from_glb` reads a baked
``asset.glb`` through :func:`neural_bake.io.gltf.read_glb` exactly as a viewer does (the exported NORMAL and
TANGENT, not recomputed; the identity frame: the vertices are the file's source-frame positions);
:func:`view_mesh_from_mesh` takes a loaded source mesh in its own frame, with its own normals and texture.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import NeuralBakeError
from ..geometry import vertex_normals
from ..io.gltf import GENERATOR, glb_generator, read_glb
from ..types import Frame, Mesh

__all__ = ["ViewMesh", "ViewError", "view_mesh_from_glb", "view_mesh_from_mesh", "load_view_mesh"]


class ViewError(NeuralBakeError):
    """A file or setting the visual checks cannot use (not a GLB, no output folder, bad view count, …)."""


@dataclass
class ViewMesh(Mesh):
    """A renderable :class:`Mesh`: its fields as there, with these required or narrowed, and the glTF extras.

    - ``vertices``: (V, 3) float64 in ``frame``'s unit frame (the identity frame: source-frame positions);
      ``faces``: (F, 3) int64, counter-clockwise seen from outside.
    - ``vertex_normals``: (V, 3) float64 unit vertex normals (required).
    - ``uv``: (F, 3, 2) float64 per-corner texture coordinates, v = 0 at the image's bottom row, or None.
    - ``texture``: (H, W, 3) float32 linear RGB base-colour texture (row 0 on top), or None (needs UVs).
    - ``source``: what reports and messages call it (:attr:`Mesh.name`).
    - ``tangents``: (V, 4) float64 glTF tangents (xyz unit, w = ±1: bitangent ``w · cross(n, t)``), or None.
    - ``normal_map``: (H, W, 3) float32 in [0, 1], tangent space, +Y green up, or None (needs UVs and tangents).
    - ``vertex_colors``: (V, 3) float64 linear RGB, or None (used where there is no base-colour texture).
    """

    tangents: np.ndarray | None = None
    normal_map: np.ndarray | None = None
    vertex_colors: np.ndarray | None = None

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=np.float64)
        f = np.asarray(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise ViewError(f"{self.name}: vertices must be (V, 3) with V ≥ 1, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise ViewError(f"{self.name}: faces must be (F, 3) with F ≥ 1, got shape {f.shape}")
        if f.min() < 0 or f.max() >= len(v):
            raise ViewError(f"{self.name}: face index {int(f.max())} out of range ({len(v)} vertices)")
        self.vertices, self.faces = v, f
        n = np.asarray(self.vertex_normals, dtype=np.float64)
        if n.shape != v.shape:
            raise ViewError(f"{self.name}: vertex_normals must have shape {v.shape}, got {n.shape}")
        self.vertex_normals = n
        if self.uv is not None:
            uv = np.asarray(self.uv, dtype=np.float64)
            if uv.shape != (len(f), 3, 2):
                raise ViewError(f"{self.name}: uv must have shape {(len(f), 3, 2)}, got {uv.shape}")
            self.uv = uv
        if self.tangents is not None:
            t = np.asarray(self.tangents, dtype=np.float64)
            if t.shape != (len(v), 4):
                raise ViewError(f"{self.name}: tangents must have shape {(len(v), 4)}, got {t.shape}")
            self.tangents = t
        for name in ("texture", "normal_map"):
            img = getattr(self, name)
            if img is not None:
                img = np.asarray(img, dtype=np.float32)
                if img.ndim != 3 or img.shape[2] < 3:
                    raise ViewError(f"{self.name}: {name} must be (H, W, 3), got shape {img.shape}")
                if self.uv is None:
                    raise ViewError(f"{self.name}: a {name} needs UVs")
                setattr(self, name, img[..., :3])
        if self.normal_map is not None and self.tangents is None:
            raise ViewError(f"{self.name}: a tangent-space normal map needs tangents")
        if self.vertex_colors is not None:
            c = np.asarray(self.vertex_colors, dtype=np.float64)[:, :3]
            if c.shape != v.shape:
                raise ViewError(f"{self.name}: vertex_colors must have shape {v.shape}, got {c.shape}")
            self.vertex_colors = c

    @property
    def positions(self) -> np.ndarray:
        """(V, 3) float64 vertex positions, source frame: the vertices mapped back by ``frame`` (the vertices
        themselves in the identity frame)."""
        return self.vertices if self.frame == Frame() else self.frame.to_source(self.vertices)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) corners of the bounding box, source frame."""
        positions = self.positions
        return positions.min(axis=0), positions.max(axis=0)

    def without_maps(self) -> "ViewMesh":
        """The same geometry with neither texture: what the coarse mesh alone shows."""
        return replace(self, texture=None, normal_map=None, source=f"{self.name} (no maps)")

    def with_normal_map(self, normal_map: np.ndarray | None) -> "ViewMesh":
        """The same mesh with another normal map (e.g. a deliberately broken one, for tests)."""
        return replace(self, normal_map=normal_map)

    def to_mesh(self, frame: Frame | None = None, *, source: str | None = None) -> Mesh:
        """The geometry as a plain :class:`Mesh` whose unit frame is ``frame``'s (default the identity: vertices
        are the source-frame positions), with these vertex normals, UVs and base-colour texture; ``source``
        (default :attr:`name`) is what messages call it."""
        frame = Frame() if frame is None else frame
        return Mesh(vertices=frame.to_unit(self.positions), faces=self.faces, uv=self.uv, texture=self.texture,
                    vertex_normals=self.vertex_normals, frame=frame, source=self.name if source is None else source)


def _decode_png(data: bytes, colour: str) -> np.ndarray:
    from ..io.images import read_image

    with tempfile.TemporaryDirectory(prefix="neural_bake_view_") as d:
        p = Path(d) / "map.png"
        p.write_bytes(data)
        return read_image(p, colour=colour)


def view_mesh_from_glb(path) -> ViewMesh:
    """A GLB written by :func:`neural_bake.bake.export.export_glb`, as a glTF viewer reads it.

    POSITION (source frame), NORMAL, TEXCOORD_0 (glTF's v points down: flipped back to v up), TANGENT, COLOR_0,
    the baseColorTexture (sRGB PNG, decoded to linear) and the normalTexture (linear data). Raises
    :class:`ViewError` naming the file for a missing file or one that is not such a GLB.
    """
    p = Path(path)
    if not p.is_file():
        raise ViewError(f"{p}: no such GLB file")
    try:
        gltf, arr, images = read_glb(p)
    except NeuralBakeError:
        raise
    except (KeyError, IndexError, ValueError, TypeError) as exc:
        raise ViewError(f"{p}: unreadable GLB ({type(exc).__name__}: {exc})") from None
    if "POSITION" not in arr:
        raise ViewError(f"{p}: GLB primitive without POSITION")
    faces = np.asarray(arr["indices"], dtype=np.int64)
    positions = np.asarray(arr["POSITION"], dtype=np.float64)
    if "NORMAL" in arr:
        normals = np.asarray(arr["NORMAL"], dtype=np.float64)
    else:
        normals = vertex_normals(Mesh(vertices=positions, faces=faces))
    uv = None
    if "TEXCOORD_0" in arr:
        t = np.asarray(arr["TEXCOORD_0"], dtype=np.float64)
        uv = np.stack([t[:, 0], 1.0 - t[:, 1]], axis=1)[faces]
    tangents = np.asarray(arr["TANGENT"], dtype=np.float64) if "TANGENT" in arr else None
    colors = np.asarray(arr["COLOR_0"], dtype=np.float64)[:, :3] if "COLOR_0" in arr else None
    albedo = normal_map = None
    materials = gltf.get("materials") or []
    if materials:
        mat = materials[0]
        textures = gltf.get("textures", [])

        def image_of(ref) -> bytes:
            return images[textures[ref["index"]]["source"]]

        base = mat.get("pbrMetallicRoughness", {}).get("baseColorTexture")
        if base is not None:
            albedo = _decode_png(image_of(base), "srgb")[..., :3]
        if mat.get("normalTexture") is not None:
            normal_map = _decode_png(image_of(mat["normalTexture"]), "data")[..., :3]
    return ViewMesh(positions, faces, uv=uv, texture=albedo, vertex_normals=normals, tangents=tangents,
                    normal_map=normal_map, vertex_colors=colors, source=p.name)


def view_mesh_from_mesh(mesh: Mesh, name: str | None = None) -> ViewMesh:
    """A loaded :class:`Mesh` as a view of it: the same vertices and frame, its own vertex normals, and its UVs
    and texture (RGB) when it has both; ``name`` (default the file's name) is what reports call it."""
    albedo = None
    if mesh.texture is not None and mesh.uv is not None:
        albedo = np.asarray(mesh.texture, dtype=np.float32)
        if albedo.shape[2] < 3:  # grey (+ alpha): replicate to RGB
            albedo = np.repeat(albedo[..., :1], 3, axis=2)
    return ViewMesh(mesh.vertices, mesh.faces, uv=mesh.uv if albedo is not None else None, texture=albedo,
                    vertex_normals=vertex_normals(mesh), frame=mesh.frame, degenerate=mesh.degenerate,
                    uv_policy=mesh.uv_policy, watertight=mesh.watertight,
                    source=name or Path(mesh.source).name or "mesh")


def load_view_mesh(path, texture=None) -> ViewMesh:
    """A mesh file as a :class:`ViewMesh`: the toolkit's GLBs (``asset.generator`` is
    :data:`~neural_bake.io.gltf.GENERATOR`) through :func:`view_mesh_from_glb` (maps and tangents as exported),
    any other mesh (OBJ, PLY, a foreign GLB) through :func:`~neural_bake.io.mesh_io.load_mesh`."""
    from ..io.mesh_io import load_mesh

    p = Path(path)
    if p.suffix.lower() == ".glb" and p.is_file() and glb_generator(p) == GENERATOR:
        return view_mesh_from_glb(p)
    return view_mesh_from_mesh(load_mesh(p, texture), name=p.name)
