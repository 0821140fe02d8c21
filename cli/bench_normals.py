"""`neural-bake bench normals`: GEMM normals vs autograd, torch.func and finite differences."""

from __future__ import annotations

import click

from .bench import bench_options, report


@click.command("normals")
@bench_options
def command(quick: bool, json_path: str | None) -> None:
    """GEMM normals (both modes) against autograd, torch.func and central differences: time, speed-up,
    cost over the forward pass, fraction of this machine's roofline and angular error."""
    from neural_bake.bench.normals import run

    report(run(quick=quick), json_path)
