"""`neural-bake render MODEL -o OUT.png`: a sphere-traced preview of a fitted SDF or nested sequence (thin verb).

Parses the options into a :class:`~neural_bake.render.scene.Scene` (a scene file first, options on top),
renders with :func:`neural_bake.render.render` and writes OUT, the extra channels beside it and, with
--stats, the evaluation counters as JSON. A space-time model (networks of x, y, z, t) with OUT ending in
.gif or .mp4 renders --frames frames (each with its channels beside it) into OUT's ``<stem>_frames/`` folder
and the animation into OUT; with OUT a folder, the frames alone; with OUT an image, the one time --t names.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import click

from .config_options import ConfigCommand, ConfigSpec
from .options import say, verbosity, verbosity_options

__all__ = ["command", "RenderOptions"]


def _vec3(text: str | None, option: str):
    from neural_bake.render.scene import SceneError

    if text is None:
        return None
    try:
        v = tuple(float(c) for c in text.split(","))
    except ValueError:
        raise SceneError(f"{option}: expected X,Y,Z numbers, got {text!r}") from None
    if len(v) != 3:
        raise SceneError(f"{option}: expected X,Y,Z (3 numbers), got {text!r}")
    return v


def _size(text: str | None):
    from neural_bake.render.scene import SceneError

    if text is None:
        return None
    try:
        parts = [int(p) for p in text.lower().split("x")]
    except ValueError:
        raise SceneError(f"--size: expected N or WxH pixels, got {text!r}") from None
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or min(parts) < 1:
        raise SceneError(f"--size: expected N or WxH pixels ≥ 1, got {text!r}")
    from neural_bake.limits import check_image_size

    return check_image_size(parts[0], parts[1], error=SceneError)


@dataclass
class RenderOptions:
    """The render verb's settings on top of the scene file (``--config``/``--scene``); one line per field."""

    device: str | None = None
    """Torch device of the networks and rays: cpu, cuda, cuda:1, … (none: cpu)."""
    texture: str | None = None
    """Texture field file (neural texture mapping; adds the texture effect)."""
    size: str | None = None
    """Image size: N (square) or WxH pixels (none: the scene camera's, else 256)."""
    camera: str | None = None
    """Eye position X,Y,Z (source frame)."""
    look_at: str | None = None
    """Target X,Y,Z (source frame) (none: the object's centre)."""
    fov: float | None = None
    """Vertical field of view in degrees (none: the scene camera's, else 40)."""
    effects: str = ""
    """Comma-separated: shading, normal_mapping, texture, shadows, ambient_occlusion, hole_map, or none (empty:
    the scene's, else shading)."""
    channels: str = ""
    """Comma-separated: color, depth, normal, hit, iterations, holes, lod (empty: the scene's, else color); the
    others are written beside OUT as OUT-stem.<channel>.<ext> (beside each frame of a space-time model)."""
    channel_format: str = "png"
    """File format of the extra channels: png, or exr (raw values)."""
    mode: str = ""
    """Sphere tracing: fixed (iterations per level, the paper's) or threshold (a distance threshold with a cap);
    empty: the scene's."""
    iterations: str | None = None
    """Iterations per level, coarse to fine, e.g. 30,30 (0 skips a level)."""
    guaranteed: bool = False
    """Cast primary rays with range analysis (slower, exact)."""
    skip: bool = True
    """Empty-space skipping."""
    frames: int = 24
    """Frames of a space-time model's animation."""
    time_range: str | None = None
    """T0,T1 of a space-time model (none: the model's)."""
    t: str | None = None
    """Frame times of a space-time model: START:STOP:COUNT (e.g. 0:1:60) or a list 0,0.5,1 (instead of
    ``frames`` and ``time_range``)."""
    fps: float = 12.0
    """Animation frame rate."""
    stats: str | None = None
    """JSON file of the evaluation counters per network and effect, timings and pixel counts."""
    precision: str = "fp32"
    """Hidden GEMMs of the networks: fp32, or auto (bfloat16 where measured faster on this CPU/GPU)."""
    force: bool = False
    """Render a texture fitted in another frame or on another surface than MODEL (with a warning)."""


#: The values of RenderOptions' fields that take one of a few words.
_CHOICES = {"channel_format": ("png", "exr"), "mode": ("", "fixed", "threshold"), "precision": ("fp32", "auto")}


def _resolve(preset, values) -> RenderOptions:
    from neural_bake.render.scene import SceneError

    options = RenderOptions(**values)
    for name, words in _CHOICES.items():
        if getattr(options, name) not in words:
            raise SceneError(f"--{name.replace('_', '-')}: expected one of {', '.join(w for w in words if w)}, got "
                             f"{getattr(options, name)!r}")
    return options


