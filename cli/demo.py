"""`neural-bake demo --out DIR`: the main job end to end on a bundled sample (thin verb)."""

from __future__ import annotations

import click

__all__ = ["command"]


@click.command()
@click.option("--out", "out", default="demo-out", show_default=True, type=click.Path(file_okay=False),
              help="Output folder (models, asset.glb, maps, report.json, demo.json).")
@click.option("--sample", default="bumpy_sphere", show_default=True, help="Bundled sample to bake.")
@click.option("--sdf-minutes", type=float, default=2.5, show_default=True, help="SDF fit budget, minutes.")
@click.option("--texture-minutes", type=float, default=1.0, show_default=True, help="Texture fit budget, minutes.")
@click.option("--size", type=int, default=1024, show_default=True, help="Map side in texels.")
@click.option("--progress/--no-progress", default=True, help="Progress bars on stderr.")
def command(out, sample, sdf_minutes, texture_minutes, size, progress):
    """Fit, coarsen, bake and report on a bundled sample (about 4 minutes on 2 CPU cores)."""
    from neural_bake.pipelines.demo import DemoConfig, run_demo

    run_demo(out, DemoConfig(sample=sample, sdf_minutes=sdf_minutes, texture_minutes=texture_minutes, size=size,
                             progress=progress), log=click.echo)
