"""`neural-bake bench bake`: texel throughput, and error against time beside the mesh-to-mesh baseline."""

from __future__ import annotations

import click

from .bench import bench_options, report


@click.command("bake")
@bench_options
@click.option("--sdf-model", type=click.Path(dir_okay=False), default=None,
              help="A trained SDF model of the bumpy sphere sample: adds error rows with its ∇f.")
def command(quick: bool, json_path: str | None, sdf_model: str | None) -> None:
    """Texels per second of tangent-space normal maps from a (256, 3) SIREN (GEMM vs autograd normals), and
    the error of baked normals against time as map size and coarse face count vary on the bumpy sphere,
    beside the classical mesh-to-mesh bake."""
    from neural_bake.bench.bake import run

    report(run(quick=quick, sdf_model=sdf_model), json_path)
