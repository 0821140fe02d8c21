"""`neural-bake bake-frames MODEL --t 0:1:10 -o DIR`: per-frame bake of a space-time SDF (thin verb).

At each t the coarse level (a space-time nested sequence's first level, or the single network) is marched and
the fine level's neural normals at the same t are written per vertex: numbered PLY or GLB frames, or one
USD stage with time samples (--format usd, at --fps), and frames.json. ``--texture`` adds per-vertex colours from a texture model (``fit texture`` output) evaluated on
the moving surface at each t (the field layer holds static texture fields; a space-time colour field g(x, t)
goes through the library, :func:`neural_bake.bake.frames.bake_frames`). (`neural-bake bake` bakes a static model, with or without a source mesh, onto one UV-mapped mesh.)
"""

from __future__ import annotations

from pathlib import Path

import click

from .options import say, verbosity_options

__all__ = ["command"]


@click.command("bake-frames", epilog="""\b
Example:
  neural-bake fit morph samples/sphere.obj samples/torus.obj -o morph.sdf
  neural-bake bake-frames morph.sdf --t 0:1:10 -o frames/ --format glb
  neural-bake bake-frames morph.sdf --t 0:1:48 -o anim/ --format usd --fps 24""")
@click.argument("model", metavar="MODEL", type=click.Path(dir_okay=False))
@click.option("--t", "times", required=True, help="Frame times: START:STOP:COUNT (e.g. 0:1:10) or a list 0,0.5,1.")
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False),
              help="Output folder (committed as a unit).")
@click.option("--resolution", type=int, default=96, show_default=True, help="Marching-cubes cells per axis.")
@click.option("--format", "fmt", type=click.Choice(["ply", "glb", "usd"]), default="ply", show_default=True,
              help="Frame file format (positions and neural normals): one file per frame (ply, glb) or one USD "
                   "stage with time samples (usd; needs the extra usd).")
@click.option("--fps", type=float, default=24.0, show_default=True,
              help="Frames per second of the USD stage (frame i plays at i / fps seconds).")
@click.option("--texture", type=click.Path(dir_okay=False), default=None,
              help="Texture model: per-vertex colours evaluated on the surface at each t.")
@click.option("--force", is_flag=True,
              help="Use a texture fitted in another frame than MODEL (with a warning).")
@verbosity_options
def command(model, times, out, resolution, fmt, fps, texture, force):
    """Bake a space-time SDF (fit morph / fit sequence output, or its nested sequence) frame by frame."""
    from neural_bake.bake.frames import bake_frames
    from neural_bake.errors import ModelFileError
    from neural_bake.fields import SpaceTimeField, load_field, time_mapping
    from neural_bake.fit.spacetime import parse_times
    from neural_bake.nets.timeslice import fix_last_input

    ts = parse_times(times, name="--t")
    field = load_field(model)
    mapping = time_mapping(field)
    if mapping is None:
        raise ModelFileError(f"MODEL {model}: not a space-time SDF (fit morph / fit sequence output)")
    _, time_input = mapping
    nets = [field.model] if isinstance(field, SpaceTimeField) else list(field.levels)
    tex = None if texture is None else _texture(texture)
    if tex is not None:
        from neural_bake.fields import check_texture_matches_sdf

        check_texture_matches_sdf(tex, field, force=force, option="--force", sdf_name=Path(model).name)
    res = bake_frames(lambda t: fix_last_input(nets[0], time_input(t)), lambda t: fix_last_input(nets[-1], time_input(t)),
                      field.frame, ts, out, resolution=resolution, fmt=fmt, texture=tex, fps=fps)
    total = sum(s["march_s"] + s["normals_s"] + s["colours_s"] + s["write_s"] for s in res.stats)
    say(f"baked {len(res.times)} frames into {out} ({total / len(res.times):.2f} s per frame)")
    sizes, net = res.sizes or {}, Path(model).stat().st_size
    if fmt == "usd":
        say(f"{res.files[0].name}: {_mb(sizes['file_bytes'])} (the {len(res.times)} per-frame PLY files would be "
            f"{_mb(sizes['ply_bytes'])}, counted, not written); the network {Path(model).name}: {_mb(net)}")
    else:
        say(f"{len(res.files)} {fmt.upper()} files: {_mb(sizes['file_bytes'])}; the network {Path(model).name}: "
            f"{_mb(net)}")


def _mb(n: int) -> str:
    return f"{n / 1e6:.2f} MB"



def _texture(path):
    """The static texture field of ``--texture`` (evaluated on the moving surface at each t)."""
    from neural_bake.errors import ModelFileError
    from neural_bake.fields import TextureField, load_field

    tex = load_field(path)
    if not isinstance(tex, TextureField):
        raise ModelFileError(f"--texture {path}: not a texture model (a {type(tex).__name__})")
    return tex
