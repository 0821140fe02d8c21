"""Per-frame baking of a space-time SDF: at each time t, the coarse level marched into a mesh, and per-vertex
neural normals ∇f(·, t) / |∇f(·, t)| of the fine level at the same t (GEMM normals), written as numbered PLY
or GLB frames.

The frames go to a folder committed as a unit (:class:`~neural_bake.io.outdir.OutputFolder`: a reader sees the
whole old set or the whole new set; a failed run leaves the old folder untouched).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..errors import NeuralBakeError
from ..io.outdir import OutputFolder
from ..nets.gemm import gemm_gradient, normalized_gradient
from ..nets.siren import Siren
from ..types import Frame

__all__ = ["FrameBake", "bake_frames", "FRAME_FORMATS"]

#: Formats of the baked frames.
FRAME_FORMATS = ("ply", "glb")


@dataclass
class FrameBake:
    """What :func:`bake_frames` wrote: ``files`` in time order, ``times``, and per-frame ``stats``
    (vertices, faces, seconds of marching and of normals, invalid normals)."""

    files: list[Path]
    times: list[float]
    stats: list[dict]


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
) -> FrameBake:
    """Bake frames of a space-time SDF at ``times`` into ``out_dir/<name>_0000.<fmt>`` … and ``frames.json``.

    Args:
        coarse_at, fine_at: t ↦ the 3-D Siren of the coarse and fine levels at t (e.g. ``fit.at`` of a
            :class:`~neural_bake.fit.spacetime.SpaceTimeFit`, or slices of a space-time nested sequence); they
            raise :class:`~neural_bake.errors.TimeRangeError` for a t outside the fitted range.
        frame: the common unit frame of the fields (outputs are in its source frame).
        times: the frame times.
        resolution: marching-cubes cells per axis of the coarse mesh.
        fmt: "ply" (positions, neural normals) or "glb" (positions, neural normals).
        pruned: marching-cubes octree pruning (:func:`~neural_bake.mesh.marching.march`).
        name: the files' stem.

    Returns:
        A :class:`FrameBake`.

    Raises:
        NeuralBakeError: an unknown format, no times, an output folder whose parent does not exist, a frame
            whose coarse level has no surface; TimeRangeError for a time outside the range (before anything
            is written).
    """
    from ..mesh.marching import march
    from .export import export_glb, export_vertex_ply

    if fmt not in FRAME_FORMATS:
        raise NeuralBakeError(f"fmt: expected one of {', '.join(FRAME_FORMATS)}, got {fmt!r}")
    times = [float(t) for t in np.atleast_1d(np.asarray(times, dtype=np.float64))]
    if not times:
        raise NeuralBakeError("times: give at least one frame time")
    out_dir = Path(out_dir)
    parent = out_dir.parent if str(out_dir.parent) else Path(".")
    if not parent.is_dir():
        raise NeuralBakeError(f"{out_dir}: folder {parent} does not exist")
    for t in times:  # every time checked before any work: a bad one fails fast
        coarse_at(t)
    files, stats = [], []
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
            fname = f"{name}_{i:04d}.{fmt}"
            if fmt == "ply":
                export_vertex_ply(tmp / fname, mesh, normals=normals)
            else:
                export_glb(tmp / fname, mesh, normals=normals)
            files.append(out_dir / fname)
            stats.append({"t": t, "vertices": mesh.n_vertices, "faces": mesh.n_faces, "march_s": round(t1 - t0, 4),
                          "normals_s": round(t2 - t1, 4), "write_s": round(time.perf_counter() - t2, 4),
                          "invalid_normals": int(bad.sum())})
        (tmp / "frames.json").write_text(json.dumps({"times": times, "frames": [f.name for f in files],
                                                     "stats": stats}, indent=1) + "\n")
    return FrameBake(files, times, stats)
