"""glTF 2.0 binary (GLB) export of a baked asset: mesh, UVs, tangents, normal and base-colour textures.

Every attribute the baker used goes in exactly (packed by :func:`neural_bake.io.gltf.glb_bytes`): POSITION
(source frame), NORMAL, TEXCOORD_0, TANGENT (vec4, handedness in w: the renderer's bitangent is
``w · cross(N, T)``), COLOR_0 (linear), baseColorTexture (sRGB 8-bit PNG) and normalTexture (linear 8-bit PNG,
+Y green up as glTF requires). :func:`read_glb` (:mod:`neural_bake.io.gltf`'s) reads such a file back;
trimesh loads it too.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..constants import DIRECTION_EPS
from ..errors import MeshError, NeuralBakeError
from ..io.atomic import atomic_path
from ..io.gltf import glb_bytes, png_bytes, read_glb
from ..types import Mesh

__all__ = ["export_glb", "read_glb", "export_vertex_ply", "vertex_ply_bytes"]

def _check_image(name: str, image, channels: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(image, dtype=np.float32)
    if a.ndim != 3 or a.shape[2] not in channels or a.shape[0] < 1 or a.shape[1] < 1:
        raise NeuralBakeError(f"export_glb: {name} must be (H, W, C) with C in {channels}, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise NeuralBakeError(f"export_glb: {name} holds NaN or infinite values")
    return a


def _check_vertex_array(name: str, a, mesh: Mesh, cols: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] != mesh.n_vertices or a.shape[1] not in cols:
        want = " or ".join(f"({mesh.n_vertices}, {c})" for c in cols)
        raise NeuralBakeError(f"export_glb: {name} must have shape {want}, got {a.shape}")
    if not np.isfinite(a).all():
        raise NeuralBakeError(f"export_glb: {name} holds NaN or infinite values")
    return a


def export_glb(
    path,
    mesh: Mesh,
    *,
    normal_map: np.ndarray | None = None,
    albedo: np.ndarray | None = None,
    tangents: np.ndarray | None = None,
    vertex_colors: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    material_maps: dict[str, np.ndarray] | None = None,
    same_image: list[tuple[str, str]] | None = None,
    material_factors: dict[str, float] | None = None,
    png_files: dict[str, Path] | None = None,
    name: str = "neural_bake",
) -> Path:
    """Write ``mesh`` and its baked maps as one GLB file at ``path`` (atomically); return the path.

    - ``mesh``: unit-frame mesh; positions are written in the SOURCE frame (``mesh.frame.to_source``).
      With a texture map its vertices must be split at UV seams (per-corner uv == per-vertex uv, as
      ``Baker.mesh``); glTF's TEXCOORD_0 is written as (u, 1 − v) (glTF's v points down).
    - ``normal_map``: (H, W, 3) float in [0, 1], encoded ``(n + 1)/2`` in glTF tangent space (+Y up);
      stored as linear data. Requires ``tangents``.
    - ``albedo``: (H, W, 3|4) float linear RGB(A); stored sRGB-encoded.
    - ``tangents``: (V, 4) glTF tangents, xyz unit, w = ±1 (``Baker.tangents``).
    - ``vertex_colors``: (V, 3|4) linear RGB(A) in [0, 1] (per-vertex bakes), written as COLOR_0.
    - ``normals``: (V, 3) unit vertex normals (per-vertex bakes); default the mesh's vertex normals.
    - ``material_maps``: maps the bake did not make, kept from the asset (:class:`~neural_bake.io.asset.Asset`
      ``maps``): "normal" (written only when ``normal_map`` is None), "metallic_roughness", "occlusion";
      (H, W, 3) float data in [0, 1], written unchanged (no colour encoding). ``same_image``: pairs of those
      names that are one image (written once); ``material_factors``: ``metallicFactor``/``roughnessFactor``
      of the asset's material (default 1.0 with a metallic-roughness map, else 0.0 and 1.0).
    - ``png_files``: 8-bit PNG files already written from ``normal_map`` / ``albedo`` (keys "normal_map",
      "albedo"), with the encoding this function gives them (the normal map as data, the albedo sRGB, as
      :func:`~neural_bake.io.images.write_image` writes them): their bytes are embedded, not encoded again.

    Raises :class:`NeuralBakeError` for arrays of the wrong shape, a normal map without tangents, and
    :class:`MeshError` for a texture map on a mesh without UVs or not split at seams.
    """
    from ..mesh.tangents import vertex_normals, vertex_uv

    path = Path(path)
    if not path.parent.is_dir() and str(path.parent):
        raise NeuralBakeError(f"{path}: folder {path.parent} does not exist")
    if normal_map is not None and tangents is None:
        raise NeuralBakeError("export_glb: a tangent-space normal_map needs tangents (Baker.tangents)")
    kept = {k: _check_image(k, v, (3, 4)) for k, v in (material_maps or {}).items()}
    bad = sorted(set(kept) - {"normal", "metallic_roughness", "occlusion"})
    if bad:
        raise NeuralBakeError(f"export_glb: unknown material map {bad[0]!r} (normal, metallic_roughness, occlusion)")
    if normal_map is not None:
        kept.pop("normal", None)  # the baked map replaces the asset's
    if "normal" in kept and tangents is None:
        raise NeuralBakeError("export_glb: the asset's normal map needs tangents (Baker.tangents)")
    textured = normal_map is not None or albedo is not None or bool(kept)
    if textured and mesh.uv is None:
        raise MeshError(f"{mesh.name}: export_glb: texture maps need a mesh with UVs")
    if mesh.n_faces == 0:
        raise MeshError(f"{mesh.name}: export_glb: mesh has no faces")
    nrm = vertex_normals(mesh) if normals is None else _check_vertex_array("normals", normals, mesh, (3,))
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), DIRECTION_EPS)
    attrs: list[tuple[str, np.ndarray]] = [
        ("POSITION", mesh.frame.to_source(mesh.vertices)),
        ("NORMAL", nrm),
    ]
    if mesh.uv is not None:
        uv = vertex_uv(mesh)
        attrs.append(("TEXCOORD_0", np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)))
    if tangents is not None:
        t = _check_vertex_array("tangents", tangents, mesh, (4,))
        t = np.concatenate([t[:, :3], np.where(t[:, 3:] < 0, -1.0, 1.0)], axis=1)
        attrs.append(("TANGENT", t))
    if vertex_colors is not None:
        attrs.append(("COLOR_0", np.clip(_check_vertex_array("vertex_colors", vertex_colors, mesh, (3, 4)), 0, 1)))

    images: list[bytes] = []
    material: dict = {"pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0}}

    def add_texture(image: np.ndarray, colour: str, key: str | None = None) -> int:
        written = (png_files or {}).get(key) if key is not None else None
        images.append(Path(written).read_bytes() if written is not None else png_bytes(image, colour, path))
        return len(images) - 1

    if albedo is not None:
        a = _check_image("albedo", albedo, (3, 4))
        material["pbrMetallicRoughness"]["baseColorTexture"] = {"index": add_texture(a, "srgb", "albedo")}
        if a.shape[2] == 4:
            material["alphaMode"] = "BLEND"
    if normal_map is not None:
        nm = _check_image("normal_map", normal_map, (3,))
        material["normalTexture"] = {"index": add_texture(np.clip(nm, 0, 1), "data", "normal_map")}
    shared = {b: a for a, b in (same_image or [])}
    index: dict[str, int] = {}
    for key, slot in (("normal", "normalTexture"), ("metallic_roughness", "metallicRoughnessTexture"),
                      ("occlusion", "occlusionTexture")):
        if key not in kept:
            continue
        twin = shared.get(key)
        index[key] = index[twin] if twin in index else add_texture(np.clip(kept[key][..., :3], 0, 1), "data")
        if key == "metallic_roughness":
            pbr = material["pbrMetallicRoughness"]
            pbr[slot] = {"index": index[key]}
            pbr["metallicFactor"] = float((material_factors or {}).get("metallicFactor", 1.0))
            pbr["roughnessFactor"] = float((material_factors or {}).get("roughnessFactor", 1.0))
        else:
            material[slot] = {"index": index[key]}
    # no maps: glTF's default material (trimesh then shows COLOR_0 as vertex colours)
    data = glb_bytes(attrs, mesh.faces, images=images, material=material if images else None, name=name)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def export_vertex_ply(path, mesh: Mesh, *, normals: np.ndarray | None = None, vertex_colors: np.ndarray | None = None) -> Path:
    """Write a per-vertex bake as a binary PLY (atomically); return the path.

    Positions in the SOURCE frame (float32 x y z), ``normals`` (V, 3) as nx ny nz (default the mesh's),
    ``vertex_colors`` (V, 3|4) linear in [0, 1] as 8-bit sRGB-encoded red green blue (alpha dropped),
    faces as uchar-counted int32 lists. Raises :class:`NeuralBakeError` for arrays of the wrong shape.
    """
    path = Path(path)
    data = vertex_ply_bytes(mesh, normals=normals, vertex_colors=vertex_colors)
    if str(path.parent) and not path.parent.is_dir():
        raise NeuralBakeError(f"{path}: folder {path.parent} does not exist")
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def vertex_ply_bytes(mesh: Mesh, *, normals: np.ndarray | None = None, vertex_colors: np.ndarray | None = None) -> bytes:
    """The content :func:`export_vertex_ply` writes for these arrays (its size is a PLY frame's file size)."""
    from ..io.colour import linear_to_srgb
    from ..mesh.tangents import vertex_normals

    nrm = vertex_normals(mesh) if normals is None else _check_vertex_array("normals", normals, mesh, (3,))
    pos = mesh.frame.to_source(mesh.vertices)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    cols = None
    if vertex_colors is not None:
        c = _check_vertex_array("vertex_colors", vertex_colors, mesh, (3, 4))[:, :3]
        cols = np.round(linear_to_srgb(np.clip(c, 0, 1)) * 255).astype(np.uint8)
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vert = np.empty(mesh.n_vertices, dtype=fields)
    for k, name in enumerate("xyz"):
        vert[name] = pos[:, k]
        vert["n" + name] = nrm[:, k]
    if cols is not None:
        for k, name in enumerate(("red", "green", "blue")):
            vert[name] = cols[:, k]
    face = np.empty(mesh.n_faces, dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"] = 3
    face["v"] = mesh.faces
    ply_type = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", "comment neural_bake per-vertex bake",
              f"element vertex {mesh.n_vertices}"]
    header += [f"property {ply_type[t]} {n}" for n, t in fields]
    header += [f"element face {mesh.n_faces}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(header) + "\n").encode("ascii") + vert.tobytes() + face.tobytes()
