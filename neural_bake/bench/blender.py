"""Blender's Cycles "selected to active" normal bake, the artists' anchor, through ``bpy`` when it is installed.

Optional: ``pip install neural-bake[blender]`` (the ``bpy`` wheel, about 400 MB). :func:`available` says
whether it imports here and why not; :func:`cycles_bake` bakes an object-space normal map of the fine mesh
onto the coarse mesh's UV layout (CPU, one sample per texel, a cage of ``cage`` unit-frame units), so the
benchmark decodes it with the same decoder as ours.
"""

from __future__ import annotations

import time

import numpy as np

from ..types import Mesh

__all__ = ["available", "cycles_bake"]


def available() -> tuple[bool, str]:
    """(True, version) when ``bpy`` imports here, else (False, the reason in one line)."""
    try:
        import bpy  # noqa: F401
    except Exception as exc:  # not installed, or a wheel that does not load on this machine
        return False, f"bpy not importable ({type(exc).__name__}: {str(exc).splitlines()[0][:120] if str(exc) else ''})"
    return True, f"bpy {'.'.join(str(v) for v in bpy.app.version)}"


def _object(bpy, name: str, mesh: Mesh, uv: np.ndarray | None):
    data = bpy.data.meshes.new(name)
    data.from_pydata(np.asarray(mesh.vertices, dtype=np.float64).tolist(), [],
                     np.asarray(mesh.faces, dtype=np.int64).tolist())
    if uv is not None:
        layer = data.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", np.asarray(uv, dtype=np.float32).reshape(-1))
    data.update()
    for p in data.polygons:
        p.use_smooth = True
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def cycles_bake(coarse: Mesh, fine: Mesh, size: int, *, cage: float = 0.05) -> tuple[np.ndarray, float]:
    """Object-space normal map (size, size, 3) in [0, 1] ((n + 1) / 2, row 0 at the top) of ``fine`` baked
    onto ``coarse`` (per-corner UVs (F, 3, 2), both in the same unit frame) by Cycles "selected to active",
    and the bake's seconds (set-up of the scene excluded)."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    low = _object(bpy, "low", coarse, coarse.uv)
    high = _object(bpy, "high", fine, None)
    image = bpy.data.images.new("normal", width=int(size), height=int(size), float_buffer=True)
    mat = bpy.data.materials.new("bake")
    mat.use_nodes = True
    node = mat.node_tree.nodes.new("ShaderNodeTexImage")
    node.image = image
    mat.node_tree.nodes.active = node
    low.data.materials.append(mat)
    bpy.ops.object.select_all(action="DESELECT")
    high.select_set(True)
    low.select_set(True)
    bpy.context.view_layer.objects.active = low
    t0 = time.perf_counter()
    bpy.ops.object.bake(type="NORMAL", normal_space="OBJECT", use_selected_to_active=True,
                        cage_extrusion=float(cage), max_ray_distance=float(2 * cage), margin=0)
    seconds = time.perf_counter() - t0
    pixels = np.empty(int(size) * int(size) * 4, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    rgba = pixels.reshape(int(size), int(size), 4)[::-1]  # Blender's rows start at the bottom
    return np.clip(rgba[..., :3], 0.0, 1.0), seconds
