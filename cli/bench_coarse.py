"""`neural-bake bench coarse`: decimation vs marching cubes (dense, range-pruned, cost-aware), error against time."""

from __future__ import annotations

import click

from .bench import bench_options, report


@click.command("coarse")
@bench_options
@click.option("--sdf-model", type=click.Path(exists=True, dir_okay=False), default=None,
              help="A trained SDF model of the bumpy sphere sample to march (default: train a small one first).")
def command(quick: bool, json_path: str | None, sdf_model: str | None) -> None:
    """Coarse meshes of the bumpy sphere (and Spot, full run) by quadric decimation at several face counts and by
    marching cubes of an SDF network at several resolutions (dense, range-pruned, cost-aware); the data folder's
    scans by decimation, its fast first pass beside pymeshlab alone: time, network evaluations, faces and
    Chamfer-L1 / Hausdorff against the fine mesh."""
    from neural_bake.bench.coarse import COLUMNS, run

    report(run(quick=quick, sdf_model=sdf_model), json_path, COLUMNS)