SPEC = ConfigSpec(load=lambda: RenderOptions, resolve=_resolve, settings_file=False)


@click.command(cls=ConfigCommand, config=SPEC, epilog="""\b
Examples:
  neural-bake render bumpy.nested -o bumpy.png --texture bumpy.tex --size 512
  neural-bake render bumpy.nested -o bumpy.png --config scene.toml --effects shading,shadows --device cuda
  neural-bake render morph.sdf -o morph.gif --frames 24 --fps 12
  neural-bake render morph.sdf -o half.png --t 0.5 --channels color,depth""")
@click.argument("model", metavar="MODEL", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", default=None, type=click.Path(),
              help="Colour image (PNG, EXR…); for a space-time model a folder of frames, a .gif or .mp4, or an image "
                   "of one time (--t T).")
@click.option("--config", "--scene", "scene_path", type=click.Path(dir_okay=False), default=None,
              help="TOML scene file (camera, lights, material, effects, channels, trace settings); the options "
                   "given override it.")
@click.option("--print-config", is_flag=True,
              help="Print the resolved scene (the file's, the options on top, the camera that frames MODEL) as "
                   "a scene file and exit.")
@verbosity_options
def command(model, out, scene_path, print_config, config):
    """Render MODEL (an SDF or nested sequence file) straight from its networks into OUT."""
    from dataclasses import replace

    from neural_bake.io.atomic import atomic_write_text
    from neural_bake.io.jsonio import dumps, finite
    from neural_bake.render import (Camera, Scene, SpaceTimeAsset, default_camera, load_asset, load_scene, render,
                                    render_sequence, write_render)
    from neural_bake.render.scene import EFFECTS, SceneError, parse_list

    ctx = click.get_current_context()
    o = config
    device, texture_path, size, camera_pos, look_at, fov = o.device, o.texture, o.size, o.camera, o.look_at, o.fov
    channel_format, iterations, frames, time_range, times, fps = (o.channel_format, o.iterations, o.frames,
                                                                  o.time_range, o.t, o.fps)
    scene = load_scene(scene_path) if scene_path else Scene()
    obj = scene.objects[0] if scene.objects else None
    tex = texture_path or (obj.texture if obj else None)
    wh = _size(size)
    asset = load_asset(model, texture=tex, deltas=obj.deltas if obj else None, device=device, precision=o.precision,
                       force=o.force, force_option="--force")
    if not isinstance(asset, SpaceTimeAsset):
        given = [opt for name, opt in (("t", "--t"), ("time_range", "--time-range"), ("frames", "--frames"))
                 if ConfigCommand.given(ctx, name)]
        if given:
            raise SceneError(f"{given[0]}: MODEL {model} is a static SDF and has no time (it takes x, y, z); "
                             f"times are for a space-time model")
    if len(scene.objects) > 1:
        raise SceneError(f"{scene_path}: the render verb draws MODEL as the scene's one object; the scene has "
                         f"{len(scene.objects)} (render several objects from Python with render([...], scene))")
    changes = {}
    if o.effects:
        changes["effects"] = parse_list(o.effects, "--effects", EFFECTS)
    elif texture_path and "texture" not in scene.effects:
        changes["effects"] = tuple(scene.effects) + ("texture",)
    if o.channels:
        changes["channels"] = o.channels
    trace_changes = {}
    if o.mode:
        trace_changes["mode"] = o.mode
    if iterations is not None:
        try:
            trace_changes["iterations"] = tuple(int(i) for i in iterations.split(","))
        except ValueError:
            raise SceneError(f"--iterations: expected whole numbers per level, e.g. 30,30; got {iterations!r}") from None
    if trace_changes:
        changes["trace"] = replace(scene.trace, **trace_changes)
    if ConfigCommand.given(ctx, "guaranteed"):
        changes["guaranteed"] = o.guaranteed
    if ConfigCommand.given(ctx, "skip"):
        changes["skip"] = o.skip
    scene = scene.with_(**changes) if changes else scene

    first = asset.at(asset.time_range[0]) if isinstance(asset, SpaceTimeAsset) else asset
    pos, target = _vec3(camera_pos, "--camera"), _vec3(look_at, "--look-at")
    if scene.camera is not None or pos is not None or target is not None:
        from neural_bake.render.renderer import object_bounds

        base = scene.camera or default_camera([first], [obj.transform] if obj else None)
        if scene.camera is None:
            lo, hi = object_bounds(first, obj.transform if obj else None)
            base = Camera(base.position, tuple((lo + hi) / 2), base.up, base.fov_deg, base.width, base.height)
        w, h = wh or (base.width, base.height)
        scene = scene.with_(camera=Camera(pos or base.position, target or base.look_at, base.up,
                                          base.fov_deg if fov is None else fov, w, h))
    render_kw = {"size": wh, "fov_deg": fov, "device": device}
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    if print_config:
        from neural_bake.io.tomlio import toml_text
        from neural_bake.render.renderer import scene_camera
        from neural_bake.render.scene import scene_table

        camera = scene_camera([first], scene, size=wh, fov_deg=fov, device=device,
                              cache_dir=None if isinstance(asset, SpaceTimeAsset) else Path(cache) / "neural_bake",
                              grids=[None] if isinstance(asset, SpaceTimeAsset) else None)
        click.echo(toml_text(scene_table(scene.with_(camera=camera))), nl=False)
        return
    if out is None:
        raise click.UsageError("missing -o/--output (needed unless --print-config)")

    out_path = Path(out)
    names_folder = out.endswith(("/", "\\")) or out_path.is_dir()
    as_folder = names_folder or not out_path.suffix
    as_image = not as_folder and out_path.suffix.lower() not in (".gif", ".mp4")
    if isinstance(asset, SpaceTimeAsset):
        from neural_bake.fields.spacetime import time_to_tau

        tr = _time_range(time_range)
        ts = None
        if times is not None:
            from neural_bake.fit.spacetime import parse_times

            ts = parse_times(times, name="--t")
            time_to_tau(ts, asset.time_range, 1.0, name="--t")
        if tr is not None:
            time_to_tau(list(tr), asset.time_range, 1.0, name="--time-range: t")
    if isinstance(asset, SpaceTimeAsset) and as_image:
        from neural_bake.render import render_time
        from neural_bake.render.sequence import frame_times

        one = ts if ts is not None else frame_times(frames, tr or asset.time_range)
        if len(one) != 1:
            raise SceneError(f"-o {out}: an image holds one time; {len(one)} times of a space-time model go to "
                             f"a folder (-o frames/) or an animation (a .gif or .mp4 path)")
        result = render_time(asset, scene, one[0], **render_kw)
        paths = write_render(result, out_path, channel_format=channel_format)
        s = result.stats
        say(f"wrote {', '.join(str(p) for p in paths)} at t = {one[0]:g} ({s['pixels']['hit']} of "
            f"{s['pixels']['total']} pixels hit, {s['seconds']['total']:.2f} s)")
        stats = s
    elif isinstance(asset, SpaceTimeAsset):

        def progress(i, n, seconds):
            if verbosity() >= 0:
                click.echo(f"frame {i}/{n} ({seconds:.2f} s)", err=True)

        frames_dir = out_path if as_folder else out_path.with_name(f"{out_path.stem}_frames")
        res = render_sequence(asset, scene, frames_dir, frames=frames, time_range=tr, times=ts,
                              animation=None if as_folder else out_path, fps=fps, channel_format=channel_format,
                              progress=progress, **render_kw)
        extra = f" with {', '.join(res.channels)}" if res.channels else ""
        say(f"wrote {len(res.frames)} frames{extra} to {frames_dir}/" + ("" if as_folder else f" and {out_path}"))
        stats = res.stats
    else:
        if out_path.suffix.lower() in (".gif", ".mp4"):
            raise SceneError(f"-o {out}: an animation needs a space-time model (networks of x, y, z, t)")
        if names_folder:
            raise SceneError(f"-o {out}: a folder; a still render needs an image path (e.g. shot.png)")
        result = render(asset, scene, cache_dir=Path(cache) / "neural_bake", **render_kw)
        paths = write_render(result, out_path, channel_format=channel_format)
        s = result.stats
        say(f"wrote {', '.join(str(p) for p in paths)} ({s['pixels']['hit']} of {s['pixels']['total']} "
                   f"pixels hit, {s['seconds']['total']:.2f} s)")
        stats = s
    if o.stats:
        atomic_write_text(o.stats, dumps(finite(stats)))
        say(f"wrote {o.stats}")


def _time_range(text):
    from neural_bake.render.scene import SceneError

    if text is None:
        return None
    try:
        t0, t1 = (float(v) for v in text.split(","))
    except ValueError:
        raise SceneError(f"--time-range: expected T0,T1, got {text!r}") from None
    from neural_bake.constants import MAX_TIME_MAGNITUDE
    from neural_bake.limits import check_magnitude

    for t in (t0, t1):  # a non-finite or huge end is refused as such, before any range check
        check_magnitude(t, "time_range", MAX_TIME_MAGNITUDE, error=SceneError)
    if not t0 <= t1:
        raise SceneError(f"--time-range: T0 must not exceed T1, got {text!r}")
    return t0, t1
