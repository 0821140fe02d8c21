"""`neural-bake bench sampling [--quick] [--json PATH]`: sampling throughput and the inside test vs baselines."""

from __future__ import annotations

import click

from .bench import bench_options, report


@click.command("sampling")
@bench_options
def command(quick: bool, json_path: str | None):
    """Samples per second (surface, near, uniform with ground-truth SDF) and sign accuracy vs trimesh/open3d."""
    from neural_bake.bench.sampling import run

    report(run(quick=quick), json_path)
