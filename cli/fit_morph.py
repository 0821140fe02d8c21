"""`neural-bake fit morph A B -o MODEL`: a space-time SDF whose surface moves from shape A (t = 0) to B (t = 1)."""

from __future__ import annotations

import json
import os

import click

from .config_options import ConfigCommand, ConfigSpec
from .options import say, verbosity, verbosity_options

__all__ = ["command", "load_shape", "spacetime_spec", "spacetime_options", "spacetime_config", "report_fit"]


def load_shape(path: str):
    """A mesh file (OBJ, PLY, glTF) as a Mesh, anything else as a fitted SDF model file."""
    from pathlib import Path

    from neural_bake.io.mesh_io import MESH_FORMATS, load_mesh

    if Path(path).suffix.lower() in MESH_FORMATS:
        return load_mesh(path)
    from neural_bake.fit.sdf import load_sdf

    return load_sdf(path)


def _config_class():
    from neural_bake.fit.spacetime_config import SpaceTimeFitConfig

    return SpaceTimeFitConfig


def spacetime_spec(fn: str, required: tuple[str, ...]) -> ConfigSpec:
    """The options of fit morph (``fn`` "fit_morph") and fit sequence ("fit_sequence"): the fields of
    SpaceTimeFitConfig, checked as ``fn`` checks them (its methods)."""

    def resolve(preset, values):
        from neural_bake.fit.spacetime_config import config_from

        return config_from(fn=fn, **values)

    return ConfigSpec(load=_config_class, resolve=resolve, required=required)


def spacetime_options(fn):
    """The options fit morph and fit sequence add to their config's."""
    for opt in reversed([
        click.option("--pool", type=int, default=None,
                     help="Samples per shape of the surface, near and in-between pools at once (uniform: a quarter); "
                          "overrides --pool-surface, --pool-near, --pool-uniform and --pool-between."),
        click.option("--metrics/--no-metrics", default=True,
                     help="Measure Chamfer/Hausdorff against the given meshes at their times."),
    ]):
        fn = opt(fn)
    return fn


def spacetime_config(config, pool):
    """The resolved config with ``--pool`` applied and no progress bar under ``--quiet``."""
    from dataclasses import replace

    config = replace(config, **pools(pool))
    return replace(config, progress=False) if verbosity() < 0 else config


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


@click.command(cls=ConfigCommand, config=spacetime_spec("fit_morph", ("a", "b", "output")), epilog="""\b
Example:
  neural-bake fit morph samples/sphere.obj samples/torus.obj -o morph.sdf --minutes 2
  neural-bake render morph.sdf -o morph.gif --frames 24
  neural-bake fit morph --method lse --print-config > morph.toml""")
@click.argument("a", type=click.Path(dir_okay=False), required=False)
@click.argument("b", type=click.Path(dir_okay=False), required=False)
@click.option("-o", "--output", type=click.Path(dir_okay=False),
              help="Model file to write (safetensors + JSON metadata, kind 'spacetime_sdf').")
@click.option("--align", type=click.Choice(["source", "unit"]), default="source", show_default=True,
              help="source: the shapes keep their places; unit: each is centred and scaled first (unrelated models).")
@spacetime_options
@verbosity_options
def command(a, b, output, align, pool, metrics, config):
    """Fit a space-time SDF morphing shape A (t = 0) into shape B (t = 1); A and B are meshes or SDF model files.

    --method lse: the level set equation df/dt + v|grad f| = 0 with v = d_A - d_B; interpolate: a supervised
    blend of the two distances plus the eikonal term."""
    from neural_bake.fit.spacetime import fit_morph

    check_output(output)
    sa, sb = load_shape(a), load_shape(b)
    fit = fit_morph(sa, sb, spacetime_config(config, pool), align=align)
    if align == "unit":  # the metrics compare with the shapes as the fit saw them
        from dataclasses import replace

        from neural_bake.types import Frame, Mesh

        sa, sb = (replace(s, frame=Frame()) if isinstance(s, Mesh) else s for s in (sa, sb))
    report_fit(fit, [(0.0, sa), (1.0, sb)], metrics, output)
