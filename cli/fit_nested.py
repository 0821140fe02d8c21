"""`neural-bake fit nested MODEL -o NESTED`: distil coarser levels from a fine SDF and set their δ (thin verb)."""

from __future__ import annotations

import click

from .config_options import ConfigCommand, ConfigSpec
from .options import lock_outputs, output_option, refuse_nonpositive, say, verbosity, verbosity_options

__all__ = ["command"]


def _config_class():
    from neural_bake.fit.nested import NestedFitConfig

    return NestedFitConfig


def _resolve(preset, values):
    from neural_bake.fit.nested import nested_config

    return nested_config(preset, **values)


SPEC = ConfigSpec(load=_config_class, resolve=_resolve, presets=("quick", "default", "high"),
                  costs={"quick": "32x1, 300 steps, not certified: about 15 s",
                         "default": "64x1, 2000 steps: about 25 s",
                         "high": "64x1 and 256x1, 4000 steps each: about 2 min"},
                  preset_help="Levels and steps (none: the defaults below)", required=("model", "output"))


@click.command(cls=ConfigCommand, config=SPEC, epilog="""\b
Examples:
  neural-bake fit nested bumpy.sdf -o bumpy.nested --preset quick
  neural-bake fit nested mesh.sdf -o mesh.nested --levels 32x1,128x1 --minutes 1 --device cuda
  neural-bake fit nested --preset default --print-config > nested.toml""")
@click.argument("model", type=click.Path(dir_okay=False), required=False)
@output_option("Nested-sequence file to write (one safetensors file with JSON metadata).", required=False)
@verbosity_options
def command(model, output, config):
    """Distil coarser SDFs from the fine SDF MODEL; write the sequence [h1, …, f] with δ to OUTPUT."""
    from dataclasses import replace

    from neural_bake.fit.nested import fit_nested, parse_levels
    from neural_bake.fit.sdf import load_sdf

    c = config
    refuse_nonpositive(steps=c.steps, minutes=c.minutes, band=c.band, max_boxes=c.max_boxes)
    parse_levels(c.levels)  # a bad level is refused before the model is read
    if verbosity() < 0:
        c = replace(c, progress=False)
    lock_outputs(output)  # checks its folder; one writer per file
    say(f"settings: {c}", 1)
    fine = load_sdf(model, device=c.device)
    seq = fit_nested(fine, c)
    say(f"{'level':>8} {'steps':>6} {'best':>6} {'sup est':>9} {'sup cert':>9} {'δ est':>9} {'δ cert':>9} "
        f"{'δ used':>9}")
    for info in seq.levels_info:
        def f(v):
            return "-" if v is None else f"{v:.5f}"
        say(f"{str(info['width']) + 'x' + str(info['depth']):>8} {info.get('steps', 0):>6} {str(info.get('best_step', '-')):>6} "
            f"{f(info.get('sup_estimated')):>9} {f(info.get('sup_certified')):>9} "
            f"{f(info.get('delta_estimated')):>9} {f(info.get('delta_certified')):>9} "
            f"{f(info.get('delta')):>9} ({info.get('delta_source')})")
    seq.save(output)
    say(f"wrote {output}")
