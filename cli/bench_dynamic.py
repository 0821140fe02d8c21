"""`neural-bake bench dynamic`: space-time SDFs (morph methods at equal steps, sequence, nesting, render/bake cost)."""

from __future__ import annotations

import click

from .bench import bench_options, report

__all__ = ["command"]


@click.command("dynamic")
@bench_options
@click.option("--steps", type=int, default=None, help="Steps of every space-time fit (default 2000; --quick 300).")
@click.option("--frames", type=int, default=None, help="Rendered frames (default 60; --quick 6).")
@click.option("--size", type=int, default=None, help="Square image size in pixels (default 256; --quick 64).")
@click.option("--real", is_flag=True, help="Also morph Spot into the bunny from the data folder.")
@click.option("--data", type=click.Path(file_okay=False), default=None,
              help="The data folder for --real (default $NEURAL_BAKE_DATA, else shared/data).")
def command(quick: bool, json_path: str | None, steps, frames, size, real, data):
    """Morph methods at equal steps, a sequence against every frame, nesting at each t, render/bake cost."""
    from neural_bake.bench.dynamic import run

    report(run(quick=quick, steps=steps, frames=frames, size=size, real=real, data=data), json_path)
