"""Dynamic previews: a space-time field f(x, t) rendered frame by frame into numbered PNGs and a GIF or MP4,
or at one time into a still (:func:`render_time`).

Frame i of n renders f(·, t_i) with t_i spread evenly over the time range (both ends included). The PNG
frames, and beside each the other channels asked for (``frame_0003.depth.png``…, as
:func:`~.output.write_render` writes them), go to a folder that is committed as a unit
(:class:`~neural_bake.io.outdir.OutputFolder`: a reader sees the whole old set or the whole new set, one
writer at a time); the animation is written atomically with imageio (GIF through Pillow, MP4 through the
ffmpeg binary imageio-ffmpeg ships).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..constants import MAX_FRAMES, MAX_TIME_MAGNITUDE
from ..io.atomic import atomic_path
from ..io.colour import linear_to_srgb
from ..io.outdir import OutputFolder
from ..fields.spacetime import time_to_tau
from ..limits import check_count, check_image_size, check_magnitude
from .asset import RenderError, SpaceTimeAsset
from .camera import Camera
from .output import CHANNEL_FORMATS, write_render
from .renderer import RenderResult, default_camera, render
from .scene import Scene
from .stats import EvalCounter

__all__ = ["SequenceResult", "render_sequence", "render_time", "frame_times", "ANIMATION_FORMATS"]

#: Animation containers.
ANIMATION_FORMATS = (".gif", ".mp4")


@dataclass
class SequenceResult:
    """``frames``: the PNG paths in order; ``animation``: the GIF/MP4 path (or None); ``times``: t per frame;
    ``stats``: per-frame render stats and the summed evaluation counters; ``channels``: the other channels'
    paths per frame, by channel name (``{"depth": [frame_0000.depth.png, …]}``)."""

    frames: list[Path]
    animation: Path | None
    times: list[float]
    stats: dict
    channels: dict[str, list[Path]] = field(default_factory=dict)


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
    channel_format: str = "png",
    progress: Callable[[int, int, float], None] | None = None,
    size: tuple[int, int] | None = None,
    fov_deg: float | None = None,
    device=None,
) -> SequenceResult:
    """Render ``frames`` frames of ``asset`` (evenly over ``time_range``, or at ``times`` when given) into
    ``frames_dir/frame_0000.png`` …, the scene's other channels beside each frame (``frame_0000.depth.png``…,
    ``channel_format`` "png" or "exr" as :func:`~.output.write_render`) and, with ``animation``
    (a .gif or .mp4 path), the animation of the colour frames. The camera (the scene's, or one framing the
    asset at its first time, of ``size`` and ``fov_deg``) stays fixed over the sequence. ``progress(i, n,
    seconds)`` is called after each frame.
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
    if channel_format not in CHANNEL_FORMATS:
        raise RenderError(f"channel_format {channel_format!r}: expected one of {', '.join(CHANNEL_FORMATS)}")
    if "color" not in scene.channels:
        raise RenderError("render_sequence: the scene must ask for the color channel")
    if not (isinstance(fps, (int, float)) and 0 < fps <= 120):
        raise RenderError(f"fps: expected a number in (0, 120], got {fps!r}")
    anim = Path(animation) if animation is not None else None
    if anim is not None and anim.suffix.lower() not in ANIMATION_FORMATS:
        raise RenderError(f"{anim}: unknown animation format {anim.suffix!r} (expected .gif or .mp4)")
    frames_dir = Path(frames_dir)
    parent = frames_dir.parent if str(frames_dir.parent) else Path(".")
    if not parent.is_dir():
        raise RenderError(f"{frames_dir}: folder {parent} does not exist")
    camera = _camera(asset, scene, times[0], size, fov_deg)
    scene = scene.with_(camera=camera)
    counter = EvalCounter()
    per_frame, images = [], []
    extra: dict[str, list[Path]] = {}
    with OutputFolder(frames_dir) as tmp:  # committed as a unit, one writer, a symlink followed
        paths = []
        for i, t in enumerate(times):
            res = render(asset.at(t), scene, device=device)
            counter.merge(res.counter)
            rgb = res.channels["color"]
            name = f"frame_{i:04d}.png"
            written = write_render(res, tmp / name, channel_format=channel_format)  # colour first
            paths.append(frames_dir / name)
            for c, p in zip([c for c in res.stats["channels"] if c != "color" and c in res.channels], written[1:]):
                extra.setdefault(c, []).append(frames_dir / p.name)
            images.append(np.round(np.clip(linear_to_srgb(np.clip(rgb, 0, 1)), 0, 1) * 255).astype(np.uint8))
            per_frame.append({"time": t, "seconds": res.stats["seconds"]["total"], "hit": res.stats["pixels"]["hit"]})
            if progress is not None:
                progress(i + 1, len(times), res.stats["seconds"]["total"])
    if anim is not None:
        _write_animation(anim, images, fps)
    stats = {"frames": per_frame, "evaluations": counter.to_dict(), "camera": camera.to_dict(),
             "time_range": list(tr), "fps": fps}
    return SequenceResult(paths, anim, times, stats, extra)


def render_time(
    asset: SpaceTimeAsset,
    scene: Scene,
    t: float,
    *,
    size: tuple[int, int] | None = None,
    fov_deg: float | None = None,
    device=None,
) -> RenderResult:
    """Render ``asset`` at the one time ``t`` as :func:`render_sequence` renders that frame (the same camera:
    the scene's, or one framing the asset, of ``size`` and ``fov_deg``); write it with
    :func:`~.output.write_render`. ``result.stats["time"]`` is ``t``.

    Raises RenderError for an asset that is not space-time or a non-finite ``t``, TimeRangeError for a ``t``
    outside the asset's time range.
    """
    if not isinstance(asset, SpaceTimeAsset):
        raise RenderError(f"render_time: expected a space-time asset, got {type(asset).__name__}")
    t = check_magnitude(t, "t", MAX_TIME_MAGNITUDE, error=RenderError)
    time_to_tau(t, asset.time_range, 1.0, name="t")
    if size is not None and scene.camera is None:
        check_image_size(*size, error=RenderError)
    res = render(asset.at(t), scene.with_(camera=_camera(asset, scene, t, size, fov_deg)), device=device)
    res.stats["time"] = t
    return res


def _camera(asset: SpaceTimeAsset, scene: Scene, t: float, size, fov_deg) -> Camera:
    """The scene's camera, else one framing ``asset`` at ``t`` of ``size`` (default 256²) and ``fov_deg``."""
    if scene.camera is not None:
        return scene.camera
    w, h = size or (256, 256)
    return default_camera([asset.at(t)], width=w, height=h, fov_deg=fov_deg or 40.0)


def _write_animation(path: Path, images: list[np.ndarray], fps: float) -> None:
    import imageio.v3 as iio

    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".gif":
            iio.imwrite(tmp, np.stack(images), extension=".gif", duration=1000.0 / fps, loop=0)
        else:
            iio.imwrite(tmp, np.stack(images), extension=".mp4", fps=fps, codec="libx264",
                        macro_block_size=1, plugin="FFMPEG")
