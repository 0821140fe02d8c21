"""`neural-bake bench budget`: each preset's cost per step on this machine against the budget table (thin verb)."""

from __future__ import annotations

import click

from .bench import bench_options, report


@click.command("budget")
@bench_options
@click.option("--preset", "presets", multiple=True,
              help="A preset to measure, repeatable: quick, default, high, 64x1, …, quick/coarse and quick/fine (the "
                   "levels of quick's construction), texture:quick, texture:default, texture:high, or tile (a tile "
                   "level's step per tile, --construction tiles) (default: all of them; --quick: quick, its two "
                   "levels, 64x1, texture:quick).")
@click.option("--seconds", type=click.FloatRange(min=1.0), default=None,
              help="Each fit's budget in seconds (default 30; --quick 8).")
def command(quick: bool, json_path: str | None, presets: tuple[str, ...], seconds: float | None) -> None:
    """Each preset's seconds per Adam step on this machine, in reference steps (a small Siren's step, timed in
    the same run), beside the cost the time budgets assume (fit.budget.STEP_COST) and the steps each predicts
    for the preset's whole budget. About 30 s per preset, twice for the compiled ones (9 minutes for all); --quick:
    quick, its two levels (one fit), 64x1 and texture:quick, 8 s each."""
    from neural_bake.bench.budget import COLUMNS, run

    report(run(quick=quick, presets=list(presets) or None, seconds=seconds, log=click.echo), json_path, COLUMNS)
