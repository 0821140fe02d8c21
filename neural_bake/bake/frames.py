"""Per-frame baking of a space-time SDF: at each time t, the coarse level marched into a mesh, and per-vertex
neural normals ∇f(·, t) / |∇f(·, t)| of the fine level at the same t (GEMM normals), written as numbered PLY
or GLB frames or as one USD stage with time samples (the optional extra ``usd``); with a texture field, per-vertex colours g(·, t) at the same vertices (a static field evaluated
on the moving surface, or a space-time one sliced at t).

The frames go to a folder committed as a unit (:class:`~neural_bake.io.outdir.OutputFolder`: a reader sees the
whole old set or the whole new set; a failed run leaves the old folder untouched).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Union

import numpy as np
import torch

from ..constants import MAX_FRAMES, MAX_MARCH_RESOLUTION
from ..errors import NeuralBakeError
from ..fields.texture import TextureField
from ..io.atomic import atomic_write_text
from ..io.outdir import OutputFolder
from ..limits import check_count
from ..nets.gemm import gemm_gradient, normalized_gradient
from ..nets.siren import Siren
from ..types import Frame

__all__ = ["FrameBake", "bake_frames", "FRAME_FORMATS"]

#: Formats of the baked frames: one file per frame (ply, glb) or one stage with time samples (usd).
FRAME_FORMATS = ("ply", "glb", "usd")

#: A texture for :func:`bake_frames`: one static field, or t ↦ the field at t.
FrameTexture = Union[TextureField, Callable[[float], TextureField]]


@dataclass
class FrameBake:
    """What :func:`bake_frames` wrote: ``files`` in time order (one stage for usd), ``times``, per-frame
    ``stats`` (vertices, faces, seconds of marching, of normals and of colours, invalid normals, bytes of the
    frame's file, or for usd of the PLY file it would have been) and ``sizes`` (``file_bytes``: what was
    written; ``ply_bytes``: the per-frame PLY files' total, written or, for usd, the size of their content
    built in memory)."""

    files: list[Path]
    times: list[float]
    stats: list[dict]
    sizes: dict | None = None


def bake_frames(
    coarse_at: Callable[[float], Siren],
    fine_at: Callable[[float], Siren],
    frame: Frame,
    times,
    out_dir,
    *,
    resolution: int = 64,
    fmt: str = "ply",
    pruned: bool | str = "auto",
    name: str = "frame",
    texture: FrameTexture | None = None,
    fps: float = 24.0,
) -> FrameBake:
    """Bake frames of a space-time SDF at ``times`` into ``out_dir/<name>_0000.<fmt>`` … and ``frames.json``.

    Args:
        coarse_at, fine_at: t ↦ the 3-D Siren of the coarse and fine levels at t (e.g. ``fit.at`` of a
            :class:`~neural_bake.fit.spacetime.SpaceTimeFit`, or slices of a space-time nested sequence); they
            raise :class:`~neural_bake.errors.TimeRangeError` for a t outside the fitted range.
        frame: the common unit frame of the fields (outputs are in its source frame).
        times: the frame times.
        resolution: marching-cubes cells per axis of the coarse mesh.
        fmt: "ply" (positions, neural normals, 8-bit sRGB vertex colours), "glb" (positions, neural normals,
            linear COLOR_0), or "usd": one stage ``<name>.usd`` with time-sampled points, topology, normals and
            linear ``primvars:displayColor`` (:func:`~neural_bake.io.usd.write_usd_frames`; frame i at time
            code i).
        pruned: marching-cubes octree pruning (:func:`~neural_bake.mesh.marching.march`).
        name: the files' stem.
        texture: None (no colours), a :class:`~neural_bake.fields.texture.TextureField` evaluated at each
            frame's vertices (a static colour field on the moving surface), or t ↦ the texture field at t (a
            space-time field g(·, t)). Its ``frame`` (None: ``frame``) says which unit frame its points are in.
        fps: frames per second of the usd stage (its time codes per second).

    Returns:
        A :class:`FrameBake`.

    Raises:
        MissingExtraError: fmt "usd" without usd-core (before any work).
        NeuralBakeError: an unknown format, a bad fps, no times or more than ``MAX_FRAMES``, a resolution beyond
            ``MAX_MARCH_RESOLUTION``, an output folder whose parent does not exist, a frame whose coarse level
            has no surface; TimeRangeError for a time outside the range (before anything
            is written).
    """
    from ..mesh.marching import march
    from .export import export_glb, export_vertex_ply, vertex_ply_bytes

    if fmt not in FRAME_FORMATS:
        raise NeuralBakeError(f"fmt: expected one of {', '.join(FRAME_FORMATS)}, got {fmt!r}")
    if isinstance(fps, bool) or not (isinstance(fps, (int, float)) and np.isfinite(fps) and fps > 0):
        raise NeuralBakeError(f"fps {fps!r}: must be a positive number of frames per second", parameter="fps")
    if fmt == "usd":
        from ..io.usd import import_pxr, write_usd_frames
        from .usd_export import usd_frame

        import_pxr()  # usd-core missing: one line saying how to install it, before any work
    check_count(resolution, "resolution", MAX_MARCH_RESOLUTION, minimum=2, what="marching-cubes cells per axis")
    times = [float(t) for t in np.atleast_1d(np.asarray(times, dtype=np.float64))]
    if not times:
        raise NeuralBakeError("times: give at least one frame time")
    check_count(len(times), "times", MAX_FRAMES, what="frames")
    out_dir = Path(out_dir)
    parent = out_dir.parent if str(out_dir.parent) else Path(".")
    if not parent.is_dir():
        raise NeuralBakeError(f"{out_dir}: folder {parent} does not exist")
    for t in times:  # every time checked before any work: a bad one fails fast
        coarse_at(t)
    files, stats, usd_frames = [], [], []
    with OutputFolder(out_dir) as tmp:
        for i, t in enumerate(times):
            t0 = time.perf_counter()
            coarse, fine = coarse_at(t), fine_at(t)
            try:
                mesh, _ = march(coarse, resolution, pruned=pruned, frame=frame)
            except NeuralBakeError as exc:  # e.g. no zero crossing: say at which time
                raise NeuralBakeError(f"t = {t:g}: {exc}") from None
            t1 = time.perf_counter()
            p = next(fine.parameters())
            with torch.no_grad():
                _, g = gemm_gradient(fine, torch.as_tensor(mesh.vertices, dtype=p.dtype, device=p.device))
            unit, valid = normalized_gradient(g)
            normals = unit.double().cpu().numpy()
            bad = ~valid.cpu().numpy()
            if bad.any():  # no neural direction there: the coarse mesh's own normal
                normals[bad] = mesh.vertex_normals[bad]
            t2 = time.perf_counter()
            colours = None if texture is None else _colours(texture, t, mesh)
            t3 = time.perf_counter()
            fname = f"{name}_{i:04d}.{fmt}"
            if fmt == "ply":
                export_vertex_ply(tmp / fname, mesh, normals=normals, vertex_colors=colours)
            elif fmt == "glb":
                export_glb(tmp / fname, mesh, normals=normals, vertex_colors=colours)
            else:  # kept for the one stage written after the last frame
                usd_frames.append(usd_frame(mesh, normals, colours))
            if fmt == "usd":
                size = {"ply_bytes": len(vertex_ply_bytes(mesh, normals=normals, vertex_colors=colours))}
            else:
                files.append(out_dir / fname)
                size = {"bytes": (tmp / fname).stat().st_size}
            stats.append({"t": t, "vertices": mesh.n_vertices, "faces": mesh.n_faces, "march_s": round(t1 - t0, 4),
                          "normals_s": round(t2 - t1, 4), "colours_s": round(t3 - t2, 4),
                          "write_s": round(time.perf_counter() - t3, 4),
                          "invalid_normals": int(bad.sum()), **size})
        if fmt == "usd":
            write_usd_frames(tmp / f"{name}.usd", usd_frames, fps=fps, times=times)
            files.append(out_dir / f"{name}.usd")
            sizes = {"file_bytes": (tmp / f"{name}.usd").stat().st_size, "fps": fps,
                     "ply_bytes": sum(s["ply_bytes"] for s in stats),
                     "ply_note": "the per-frame PLY files' content built in memory, not written"}
        else:
            sizes = {"file_bytes": sum(s["bytes"] for s in stats)}
            if fmt == "ply":
                sizes["ply_bytes"] = sizes["file_bytes"]
        atomic_write_text(tmp / "frames.json", json.dumps({"times": times, "frames": [f.name for f in files],
                                                           "format": fmt, "sizes": sizes, "stats": stats},
                                                          indent=1) + "\n")
    return FrameBake(files, times, stats, sizes)


def _colours(texture: FrameTexture, t: float, mesh) -> np.ndarray:
    """Linear colours (V, C) of the texture field at time ``t`` at the mesh's vertices (mesh unit frame; a field
    with normal inputs reads the mesh's vertex normals)."""
    from .baker import _evaluate

    field = texture if isinstance(texture, TextureField) else texture(t)
    if not isinstance(field, TextureField):
        raise NeuralBakeError(f"texture: at t = {t:g} expected a TextureField, got {type(field).__name__}")
    from ..geometry import vertex_normals

    normals = vertex_normals(mesh) if getattr(field, "normal_inputs", False) else None
    colours = _evaluate(mesh.vertices, mesh.frame, None, field, 65536, surface_normals=normals)["colors"]
    if colours.ndim != 2 or colours.shape[1] not in (3, 4):
        raise NeuralBakeError(f"texture: {field.name} gives {colours.shape[1:]} values per point, expected 3 or 4")
    return colours
