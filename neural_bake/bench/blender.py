"""Blender's Cycles "selected to active" normal bake, the artists' anchor, run in Blender's own process.

Blender (the ``bpy`` wheel) never loads into our interpreter: it needs Python 3.13 and ``libvulkan.so.1``,
so it lives in its own venv (``make setup-blender`` makes ``.cache/blender-venv``). :func:`find_python`
picks that interpreter (the ``python`` argument, else ``$NEURAL_BAKE_BLENDER_PYTHON``, else
``.cache/blender-venv/bin/python`` of the checkout or of the working directory); :func:`available` says
whether ``bpy`` imports under it; :func:`cycles_bake` writes the two meshes to an .npz, runs
``blender_worker.py`` under it (a subprocess with a timeout, stderr captured) and returns the map with the
worker's timings and the whole process's wall. Every failure is one :class:`BlenderError` line.
:func:`decode_samples` reads the map at our texel samples with the decoder the benchmark uses for ours: object
space as is, tangent space with Blender's own MikkTSpace frames (the basis its bake used).
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import NeuralBakeError
from ..types import Mesh

__all__ = ["BlenderError", "CyclesBake", "ENV_VAR", "available", "cycles_bake", "decode_samples", "find_python"]

#: Environment variable naming the Python interpreter that has ``bpy``.
ENV_VAR = "NEURAL_BAKE_BLENDER_PYTHON"
#: The venv ``scripts/setup-blender.sh`` makes, relative to the checkout (or the working directory).
VENV = Path(".cache") / "blender-venv"
WORKER = Path(__file__).with_name("blender_worker.py")
SETUP_HINT = "make setup-blender (or scripts/setup-blender.sh) makes .cache/blender-venv"


class BlenderError(NeuralBakeError):
    """Blender's interpreter is missing or broken, or its bake failed: the message is one line."""


@dataclass
class CyclesBake:
    """One Cycles bake.

    - ``normal_map``: (size, size, 3) float32 in [0, 1], (n + 1) / 2, row 0 at the top.
    - ``normal_space``: "tangent" (OpenGL, +Y green up, Blender's MikkTSpace frames) or "object".
    - ``frames``: (F, 3, 7) float32 per face corner of the coarse mesh: tangent (3), bitangent sign (1), normal
      (3) as Blender's bake used them; tangent space only, else None.
    - ``timings``: seconds of the worker's ``import`` (bpy), ``setup`` (scene, objects), ``bake`` (the bake
      call), ``read`` (the map out), ``script`` (its wall), ``frames`` (their export, tangent space only),
      ``process`` (the subprocess's wall seen from here) and ``whole`` (``process`` without ``frames``: what
      a user's bake script costs from its start, interpreter start-up included); ``version`` is Blender's.
    """

    normal_map: np.ndarray
    normal_space: str
    frames: np.ndarray | None = None
    timings: dict = field(default_factory=dict)


def _one_line(text: str, limit: int = 240) -> str:
    lines = [s.strip() for s in text.strip().splitlines() if s.strip()]
    return (lines[-1] if lines else "")[:limit]


def find_python(python: str | os.PathLike | None = None) -> Path:
    """The interpreter to run Blender with: ``python`` when given, else ``$NEURAL_BAKE_BLENDER_PYTHON``, else
    ``.cache/blender-venv/bin/python`` in the checkout or the working directory (which need not exist: the
    first candidate found, or the checkout's path). No check that ``bpy`` imports (:func:`available`)."""
    if python:
        return Path(python)
    if os.environ.get(ENV_VAR):
        return Path(os.environ[ENV_VAR])
    candidates = [Path(__file__).resolve().parents[2] / VENV / "bin" / "python", Path.cwd() / VENV / "bin" / "python"]
    return next((c for c in candidates if c.exists()), candidates[0])


