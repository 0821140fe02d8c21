"""Dynamic previews: a space-time field f(x, t) rendered frame by frame into numbered PNGs and a GIF or MP4.

Frame i of n renders f(·, t_i) with t_i spread evenly over the time range (both ends included). The PNG frames
go to a folder that is committed as a unit (:class:`~neural_bake.io.outdir.OutputFolder`: a reader sees the
whole old set or the whole new set, one writer at a time); the animation is written atomically with
imageio (GIF through Pillow, MP4 through the ffmpeg binary imageio-ffmpeg ships).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..constants import MAX_FRAMES, MAX_TIME_MAGNITUDE
from ..io.atomic import atomic_path
from ..io.colour import linear_to_srgb
from ..io.images import write_image
from ..io.outdir import OutputFolder
from ..fields.spacetime import time_to_tau
from ..limits import check_count, check_image_size, check_magnitude
from .asset import RenderError, SpaceTimeAsset
from .renderer import default_camera, render
from .scene import Scene
from .stats import EvalCounter

__all__ = ["SequenceResult", "render_sequence", "frame_times", "ANIMATION_FORMATS"]

#: Animation containers.
ANIMATION_FORMATS = (".gif", ".mp4")


@dataclass
class SequenceResult:
    """``frames``: the PNG paths in order; ``animation``: the GIF/MP4 path (or None); ``times``: t per frame;
    ``stats``: per-frame render stats and the summed evaluation counters."""

    frames: list[Path]
    animation: Path | None
    times: list[float]
    stats: dict


def frame_times(n: int, time_range: tuple[float, float]) -> list[float]:
    """``n`` times evenly over [t0, t1], ends included (one frame: t0)."""
    n = check_count(n, "frames", MAX_FRAMES, error=RenderError)
    t0, t1 = time_range
    return [float(t0)] if n == 1 else [float(v) for v in np.linspace(t0, t1, int(n))]


def render_sequence(
    asset: SpaceTimeAsset,
    scene: Scene,
    frames_dir,
    *,
    frames: int = 24,
    time_range: tuple[float, float] | None = None,
    times: Sequence[float] | None = None,
    animation=None,
    fps: float = 12.0,
    progress: Callable[[int, int, float], None] | None = None,
    size: tuple[int, int] | None = None,
    fov_deg: float | None = None,
    device=None,
) -> SequenceResult:
    """Render ``frames`` frames of ``asset`` (evenly over ``time_range``, or at ``times`` when given) into
    ``frames_dir/frame_0000.png`` … and, with ``animation``
    (a .gif or .mp4 path), the animation. The camera (the scene's, or one framing the asset at its first
    time, of ``size`` and ``fov_deg``) stays fixed over the sequence. ``progress(i, n, seconds)`` is called after each frame.
    ``device``: the torch device of the rays (default: the CPU; the networks stay where ``asset`` has them).
    """
    if not isinstance(asset, SpaceTimeAsset):
        raise RenderError(f"render_sequence: expected a space-time asset, got {type(asset).__name__}")
    tr = time_range or asset.time_range
    if times is None:
        tr = tuple(check_magnitude(t, "time_range", MAX_TIME_MAGNITUDE, error=RenderError) for t in tr)
        times = frame_times(frames, tr)
    else:
        check_count(len(times), "times", MAX_FRAMES, error=RenderError, what="frames")
        times = [float(t) for t in times]
        if not times or not all(math.isfinite(t) for t in times):
            raise RenderError(f"times: expected finite times, got {times!r:.80}")
        tr = (min(times), max(times))
    time_to_tau(times, asset.time_range, 1.0, name="t")  # every time inside the asset's range, before any frame
    if size is not None and scene.camera is None:
        check_image_size(*size, error=RenderError)
    if not (isinstance(fps, (int, float)) and 0 < fps <= 120):
        raise RenderError(f"fps: expected a number in (0, 120], got {fps!r}")
    anim = Path(animation) if animation is not None else None
    if anim is not None and anim.suffix.lower() not in ANIMATION_FORMATS:
        raise RenderError(f"{anim}: unknown animation format {anim.suffix!r} (expected .gif or .mp4)")
    frames_dir = Path(frames_dir)
    parent = frames_dir.parent if str(frames_dir.parent) else Path(".")
    if not parent.is_dir():
        raise RenderError(f"{frames_dir}: folder {parent} does not exist")
    camera = scene.camera
    if camera is None:
        w, h = size or (256, 256)
        camera = default_camera([asset.at(times[0])], width=w, height=h, fov_deg=fov_deg or 40.0)
    scene = scene.with_(camera=camera)
    counter = EvalCounter()
    per_frame, images = [], []
    with OutputFolder(frames_dir) as tmp:  # committed as a unit, one writer, a symlink followed
        paths = []
        for i, t in enumerate(times):
            res = render(asset.at(t), scene, device=device)
            counter.merge(res.counter)
            rgb = res.channels.get("color")
            if rgb is None:
                raise RenderError("render_sequence: the scene must ask for the color channel")
            name = f"frame_{i:04d}.png"
            write_image(tmp / name, rgb, colour="srgb")
            paths.append(frames_dir / name)
            images.append(np.round(np.clip(linear_to_srgb(np.clip(rgb, 0, 1)), 0, 1) * 255).astype(np.uint8))
            per_frame.append({"time": t, "seconds": res.stats["seconds"]["total"], "hit": res.stats["pixels"]["hit"]})
            if progress is not None:
                progress(i + 1, len(times), res.stats["seconds"]["total"])
    if anim is not None:
        _write_animation(anim, images, fps)
    stats = {"frames": per_frame, "evaluations": counter.to_dict(), "camera": camera.to_dict(),
             "time_range": list(tr), "fps": fps}
    return SequenceResult(paths, anim, times, stats)


def _write_animation(path: Path, images: list[np.ndarray], fps: float) -> None:
    import imageio.v3 as iio

    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".gif":
            iio.imwrite(tmp, np.stack(images), extension=".gif", duration=1000.0 / fps, loop=0)
        else:
            iio.imwrite(tmp, np.stack(images), extension=".mp4", fps=fps, codec="libx264",
                        macro_block_size=1, plugin="FFMPEG")
