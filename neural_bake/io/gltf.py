"""glTF 2.0 binary (GLB) files: the one writer and the one reader of the toolkit's GLBs.

:func:`glb_bytes` packs one triangle mesh (one node, one mesh, one primitive) into a GLB: its vertex
attributes as float32 accessors (POSITION with min and max), the faces as uint32 indices, embedded PNG images
(texture k shows image k, through one linear, mip-mapped, repeating sampler) and an optional material; JSON
then one binary buffer, every chunk 4-byte aligned. :func:`read_glb` reads the first primitive of a GLB back
as numpy arrays with its images' bytes. :func:`glb_generator` names what wrote a file: the toolkit's GLBs say
:data:`GENERATOR`, and are read exactly as written (``view.meshes``), others through trimesh (``io.mesh_io``).
"""

from __future__ import annotations

import json
import os
import struct
import tempfile
from pathlib import Path

import numpy as np

from ..errors import NeuralBakeError

__all__ = ["GENERATOR", "glb_bytes", "read_glb", "glb_generator", "png_bytes"]

#: ``asset.generator`` of every GLB the toolkit writes.
GENERATOR = "neural_bake"

_FLOAT, _UINT32, _UINT16, _UINT8 = 5126, 5125, 5123, 5121
_COMPONENTS = {_FLOAT: np.float32, _UINT32: np.uint32, _UINT16: np.uint16, _UINT8: np.uint8}
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
_NCOMP = {v: k for k, v in _TYPES.items()}
#: linear filtering with mip-maps (a bake's padding makes mip levels safe), repeat wrapping
_SAMPLER = {"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}


def glb_bytes(
    attributes: list[tuple[str, np.ndarray]],
    faces: np.ndarray,
    *,
    images: list[bytes] | None = None,
    material: dict | None = None,
    name: str = GENERATOR,
) -> bytes:
    """The GLB of one triangle mesh.

    - ``attributes``: (glTF name, (V, C) array) pairs in the order they are stored, written as float32
      (POSITION gets its accessor's min and max); the caller gives them in glTF's conventions (TEXCOORD_0 with
      v down, TANGENT with handedness in w).
    - ``faces``: (F, 3) vertex indices, written as uint32.
    - ``images``: PNG files' bytes, embedded in order; texture k shows image k.
    - ``material``: the primitive's glTF material (texture references are indices into ``images``), or None
      for glTF's default material.
    - ``name``: the node's, the mesh's (and the material's, when it has none) name.
    """
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
        a = np.ascontiguousarray(a, dtype=_COMPONENTS[ctype])
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

    attrs = {key: add_accessor(a, _FLOAT, _ARRAY_BUFFER, key == "POSITION") for key, a in attributes}
    indices = add_accessor(np.asarray(faces).reshape(-1), _UINT32, _ELEMENT_ARRAY_BUFFER)
    primitive: dict = {"attributes": attrs, "indices": indices, "mode": 4}
    gltf: dict = {
        "asset": {"version": "2.0", "generator": GENERATOR},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"name": name, "primitives": [primitive]}],
    }
    if material is not None:
        gltf["materials"] = [{"name": name, **material}]
        primitive["material"] = 0
    if images:
        gltf["samplers"] = [dict(_SAMPLER)]
        gltf["images"] = [{"bufferView": add_view(data), "mimeType": "image/png"} for data in images]
        gltf["textures"] = [{"source": k, "sampler": 0} for k in range(len(images))]
    while len(blob) % 4:
        blob.append(0)
    gltf["buffers"] = [{"byteLength": len(blob)}]
    gltf["bufferViews"] = views
    gltf["accessors"] = accessors
    js = json.dumps(gltf, separators=(",", ":")).encode("utf-8")
    js += b" " * (-len(js) % 4)
    total = 12 + 8 + len(js) + 8 + len(blob)
    return b"".join([
        struct.pack("<4sII", b"glTF", 2, total),
        struct.pack("<I4s", len(js), b"JSON"),
        js,
        struct.pack("<I4s", len(blob), b"BIN\x00"),
        bytes(blob),
    ])


