"""`neural-bake bench fit [--quick]`: SDF accuracy vs training time per preset; training-step cost."""

from __future__ import annotations

import click

from .bench import bench_options, report

__all__ = ["command"]


@click.command()
@bench_options
@click.option("--mesh", "meshes", multiple=True,
              help="Meshes: bumpy_sphere, torus, jack, sphere, spot, bunny (repeatable; default: all but "
                   "sphere; quick: bumpy_sphere).")
@click.option("--preset", "presets", multiple=True, type=click.Choice(["quick", "64x1", "128x2", "256x2", "256x3", "high"]),
              help="Presets to run (repeatable; default all, quick 64x1 and 256x3).")
@click.option("--minutes", type=float, default=None, help="Override every preset's time budget.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of every fit.")
@click.option("--save-models", "save_dir", type=click.Path(file_okay=False), default=None,
              help="Also save every fitted model as DIR/MESH-PRESET.nbm (e.g. for bench bake --sdf-model).")
@click.option("--compare-polish/--no-compare-polish", default=None,
              help="Also fit presets that polish with L-BFGS without their polish, side by side (default: in "
                   "full runs, not in --quick).")
def command(quick, json_path, meshes, presets, minutes, seed, save_dir, compare_polish):
    """SDF fitting: Chamfer/Hausdorff/normal error against training time; step vs autograd and roofline.

    The full run fits every preset at its budget (2/2/5/8/10/10 min; 64x1 also without its L-BFGS polish) on
    bumpy_sphere, torus, jack, spot and bunny: about three and a half hours. --quick: bumpy_sphere, 64x1 for 30 s and 256x3 for 20 s (< 2 minutes).
    """
    from neural_bake.bench.fit import run

    result = run(quick=quick, meshes=list(meshes) or None, presets=list(presets) or None, minutes=minutes,
                 seed=seed, save_dir=save_dir, compare_polish=compare_polish)
    report(result, json_path)
