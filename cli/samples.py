"""`neural-bake samples --out DIR`: write the generated sample meshes (OBJ + MTL + PNG) with analytic truth, and
the animated samples as folders of numbered OBJ frames with ``frames.json``."""

from __future__ import annotations

import click


@click.command("samples")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Folder to write <name>.obj/.mtl/.png into (created if missing).")
@click.option("--names", multiple=True, metavar="NAME[,NAME...]",
              help="Samples to write (repeat or comma-separate); default all: sphere, bumpy_sphere, torus, jack, and the "
                   "animations travelling_bumps, twisting_torus, splitting_sphere (numbered OBJ frames).")
@click.option("--resolution", type=int, default=None, metavar="FACES",
              help="Approximate face count of every mesh (default: each sample's own, ~8k-16k).")
@click.option("--texture-size", type=int, default=None, metavar="TEXELS",
              help="Texture width in texels (default 512; lat-long textures are half as high).")
def command(out_dir: str, names: tuple[str, ...], resolution: int | None, texture_size: int | None):
    """Write small UV-textured sample meshes whose SDF, normals and colours are known analytically.

    OUT is committed as a unit: it holds this run's files only, replacing an earlier run's set."""
    from pathlib import Path

    from neural_bake.io.outdir import OutputFolder
    from neural_bake.samples.generate import FRAMES_FILE, check_generate_args, generate

    chosen = [n.strip() for item in names for n in item.split(",") if n.strip()] or None
    check_generate_args(chosen, resolution, texture_size)  # every option checked before any write
    out = Path(out_dir)
    out.absolute().parent.mkdir(parents=True, exist_ok=True)
    with OutputFolder(out) as stage:
        written = generate(stage, chosen, resolution=resolution, texture_size=texture_size)
    for name, path in written.items():
        shown = out / path.name
        click.echo(f"{name}: {shown}" + (f"/ (frames and {FRAMES_FILE})" if path.is_dir() else ""))