def _chunks(data: bytes, path) -> tuple[dict, bytes]:
    """(glTF JSON, binary chunk) of a GLB file's bytes; :class:`NeuralBakeError` naming ``path`` otherwise."""
    if len(data) < 20 or data[:4] != b"glTF":
        raise NeuralBakeError(f"{path}: not a GLB file")
    jlen, jtype = struct.unpack_from("<I4s", data, 12)
    if jtype != b"JSON":
        raise NeuralBakeError(f"{path}: GLB without a JSON chunk")
    try:
        gltf = json.loads(data[20 : 20 + jlen])
    except ValueError:
        raise NeuralBakeError(f"{path}: GLB whose JSON chunk does not parse") from None
    off = 20 + jlen
    blob = b""
    if len(data) >= off + 8:
        blen, _ = struct.unpack_from("<I4s", data, off)
        blob = data[off + 8 : off + 8 + blen]
    return gltf, blob


def read_glb(path) -> tuple[dict, dict[str, np.ndarray], list[bytes]]:
    """Read a GLB: (glTF JSON, the first primitive's arrays, every image's bytes).

    The arrays dict holds every attribute by its glTF name (numpy arrays of the accessor's component type:
    float32, uint32, uint16 or uint8) and ``"indices"`` as (F, 3). Reads what :func:`glb_bytes` writes (tightly
    packed accessors in the binary chunk). Raises :class:`NeuralBakeError` for a file that is not a GLB.
    """
    gltf, blob = _chunks(Path(path).read_bytes(), path)

    def view_bytes(i: int) -> bytes:
        v = gltf["bufferViews"][i]
        return blob[v.get("byteOffset", 0) : v.get("byteOffset", 0) + v["byteLength"]]

    def accessor(i: int) -> np.ndarray:
        a = gltf["accessors"][i]
        n = a["count"] * _NCOMP[a["type"]]
        arr = np.frombuffer(view_bytes(a["bufferView"]), dtype=_COMPONENTS[a["componentType"]], count=n,
                            offset=a.get("byteOffset", 0))
        return arr.reshape(a["count"], -1) if a["type"] != "SCALAR" else arr

    prim = gltf["meshes"][0]["primitives"][0]
    arrays = {k: accessor(i) for k, i in prim["attributes"].items()}
    arrays["indices"] = accessor(prim["indices"]).reshape(-1, 3)
    images = [view_bytes(im["bufferView"]) for im in gltf.get("images", [])]
    return gltf, arrays, images


def glb_generator(path) -> str | None:
    """``asset.generator`` of the GLB file ``path`` (:data:`GENERATOR` for the toolkit's own), or None for a
    file that is not a GLB or names no generator."""
    p = Path(path)
    with open(p, "rb") as fh:
        head = fh.read(20)
        if len(head) < 20 or head[:4] != b"glTF":
            return None
        (jlen,) = struct.unpack_from("<I", head, 12)
        data = head + fh.read(jlen)
    try:
        gltf, _ = _chunks(data, p)
    except NeuralBakeError:
        return None
    generator = gltf.get("asset", {}).get("generator") if isinstance(gltf, dict) else None
    return generator if isinstance(generator, str) else None


def png_bytes(image: np.ndarray, colour: str, beside: Path) -> bytes:
    """``image`` as 8-bit PNG bytes (:func:`~neural_bake.io.images.write_image` with ``colour``). OpenImageIO
    writes a file: it goes in a folder beside ``beside`` (the GLB) named as the GLB's atomic temporary file, so
    what a killed run leaves is removed by the next run for that output (or with the staging folder it is in),
    never left in the system's temporary folder."""
    from .images import write_image

    folder = beside.parent if str(beside.parent) else Path(".")
    try:
        with tempfile.TemporaryDirectory(prefix=f".{beside.name}.{os.getpid()}.", suffix=".tmp", dir=folder) as d:
            p = Path(d) / "map.png"
            write_image(p, image, colour=colour, bits=8)
            return p.read_bytes()
    except OSError as exc:  # the GLB is the file the user asked for: name it, not the temporary map
        raise OSError(exc.errno, exc.strerror, str(beside)) from None
