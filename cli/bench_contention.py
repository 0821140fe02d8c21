"""`neural-bake bench contention`: the fit, bake and render commands beside one busy program (thin verb)."""

from __future__ import annotations

import click

from .bench import bench_options, report


@click.command("contention")
@bench_options
@click.option("--workload", "workloads", multiple=True, type=click.Choice(["fit", "bake", "render"]),
              help="A command to measure, repeatable (default: all three).")
@click.option("--fit-seconds", type=click.FloatRange(min=1.0), default=None,
              help="The fit's time budget in seconds (default 60; --quick 12).")
def command(quick: bool, json_path: str | None, workloads: tuple[str, ...], fit_seconds: float | None) -> None:
    """The quick SDF fit, a 2048² bake and a 256² render, each as its own neural-bake process, quiet and beside
    a CPU-bound process started with setsid, with torch's default threads and with the count chosen by
    measurement: steps kept and slowdowns as ratios of the same run. About 8 minutes; --quick about 2 (a
    12-s fit, a 512² bake, a 128² render)."""
    from neural_bake.bench.contention import COLUMNS, run

    report(run(quick=quick, workloads=workloads or None, fit_seconds=fit_seconds, log=click.echo), json_path,
           COLUMNS)
