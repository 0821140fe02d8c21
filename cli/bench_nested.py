"""`neural-bake bench nested [--quick] [--json PATH]`: nested levels' sup-norm and δ against time, vs direct fits."""

from __future__ import annotations

import click

from .bench import bench_options, report

__all__ = ["command"]


@click.command()
@bench_options
@click.option("--mesh", "meshes", multiple=True,
              help="Meshes: bumpy_sphere, torus, jack, spot, bunny (repeatable; default: bumpy_sphere and spot).")
@click.option("--model", "model_path", type=click.Path(dir_okay=False), default=None,
              help="A fine SDF file to use instead of fitting one (with the first --mesh as its source mesh).")
@click.option("--levels", default=None, help="Coarse levels WIDTHxDEPTH, coarse to fine (default 64x1,256x1).")
@click.option("--steps", type=int, default=None, help="Adam steps per level (default 2000; quick 300).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of every fit.")
def command(quick, json_path, meshes, model_path, levels, steps, seed):
    """Distilled levels' sup-norm |h - g|, δ and their cost, against levels fitted to the mesh directly."""
    from neural_bake.bench.nested import run
    from neural_bake.fit.nested import parse_levels

    result = run(quick=quick, meshes=list(meshes) or None, model_path=model_path,
                 levels=parse_levels(levels) if levels else None, steps=steps, seed=seed)
    report(result, json_path)
