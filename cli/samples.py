"""`neural-bake samples -o DIR`: write the generated sample meshes (OBJ + MTL + PNG) with analytic truth, and
the animated samples as folders of numbered OBJ frames with ``frames.json``."""

from __future__ import annotations

import click

from .options import output_option, say, verbosity_options


@click.command("samples", epilog="""\b
Examples:
  neural-bake samples -o samples/
  neural-bake samples -o samples/ --names sphere,torus --resolution 4000 --texture-size 256""")
@output_option("Folder to write <name>.obj/.mtl/.png into (created if missing).", folder=True, old_spelling=True)
@click.option("--names", multiple=True, metavar="NAME[,NAME...]",
              help="Samples to write (repeat or comma-separate); default all: sphere, bumpy_sphere, torus, jack, and the "
                   "animations travelling_bumps, twisting_torus, splitting_sphere (numbered OBJ frames).")
@click.option("--resolution", type=int, default=None, metavar="FACES",
              help="Approximate face count of every mesh (default: each sample's own, ~8k-16k).")
@click.option("--texture-size", type=int, default=None, metavar="TEXELS",
              help="Texture width in texels (default 512; lat-long textures are half as high).")
@verbosity_options
def command(output: str, names: tuple[str, ...], resolution: int | None, texture_size: int | None):
    """Write small UV-textured sample meshes whose SDF, normals and colours are known analytically.

    OUT is committed as a unit: it holds this run's files only, replacing an earlier run's set."""
    from pathlib import Path

    from neural_bake.io.outdir import OutputFolder
    from neural_bake.samples.generate import FRAMES_FILE, check_generate_args, generate

    chosen = [n.strip() for item in names for n in item.split(",") if n.strip()] or None
    check_generate_args(chosen, resolution, texture_size)  # every option checked before any write
    out = Path(output)
    out.absolute().parent.mkdir(parents=True, exist_ok=True)
    with OutputFolder(out) as stage:
        written = generate(stage, chosen, resolution=resolution, texture_size=texture_size)
    for name, path in written.items():
        shown = out / path.name
        say(f"{name}: {shown}" + (f"/ (frames and {FRAMES_FILE})" if path.is_dir() else ""))
