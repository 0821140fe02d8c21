"""`neural-bake bench batch`: assets per hour of `neural-bake batch` (1, 2, 4 workers) against the verbs run one
after another."""

from __future__ import annotations

import click

from .bench import bench_options, report


@click.command("batch", epilog="\b\nExample:\n  neural-bake bench batch --quick --json batch.json")
@bench_options
def command(quick: bool, json_path: str | None) -> None:
    """Throughput of a batch of the four bundled samples with 1, 2 and 4 workers, and over a finished output
    (every stage cached), against fit sdf, fit nested, fit texture and bake run one after another."""
    from neural_bake.bench.batch import COLUMNS, run

    report(run(quick=quick), json_path, COLUMNS)
