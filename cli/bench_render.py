"""`neural-bake bench render [--quick] [--json PATH]`: the preview renderer's image MSE against time (Tables 6, 8)."""

from __future__ import annotations

from pathlib import Path

import click

from .bench import bench_options, report

__all__ = ["command"]


@click.command()
@bench_options
@click.option("--size", "sizes", type=int, multiple=True, help="Image side (repeatable; default 256 and 512).")
@click.option("--plot", type=click.Path(dir_okay=False), default=None,
              help="PNG of MSE against time [default: beside --json, same name with .png; none without --json].")
@click.option("--cache", "cache_dir", type=click.Path(file_okay=False), default=None,
              help="Folder of the fitted networks (default: the user cache); fitted once, then reused.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the fits.")
@click.option("--threads", type=int, default=1, show_default=True,
              help="Torch threads while timing (0: torch's default).")
def command(quick, json_path, sizes, plot, cache_dir, seed, threads):
    """Render configurations (coarse, fine, normal mapping, multiscale, three levels, a straightforward tracer)
    against a converged fine render: seconds, speed-up and MSE; skipping, compaction and guaranteed casting."""
    from neural_bake.bench.render import run

    if plot is None and json_path:
        plot = str(Path(json_path).with_suffix(".png"))
    report(run(quick=quick, sizes=list(sizes) or None, plot=plot, cache_dir=cache_dir, seed=seed,
               threads=threads or None), json_path)
