"""`neural-bake fit morph A B -o MODEL`: a space-time SDF whose surface moves from shape A (t = 0) to B (t = 1)."""

from __future__ import annotations

import json
import os

import click

from .options import say, verbosity, verbosity_options

__all__ = ["command", "load_shape", "network_options", "report_fit"]


def load_shape(path: str):
    """A mesh file (OBJ, PLY, glTF) as a Mesh, anything else as a fitted SDF model file."""
    from pathlib import Path

    from neural_bake.io.mesh_io import MESH_FORMATS, load_mesh

    if Path(path).suffix.lower() in MESH_FORMATS:
        return load_mesh(path)
    from neural_bake.fit.sdf import load_sdf

    return load_sdf(path)


def network_options(fn):
    """The options fit morph and fit sequence share."""
    for opt in reversed([
        click.option("--width", type=int, default=128, show_default=True, help="Hidden width W of the 4-D Siren."),
        click.option("--depth", type=int, default=2, show_default=True, help="Hidden W x W matrices D."),
        click.option("--steps", type=int, default=3000, show_default=True, help="Maximum optimiser steps."),
        click.option("--minutes", type=float, default=None, help="Wall-clock budget in minutes (default: none)."),
        click.option("--seed", type=int, default=0, show_default=True, help="Seed of weights and samples."),
        click.option("--lr", type=float, default=None, help="Initial Adam learning rate (default 2e-4)."),
        click.option("--time-extent", type=float, default=None,
                     help="The time range maps onto tau in [-E, E] (default 1; smaller: smoother in t)."),
        click.option("--pool", type=int, default=None,
                     help="Samples per shape of the surface and near pools (default 50000; uniform: a quarter)."),
        click.option("--metrics/--no-metrics", default=True,
                     help="Measure Chamfer/Hausdorff against the given meshes at their times."),
        click.option("--progress/--no-progress", default=True, help="Show a progress bar on stderr."),
    ]):
        fn = opt(fn)
    return fn


def report_fit(fit, shapes_at_times, metrics: bool, output: str) -> None:
    """Print the fit's summary (and metrics against the meshes given at their times), write OUTPUT."""
    from neural_bake.types import Mesh

    last = fit.history[-1] if fit.history else {}
    say(f"fit {fit.kind} {fit.config.width}x{fit.config.depth} ({fit.method}): {fit.steps} steps in "
               f"{fit.seconds:.1f} s ({fit.stopped_reason}); final loss {last.get('loss', float('nan')):.4g}; "
               f"t in [{fit.time_range[0]:g}, {fit.time_range[1]:g}]")
    if metrics:
        from neural_bake.fit.spacetime import spacetime_metrics

        from neural_bake.errors import FitError

        for t, shape in shapes_at_times:
            if isinstance(shape, Mesh):
                try:
                    r = spacetime_metrics(fit, shape, t, n=20_000, resolution=96)
                except FitError as exc:  # e.g. no zero level set yet: the model is still written
                    say(f"metrics at t = {t:g}: not measured ({exc})")
                    continue
                say(f"metrics at t = {t:g} (unit frame): " + json.dumps(
                    {k: round(r[k], 6) for k in ("chamfer_l1", "hausdorff", "normal_median_deg")}))
    fit.save(output)
    say(f"wrote {output}")


def pools(pool):
    """fit_morph / fit_sequence pool settings of ``--pool`` (None: the defaults)."""
    if pool is None:
        return {}
    return {"pool_surface": pool, "pool_near": pool, "pool_uniform": max(1, pool // 4), "pool_between": pool}


def check_output(output: str) -> None:
    """Refuse an output in a missing folder; lock it for the run (one writer per file, see lock_outputs)."""
    from neural_bake.errors import FitError

    from .options import lock_outputs

    out_dir = os.path.dirname(os.path.abspath(output))
    if not os.path.isdir(out_dir):
        raise FitError(f"{output}: folder {out_dir} does not exist")
    lock_outputs(output)


@click.command(epilog="""\b
Example:
  neural-bake fit morph samples/sphere.obj samples/torus.obj -o morph.sdf --minutes 2
  neural-bake render morph.sdf -o morph.gif --frames 24""")
@click.argument("a", type=click.Path(dir_okay=False))
@click.argument("b", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Model file to write (safetensors + JSON metadata, kind 'spacetime_sdf').")
@click.option("--method", type=click.Choice(["lse", "interpolate"]), default="interpolate", show_default=True,
              help="lse: level set equation df/dt + v|grad f| = 0 with v = d_A - d_B; interpolate: supervised "
                   "blend of the two distances plus the eikonal term.")
@click.option("--align", type=click.Choice(["source", "unit"]), default="source", show_default=True,
              help="source: the shapes keep their places; unit: each is centred and scaled first (unrelated models).")
@network_options
@verbosity_options
def command(a, b, output, method, align, width, depth, steps, minutes, seed, lr, time_extent, pool, metrics,
            progress):
    """Fit a space-time SDF morphing shape A (t = 0) into shape B (t = 1); A and B are meshes or SDF model files."""
    from neural_bake.fit.spacetime import fit_morph

    check_output(output)
    sa, sb = load_shape(a), load_shape(b)
    fit = fit_morph(sa, sb, method=method, align=align, width=width, depth=depth, steps=steps, minutes=minutes, seed=seed,
                    lr=lr, time_extent=time_extent, progress=progress and verbosity() >= 0, **pools(pool))
    if align == "unit":  # the metrics compare with the shapes as the fit saw them
        from dataclasses import replace

        from neural_bake.types import Frame, Mesh

        sa, sb = (replace(s, frame=Frame()) if isinstance(s, Mesh) else s for s in (sa, sb))
    report_fit(fit, [(0.0, sa), (1.0, sb)], metrics, output)