@functools.lru_cache(maxsize=8)
def _probe(python: str, timeout: float) -> tuple[bool, str]:
    code = "import bpy, sys; print('Blender', bpy.app.version_string, '(Python %d.%d)' % sys.version_info[:2])"
    try:
        res = subprocess.run([python, "-I", "-c", code], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False, f"{python}: 'import bpy' took over {timeout:g} s"
    except OSError as exc:
        return False, f"{python}: cannot run ({exc.strerror or exc})"
    if res.returncode != 0:
        return False, f"{python}: bpy does not import ({_one_line(res.stderr) or f'exit code {res.returncode}'})"
    return True, _one_line(res.stdout)


def available(python: str | os.PathLike | None = None, *, timeout: float = 120.0) -> tuple[bool, str]:
    """(True, Blender's version and its Python's, one line) when ``bpy`` imports under :func:`find_python`'s
    interpreter, else (False, the reason in one line; ``SETUP_HINT`` says how to set it up). Runs the
    interpreter once per path (cached)."""
    exe = find_python(python)
    if not exe.exists():
        return False, f"no Blender interpreter at {exe}"
    return _probe(str(exe), float(timeout))


def cycles_bake(
    coarse: Mesh,
    fine: Mesh,
    size: int,
    *,
    normal_space: str = "tangent",
    margin: int = 16,
    cage: float = 0.05,
    max_ray_distance: float | None = None,
    threads: int | None = None,
    python: str | os.PathLike | None = None,
    timeout: float = 1800.0,
) -> CyclesBake:
    """Bake ``fine``'s normals onto ``coarse``'s UV layout with Cycles "selected to active" on the CPU (one
    sample per texel), in Blender's own process.

    ``coarse``: the mesh the map belongs to, with per-corner UVs (F, 3, 2) (v = 0 at the bottom), e.g.
    ``Baker.mesh``. ``fine``: the source mesh, in the same frame. The vertex normals of both (``vertex_normals``,
    else area-weighted) become Blender's custom normals, so Blender starts from the same low-poly surface as
    our bakers and reads the same source normals where its rays land.
    ``normal_space``: "tangent" (OpenGL) or "object". ``margin``: pixels of padding around the charts.
    ``cage``: how far the rays start outside the coarse surface along its normals; ``max_ray_distance``:
    their length (default 2 × ``cage``). ``threads``: Cycles threads (default Blender's choice).
    ``python``: see :func:`find_python`. Raises :class:`BlenderError` (one line) when the interpreter is
    missing, the worker exits non-zero, or it runs longer than ``timeout`` seconds.
    """
    from ..geometry import vertex_normals

    if normal_space not in ("tangent", "object"):
        raise BlenderError(f"normal_space must be 'tangent' or 'object', got {normal_space!r}")
    if isinstance(size, bool) or int(size) != size or size < 1:
        raise BlenderError(f"size must be a positive integer, got {size!r}")
    if coarse.uv is None:
        raise BlenderError("coarse mesh has no UVs: Blender bakes into the coarse mesh's UV layout (use Baker.mesh)")
    exe = find_python(python)
    if not exe.exists():
        raise BlenderError(f"no Blender interpreter at {exe}: {SETUP_HINT}, or pass its python ({ENV_VAR})")
    with tempfile.TemporaryDirectory(prefix="neural-bake-blender-") as tmp:
        inp, out = Path(tmp) / "in.npz", Path(tmp) / "out"
        np.savez(inp, low_vertices=np.asarray(coarse.vertices, np.float64), low_faces=np.asarray(coarse.faces, np.int64),
                 low_uv=np.asarray(coarse.uv, np.float32), low_normals=vertex_normals(coarse),
                 high_vertices=np.asarray(fine.vertices, np.float64), high_faces=np.asarray(fine.faces, np.int64),
                 high_normals=vertex_normals(fine))
        ray = 2.0 * float(cage) if max_ray_distance is None else float(max_ray_distance)
        cmd = [str(exe), "-I", str(WORKER), str(inp), str(out), "--size", str(int(size)), "--space", normal_space,
               "--margin", str(int(margin)), "--cage", repr(float(cage)), "--max-ray-distance", repr(ray),
               "--threads", str(int(threads or 0))]
        t0 = time.perf_counter()
        try:
            res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise BlenderError(f"Blender's bake ran over its timeout of {timeout:g} s ({exe})")
        except OSError as exc:
            raise BlenderError(f"cannot run {exe}: {exc.strerror or exc}")
        process = time.perf_counter() - t0
        if res.returncode != 0:
            why = _one_line(res.stderr) or _one_line(res.stdout) or "no message"
            raise BlenderError(f"Blender's bake failed (exit code {res.returncode}): {why}")
        try:
            normal_map = np.load(out / "map.npy")
            frames = np.load(out / "frames.npy") if normal_space == "tangent" else None
            timings = json.loads((out / "timings.json").read_text())
        except (OSError, ValueError) as exc:
            raise BlenderError(f"Blender's bake wrote no readable result ({type(exc).__name__}: {_one_line(str(exc))})")
    if normal_map.shape != (size, size, 3):
        raise BlenderError(f"Blender's map is {normal_map.shape}, expected {(size, size, 3)}")
    if frames is not None and frames.shape != (coarse.n_faces, 3, 7):
        raise BlenderError(f"Blender's frames are {frames.shape}, expected {(coarse.n_faces, 3, 7)}")
    timings["process"] = process
    timings["whole"] = process - float(timings.get("frames", 0.0))
    return CyclesBake(normal_map=normal_map, normal_space=normal_space, frames=frames, timings=timings)


def decode_samples(bake: CyclesBake, texels, *, bits: int | None = 8) -> np.ndarray:
    """Object-space unit normals (M, 3) that ``bake``'s map gives at the texel samples (``texels.pixel``,
    ``.face``, ``.bary`` of the same coarse mesh and size), quantised to ``bits`` first: the decoder the
    benchmark applies to our maps (nearest texel). Tangent space is decoded as Blender's bake encoded it,
    ``normalize(x T + y B + z N)`` with T and N its per-corner MikkTSpace tangent and normal interpolated at
    the sample and B = sign × N × T."""
    from ..bake.maps import decode_tangent_space
    from ..bake.report import decode_map

    if bake.normal_space == "object":
        return decode_map(bake.normal_map, texels, normal_space="object", bits=bits)
    x = decode_map(bake.normal_map, texels, normal_space="object", bits=bits)  # the stored unit vectors
    corner = np.asarray(bake.frames, dtype=np.float64)[np.asarray(texels.face)]  # (M, 3, 7)
    w = np.asarray(texels.bary, dtype=np.float64)[:, :, None]
    t = (corner[:, :, 0:3] * w).sum(axis=1)
    n = (corner[:, :, 4:7] * w).sum(axis=1)
    sign = np.where((corner[:, :, 3:4] * w).sum(axis=1) < 0.0, -1.0, 1.0)
    b = sign * np.cross(n, t)
    return decode_tangent_space(x, t, b, n, "opengl")

