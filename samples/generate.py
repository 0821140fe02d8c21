"""Write the samples as OBJ + MTL + PNG (8-bit sRGB) and find the bundled copies.

``generate(out_dir)`` writes ``<name>.obj``, ``<name>.mtl`` and ``<name>.png`` for each static sample, every
file atomically (texture and MTL first, the OBJ last, so an OBJ never names a missing file), and for each
animation (:mod:`neural_bake.samples.animated`) a folder ``<name>/`` of numbered geometry-only frames
``<name>_0000.obj``, … with ``frames.json`` (the frame files and their times, written last). Coordinates are the
sample's own frame (the analytic functions' frame), written with 6 decimals to keep the files small.
The package ships the default-resolution files in ``samples/data/``; :func:`sample_path` finds them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterable

import numpy as np

from neural_bake.errors import NeuralBakeError
from neural_bake.io.atomic import atomic_write_text

from .animated import ANIMATED
from .shapes import SAMPLES, SampleMesh, get_sample

__all__ = ["generate", "check_generate_args", "sample_path", "write_sample", "write_animation", "obj_text", "DATA_DIR", "FRAMES_FILE"]

#: The index file of an animation's folder: ``{"name", "sdf_kind", "times": [...], "frames": [...]}``.
FRAMES_FILE = "frames.json"

#: Where the bundled sample files live (package data).
DATA_DIR = Path(__file__).parent / "data"


def sample_path(name: str) -> Path:
    """Path of the bundled OBJ of sample ``name`` (its MTL and PNG sit beside it).

    Raises :class:`NeuralBakeError` for an unknown name or a missing file (e.g. an install without data).
    """
    get_sample(name)
    p = DATA_DIR / f"{name}.obj"
    if not p.is_file():
        raise NeuralBakeError(f"{p}: bundled sample file missing (run `neural-bake samples --out DIR` to make it)")
    return p


def obj_text(m: SampleMesh, mtl_name: str | None, material: str = "material0") -> str:
    """OBJ text of a sample mesh: ``v`` (6 decimals), unique ``vt`` and ``f v/vt`` lines, 1-based."""
    out = ["# neural_bake sample\n"]
    if mtl_name:
        out.append(f"mtllib {mtl_name}\nusemtl {material}\n")
    out.append("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in np.asarray(m.vertices).tolist()))
    uv = np.round(np.asarray(m.uv, dtype=np.float64).reshape(-1, 2), 6)
    uniq, inv = np.unique(uv, axis=0, return_inverse=True)
    out.append("".join(f"vt {u:.6f} {v:.6f}\n" for u, v in uniq.tolist()))
    f = np.asarray(m.faces, dtype=np.int64) + 1
    t = inv.reshape(-1, 3) + 1
    out.append("".join(f"f {a}/{d} {b}/{e} {c}/{g}\n" for (a, b, c), (d, e, g) in zip(f.tolist(), t.tolist())))
    return "".join(out).replace("-0.000000", "0.000000")


def write_sample(m: SampleMesh, out_dir: str | os.PathLike, name: str) -> Path:
    """Write ``m`` as ``<name>.obj/.mtl/.png`` in ``out_dir`` (which must exist); return the OBJ path."""
    from neural_bake.io.images import write_image

    out = Path(out_dir)
    write_image(out / f"{name}.png", m.texture, colour="srgb", bits=8)
    atomic_write_text(
        out / f"{name}.mtl",
        f"# neural_bake sample\nnewmtl material0\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\nmap_Kd {name}.png\n",
    )
    obj = out / f"{name}.obj"
    atomic_write_text(obj, obj_text(m, f"{name}.mtl"))
    return obj


def write_animation(anim, out_dir: str | os.PathLike, *, times=None, resolution: int | None = None) -> Path:
    """Write animation ``anim``'s frames at ``times`` (default ``anim.times``) into ``out_dir/<name>/`` as
    ``<name>_0000.obj``, … (geometry only) and :data:`FRAMES_FILE` (written last); return the folder."""
    times = [float(t) for t in (anim.times if times is None else times)]
    folder = Path(out_dir) / anim.name
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for k, t in enumerate(times):
        m = anim.mesh(t, resolution)
        name = f"{anim.name}_{k:04d}.obj"
        text = [f"# neural_bake animated sample {anim.name}, t = {t:g}\n"]
        text.append("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in np.asarray(m.vertices).tolist()))
        text.append("".join(f"f {a} {b} {c}\n" for a, b, c in (np.asarray(m.faces) + 1).tolist()))
        atomic_write_text(folder / name, "".join(text).replace("-0.000000", "0.000000"))
        files.append(name)
    index = {"name": anim.name, "sdf_kind": anim.sdf_kind, "times": times, "frames": files}
    atomic_write_text(folder / FRAMES_FILE, json.dumps(index, indent=1) + "\n")
    return folder


def generate(
    out_dir: str | os.PathLike,
    names: Iterable[str] | None = None,
    *,
    resolution: int | None = None,
    texture_size: int | None = None,
) -> dict[str, Path]:
    """Generate samples ``names`` (default: all, static and animated) into ``out_dir`` (created if missing);
    return name -> OBJ (static samples) or name -> folder of frames (animations, :func:`write_animation`).

    - ``resolution``: approximate face count of every mesh (default: each sample's own, ~8k–24k).
    - ``texture_size``: texture width in texels (default 512; lat-long textures are half as high; animated
      frames have no texture).

    Raises :class:`NeuralBakeError` for an unknown name or an output path that is not a folder.
    """
    samples = check_generate_args(names, resolution, texture_size)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise NeuralBakeError(f"{out}: not a folder")
    out.mkdir(parents=True, exist_ok=True)
    written = {}
    for s in samples:
        if s.name in ANIMATED:
            written[s.name] = write_animation(s, out, resolution=resolution)
        else:
            written[s.name] = write_sample(s.mesh(resolution, texture_size), out, s.name)
    return written


def check_generate_args(names: Iterable[str] | None, resolution: int | None, texture_size: int | None) -> list:
    """The samples and animations ``names`` (default: all) stands for; NeuralBakeError for an unknown name or a
    bad size."""
    names = [*SAMPLES, *ANIMATED] if names is None else list(names)
    unknown = [n for n in names if n not in SAMPLES and n not in ANIMATED]
    if unknown:
        raise NeuralBakeError(f"unknown sample {unknown[0]!r} (known: {', '.join([*SAMPLES, *ANIMATED])})")
    samples = [ANIMATED[n] if n in ANIMATED else get_sample(n) for n in names]
    if resolution is not None and int(resolution) < 32:
        raise NeuralBakeError(f"resolution must be an approximate face count >= 32, got {resolution}")
    if texture_size is not None and int(texture_size) < 8:
        raise NeuralBakeError(f"texture size must be at least 8 texels, got {texture_size}")
    return samples


def main() -> None:  # pragma: no cover - `python -m neural_bake.samples.generate` refreshes the bundled files
    for name, path in generate(DATA_DIR, list(SAMPLES)).items():
        print(f"{name}: {path} ({path.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":  # pragma: no cover
    main()
