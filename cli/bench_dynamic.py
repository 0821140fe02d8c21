"""`neural-bake bench dynamic`: space-time SDFs (morph methods at equal time, sequence, nesting, render/bake cost)."""

from __future__ import annotations

import click

from .bench import bench_options, report

__all__ = ["command"]


@click.command("dynamic")
@bench_options
@click.option("--minutes", type=float, default=None, help="Fit budget per run (default 3; --quick 0.15).")
@click.option("--frames", type=int, default=None, help="Rendered frames (default 60; --quick 6).")
@click.option("--size", type=int, default=None, help="Square image size in pixels (default 256; --quick 64).")
def command(quick: bool, json_path: str | None, minutes, frames, size):
    """Morph methods at equal time, a sequence against every frame, nesting at each t, render/bake cost."""
    from neural_bake.bench.dynamic import run

    report(run(quick=quick, minutes=minutes, frames=frames, size=size), json_path)
