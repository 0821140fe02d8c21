"""glTF 2.0 binary (GLB) export of a baked asset: mesh, UVs, tangents, normal and base-colour textures.

The file is written by hand (JSON + one binary buffer) so that every attribute the baker used goes in
exactly: POSITION (source frame), NORMAL, TEXCOORD_0, TANGENT (vec4, handedness in w: the renderer's
bitangent is ``w · cross(N, T)``), COLOR_0 (linear), baseColorTexture (sRGB 8-bit PNG) and normalTexture
(linear 8-bit PNG, +Y green up as glTF requires). :func:`read_glb` reads such a file back (for tests and
reports); trimesh loads it too.
"""

from __future__ import annotations

import json
import os
import struct
import tempfile
from pathlib import Path

import numpy as np

from ..constants import DIRECTION_EPS
from ..errors import MeshError, NeuralBakeError
from ..io.atomic import atomic_path
from ..types import Mesh

__all__ = ["export_glb", "read_glb", "export_vertex_ply", "vertex_ply_bytes"]

_FLOAT, _UINT32 = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
_NCOMP = {v: k for k, v in _TYPES.items()}


def _png_bytes(image: np.ndarray, colour: str, beside: Path) -> bytes:
    """``image`` as PNG bytes. OpenImageIO writes a file: it goes in a folder beside ``beside`` (the GLB)
    named as the GLB's atomic temporary file, so what a killed run leaves is removed by the next run for that
    output (or with the staging folder it is in), never left in the system's temporary folder."""
    from ..io.images import write_image

    folder = beside.parent if str(beside.parent) else Path(".")
    try:
        with tempfile.TemporaryDirectory(prefix=f".{beside.name}.{os.getpid()}.", suffix=".tmp", dir=folder) as d:
            p = Path(d) / "map.png"
            write_image(p, image, colour=colour, bits=8)
            return p.read_bytes()
    except OSError as exc:  # the GLB is the file the user asked for: name it, not the temporary map
        raise OSError(exc.errno, exc.strerror, str(beside)) from None


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

    blob = bytearray()
    views: list[dict] = []
    accessors: list[dict] = []

    def add_view(data: bytes, target: int | None = None) -> int:
        while len(blob) % 4:
            blob.append(0)
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        blob.extend(data)
        views.append(view)
        return len(views) - 1

    def add_accessor(a: np.ndarray, ctype: int, target: int, minmax: bool = False) -> int:
        dt = np.float32 if ctype == _FLOAT else np.uint32
        a = np.ascontiguousarray(a, dtype=dt)
        acc = {
            "bufferView": add_view(a.tobytes(), target),
            "componentType": ctype,
            "count": int(a.shape[0]),
            "type": _TYPES[a.shape[1]] if a.ndim == 2 else "SCALAR",
        }
        if minmax:
            acc["min"] = [float(x) for x in a.min(axis=0)]
            acc["max"] = [float(x) for x in a.max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    attributes = {key: add_accessor(a, _FLOAT, _ARRAY_BUFFER, key == "POSITION") for key, a in attrs}
    indices = add_accessor(mesh.faces.reshape(-1), _UINT32, _ELEMENT_ARRAY_BUFFER)

    gltf: dict = {
        "asset": {"version": "2.0", "generator": "neural_bake"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"name": name, "primitives": [{"attributes": attributes, "indices": indices, "mode": 4}]}],
        "materials": [{"name": name, "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0}}],
    }
    gltf["meshes"][0]["primitives"][0]["material"] = 0
    images, textures = [], []

    def add_texture(image: np.ndarray, colour: str, key: str | None = None) -> int:
        written = (png_files or {}).get(key) if key is not None else None
        data = Path(written).read_bytes() if written is not None else _png_bytes(image, colour, path)
        images.append({"bufferView": add_view(data), "mimeType": "image/png"})
        textures.append({"source": len(images) - 1, "sampler": 0})
        return len(textures) - 1

    if albedo is not None:
        a = _check_image("albedo", albedo, (3, 4))
        gltf["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = {"index": add_texture(a, "srgb", "albedo")}
        if a.shape[2] == 4:
            gltf["materials"][0]["alphaMode"] = "BLEND"
    if normal_map is not None:
        nm = _check_image("normal_map", normal_map, (3,))
        gltf["materials"][0]["normalTexture"] = {"index": add_texture(np.clip(nm, 0, 1), "data", "normal_map")}
    shared = {b: a for a, b in (same_image or [])}
    index: dict[str, int] = {}
    for key, slot in (("normal", "normalTexture"), ("metallic_roughness", "metallicRoughnessTexture"),
                      ("occlusion", "occlusionTexture")):
        if key not in kept:
            continue
        twin = shared.get(key)
        index[key] = index[twin] if twin in index else add_texture(np.clip(kept[key][..., :3], 0, 1), "data")
        if key == "metallic_roughness":
            pbr = gltf["materials"][0]["pbrMetallicRoughness"]
            pbr[slot] = {"index": index[key]}
            pbr["metallicFactor"] = float((material_factors or {}).get("metallicFactor", 1.0))
            pbr["roughnessFactor"] = float((material_factors or {}).get("roughnessFactor", 1.0))
        else:
            gltf["materials"][0][slot] = {"index": index[key]}
    if not textures:  # no maps: glTF's default material (trimesh then shows COLOR_0 as vertex colours)
        del gltf["materials"], gltf["meshes"][0]["primitives"][0]["material"]
    else:
        # linear filtering with mip-maps (the padding makes mip levels safe), repeat wrapping
        gltf["samplers"] = [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}]
        gltf["images"], gltf["textures"] = images, textures
    while len(blob) % 4:
        blob.append(0)
    gltf["buffers"] = [{"byteLength": len(blob)}]
    gltf["bufferViews"] = views
    gltf["accessors"] = accessors
    js = json.dumps(gltf, separators=(",", ":")).encode("utf-8")
    js += b" " * (-len(js) % 4)
    total = 12 + 8 + len(js) + 8 + len(blob)
    data = b"".join(
        [
            struct.pack("<4sII", b"glTF", 2, total),
            struct.pack("<I4s", len(js), b"JSON"),
            js,
            struct.pack("<I4s", len(blob), b"BIN\x00"),
            bytes(blob),
        ]
    )
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def read_glb(path) -> tuple[dict, dict[str, np.ndarray], list[bytes]]:
    """Read a GLB written by :func:`export_glb`: (glTF JSON, first primitive's arrays, image bytes).

    The arrays dict holds every attribute by its glTF name (float32 / uint32 numpy arrays) and
    ``"indices"`` as (F, 3). Raises :class:`NeuralBakeError` for a file that is not a GLB.
    """
    data = Path(path).read_bytes()
    if len(data) < 20 or data[:4] != b"glTF":
        raise NeuralBakeError(f"{path}: not a GLB file")
    jlen, jtype = struct.unpack_from("<I4s", data, 12)
    if jtype != b"JSON":
        raise NeuralBakeError(f"{path}: GLB without a JSON chunk")
    gltf = json.loads(data[20 : 20 + jlen])
    off = 20 + jlen
    blen, _ = struct.unpack_from("<I4s", data, off)
    blob = data[off + 8 : off + 8 + blen]

    def view_bytes(i: int) -> bytes:
        v = gltf["bufferViews"][i]
        return blob[v.get("byteOffset", 0) : v.get("byteOffset", 0) + v["byteLength"]]

    def accessor(i: int) -> np.ndarray:
        a = gltf["accessors"][i]
        dt = np.float32 if a["componentType"] == _FLOAT else np.uint32
        arr = np.frombuffer(view_bytes(a["bufferView"]), dtype=dt, count=a["count"] * _NCOMP[a["type"]])
        return arr.reshape(a["count"], -1) if a["type"] != "SCALAR" else arr

    prim = gltf["meshes"][0]["primitives"][0]
    arrays = {k: accessor(i) for k, i in prim["attributes"].items()}
    arrays["indices"] = accessor(prim["indices"]).reshape(-1, 3)
    images = [view_bytes(im["bufferView"]) for im in gltf.get("images", [])]
    return gltf, arrays, images


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
