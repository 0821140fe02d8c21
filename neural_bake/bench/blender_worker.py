"""Blender's side of the Cycles bake: a script run by Blender's own Python (``bpy``), never imported by us.

Imports only the standard library, numpy and bpy, so that it runs in a Python 3.13 venv with the ``bpy``
wheel (``scripts/setup-blender.sh``). :mod:`neural_bake.bench.blender` starts it as
``PYTHON blender_worker.py IN.npz OUT_DIR --size N [--space tangent|object] [--margin PX] [--cage D]
[--max-ray-distance D] [--threads N]``.

``IN.npz``: ``low_vertices`` (V, 3) float64, ``low_faces`` (F, 3) int64, ``low_uv`` (F, 3, 2) float per face
corner (v = 0 at the image's bottom), ``low_normals`` (V, 3) unit vertex normals (set as Blender's custom
normals, so both bakers start from the same low-poly surface), ``high_vertices`` (W, 3), ``high_faces``
(G, 3), ``high_normals`` (W, 3) (its custom normals: the normals a bake reads where a ray lands); all in one
frame, identity object transforms.

``OUT_DIR`` receives:
- ``map.npy``: (size, size, 3) float32 in [0, 1], (n + 1) / 2 of the ``--space`` normal, row 0 at the top;
  tangent space is OpenGL (+Y green up) with Blender's MikkTSpace frames;
- ``frames.npy`` (tangent space only): (F, 3, 7) float32 per face corner: MikkTSpace tangent (3), bitangent
  sign (1), normal (3) — what Blender's bake used, so the map can be decoded with its own basis;
- ``timings.json``: seconds of ``import`` (of bpy), ``setup`` (scene, both objects, image, material),
  ``bake`` (the ``bpy.ops.object.bake`` call), ``read`` (pixels out, map written), ``script`` (this script's
  wall from its first line to the map written), ``frames`` (their export after it, tangent space only) and
  ``version`` (Blender's).

Exit code 0 on success; otherwise the last line of stderr says why.
"""

import time

_T_START = time.perf_counter()

import argparse  # noqa: E402  (after the clock: the script's wall starts at its first line)
import json  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402


def _args(argv):
    p = argparse.ArgumentParser(description="Cycles 'selected to active' normal bake of IN.npz into OUT_DIR.")
    p.add_argument("input")
    p.add_argument("output")
    p.add_argument("--size", type=int, required=True)
    p.add_argument("--space", choices=("tangent", "object"), default="tangent")
    p.add_argument("--margin", type=int, default=16)
    p.add_argument("--cage", type=float, default=0.05, help="cage extrusion along the low-poly normals")
    p.add_argument("--max-ray-distance", type=float, default=0.1, help="0: unlimited")
    p.add_argument("--threads", type=int, default=0, help="0: Blender's automatic choice")
    return p.parse_args(argv)


def _object(bpy, name, vertices, faces, uv=None, normals=None):
    data = bpy.data.meshes.new(name)
    data.from_pydata(np.asarray(vertices, dtype=np.float64).tolist(), [], np.asarray(faces, dtype=np.int64).tolist())
    data.shade_smooth()
    if uv is not None:
        layer = data.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", np.asarray(uv, dtype=np.float32).reshape(-1))
    if normals is not None:
        data.normals_split_custom_set_from_vertices(np.asarray(normals, dtype=np.float64).tolist())
    data.update()
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _frames(data) -> np.ndarray:
    """(F, 3, 7) per corner: MikkTSpace tangent, bitangent sign, normal, as Blender's bake computes them."""
    data.calc_tangents(uvmap="UVMap")
    n = len(data.loops)
    tangent, sign, normal = np.empty(3 * n, np.float32), np.empty(n, np.float32), np.empty(3 * n, np.float32)
    data.loops.foreach_get("tangent", tangent)
    data.loops.foreach_get("bitangent_sign", sign)
    data.corner_normals.foreach_get("vector", normal)
    out = np.concatenate([tangent.reshape(n, 3), sign[:, None], normal.reshape(n, 3)], axis=1)
    return out.reshape(-1, 3, 7)


def main(argv=None) -> int:
    args = _args(sys.argv[1:] if argv is None else argv)
    if args.size < 1:
        raise SystemExit(f"blender_worker: --size must be positive, got {args.size}")
    timings = {}
    t0 = time.perf_counter()
    import bpy

    timings["import"] = time.perf_counter() - t0
    timings["version"] = bpy.app.version_string

    t0 = time.perf_counter()
    with np.load(args.input) as z:
        low_v, low_f, low_uv, low_n = z["low_vertices"], z["low_faces"], z["low_uv"], z["low_normals"]
        high_v, high_f, high_n = z["high_vertices"], z["high_faces"], z["high_normals"]
    if low_uv.shape != (len(low_f), 3, 2):
        raise SystemExit(f"blender_worker: low_uv must be (F, 3, 2) = {(len(low_f), 3, 2)}, got {low_uv.shape}")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    if args.threads > 0:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = args.threads
    low = _object(bpy, "low", low_v, low_f, low_uv, low_n)
    high = _object(bpy, "high", high_v, high_f, normals=high_n)
    image = bpy.data.images.new("normal", width=args.size, height=args.size, float_buffer=True)
    image.colorspace_settings.name = "Non-Color"
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
    timings["setup"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    bpy.ops.object.bake(type="NORMAL", normal_space=args.space.upper(), use_selected_to_active=True,
                        cage_extrusion=args.cage, max_ray_distance=args.max_ray_distance, margin=args.margin,
                        normal_r="POS_X", normal_g="POS_Y", normal_b="POS_Z", uv_layer="UVMap")
    timings["bake"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    pixels = np.empty(args.size * args.size * 4, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    rgba = pixels.reshape(args.size, args.size, 4)[::-1]  # Blender's rows start at the bottom
    os.makedirs(args.output, exist_ok=True)
    np.save(os.path.join(args.output, "map.npy"), np.ascontiguousarray(np.clip(rgba[..., :3], 0.0, 1.0)))
    timings["read"] = time.perf_counter() - t0
    timings["script"] = time.perf_counter() - _T_START
    if args.space == "tangent":
        t0 = time.perf_counter()
        np.save(os.path.join(args.output, "frames.npy"), _frames(low.data))
        timings["frames"] = time.perf_counter() - t0
    with open(os.path.join(args.output, "timings.json"), "w") as f:
        json.dump(timings, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
