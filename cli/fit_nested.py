"""`neural-bake fit nested MODEL -o NESTED`: distil coarser levels from a fine SDF and set their δ (thin verb)."""

from __future__ import annotations

import click

__all__ = ["command"]


@click.command()
@click.argument("model", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Nested-sequence file to write (one safetensors file with JSON metadata).")
@click.option("--levels", default="64x1,256x1", show_default=True,
              help="Coarse levels WIDTHxDEPTH, coarse to fine, comma-separated.")
@click.option("--steps", type=int, default=2000, show_default=True, help="Training steps per level.")
@click.option("--minutes", type=float, default=None, help="Wall-clock budget per level in minutes.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of weights and samples.")
@click.option("--band", type=float, default=0.1, show_default=True,
              help="Δ: half-width (unit frame) of the band around the zero level sets where |h - f| is measured.")
@click.option("--eps", type=float, default=1e-3, show_default=True, help="ε of Prop. 1 added to the sup-norms.")
@click.option("--certify/--no-certify", default=True, help="Certify the sup-norms by range analysis.")
@click.option("--max-boxes", type=int, default=20_000, show_default=True, help="Box budget of the certification.")
@click.option("--progress/--no-progress", default=True, help="Show progress bars on stderr.")
def command(model, output, levels, steps, minutes, seed, band, eps, certify, max_boxes, progress):
    """Distil coarser SDFs from the fine SDF MODEL; write the sequence [h1, …, f] with δ to OUTPUT."""
    from neural_bake.fit.nested import fit_nested, parse_levels
    from neural_bake.fit.sdf import load_sdf

    from .options import lock_outputs, refuse_nonpositive

    refuse_nonpositive(steps=steps, minutes=minutes, band=band, max_boxes=max_boxes)
    lv = parse_levels(levels)
    lock_outputs(output)  # checks its folder; one writer per file
    fine = load_sdf(model)
    seq = fit_nested(fine, lv, steps=steps, minutes=minutes, seed=seed, band=band, eps=eps, certify=certify,
                     certify_max_boxes=max_boxes, progress=progress)
    click.echo(f"{'level':>8} {'steps':>6} {'best':>6} {'sup est':>9} {'sup cert':>9} {'δ est':>9} {'δ cert':>9} "
               f"{'δ used':>9}")
    for info in seq.levels_info:
        def f(v):
            return "-" if v is None else f"{v:.5f}"
        click.echo(f"{str(info['width']) + 'x' + str(info['depth']):>8} {info.get('steps', 0):>6} {str(info.get('best_step', '-')):>6} "
                   f"{f(info.get('sup_estimated')):>9} {f(info.get('sup_certified')):>9} "
                   f"{f(info.get('delta_estimated')):>9} {f(info.get('delta_certified')):>9} "
                   f"{f(info.get('delta')):>9} ({info.get('delta_source')})")
    seq.save(output)
    click.echo(f"wrote {output}")
