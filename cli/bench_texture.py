"""`neural-bake bench texture [--quick]`: texture MLP accuracy (PSNR, band constancy, render MSE) vs time."""

from __future__ import annotations

import click

from .bench import bench_options, report

__all__ = ["command"]


@click.command()
@bench_options
@click.option("--case", "cases", multiple=True,
              help="Cases to run: sphere, torus, checker<k> (e.g. checker16), spot (repeatable; default: all).")
@click.option("--preset", "presets", multiple=True,
              help="Texture presets to run: quick, default, high (repeatable; default: quick and default on every "
                   "case, high on sphere and spot).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of every fit and metric.")
@click.option("--delta", type=float, default=None, help="Band half-width δ (unit frame); default 0.03.")
def command(quick, json_path, cases, presets, seed, delta):
    """Neural texture: surface PSNR, colour change across the band and render MSE vs time, the paper's λ vs λ=0."""
    from neural_bake.bench.texture import run

    result = run(quick=quick, cases=list(cases) or None, presets=list(presets) or None, seed=seed, delta=delta)
    report(result, json_path)
