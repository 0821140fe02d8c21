"""`neural-bake bench range [--quick] [--json PATH]`: cost and tightness of each range-analysis method."""

from __future__ import annotations

import click

from .bench import bench_options, report

__all__ = ["command"]


@click.command()
@bench_options
@click.option("--model", "model_path", type=click.Path(dir_okay=False), default=None,
              help="Measure this model file instead of random (64,1) and (256,3) SIRENs.")
@click.option("--omega", type=float, default=30.0, show_default=True, help="ω0 of the random SIRENs.")
@click.option("--keep", type=int, default=64, show_default=True, help="Symbols kept by affine-truncate.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the networks and regions.")
@click.option("--threads", type=int, default=1, show_default=True,
              help="Torch threads while timing (1 gives steadier figures on a shared CPU; 0 keeps torch's default).")
def command(quick, json_path, model_path, omega, keep, seed, threads):
    """Interval / affine range bounds: time per box vs a forward pass, bound width vs the true range."""
    from neural_bake.bench.range import run

    result = run(quick=quick, seed=seed, omega=omega, model_path=model_path, truncate_keep=keep, threads=threads or None)
    report(result, json_path)
