"""`neural-bake bench view`: our mesh renderer against the analytic render, beside model-viewer in Chromium."""

from __future__ import annotations

import click

from .bench import bench_options, report


@click.command("view")
@bench_options
def command(quick: bool, json_path: str | None) -> None:
    """Turntable renders of an analytic bumpy-sphere bake by our ray caster (baked maps, bare coarse mesh,
    source mesh) and by model-viewer in headless Chromium: time per view, interior PSNR, fine-detail
    correlation and silhouette IoU against the analytic render."""
    from neural_bake.bench.view import COLUMNS, run

    report(run(quick=quick), json_path, COLUMNS)
