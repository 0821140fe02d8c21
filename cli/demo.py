"""`neural-bake demo -o DIR`: the main job end to end on a bundled sample (thin verb)."""

from __future__ import annotations

import click

from .config_options import ConfigCommand, ConfigSpec
from .options import output_option, say, verbosity, verbosity_options

__all__ = ["command"]


def _config_class():
    from neural_bake.pipelines.demo import DemoConfig

    return DemoConfig


def _resolve(preset, values):
    from neural_bake.pipelines.demo import DemoConfig

    return DemoConfig(**values)


SPEC = ConfigSpec(load=_config_class, resolve=_resolve)


@click.command(cls=ConfigCommand, config=SPEC, epilog="""\b
Examples:
  neural-bake demo -o demo-out
  neural-bake demo -o demo-torus --sample torus --sdf-minutes 1 --size 512 --seed 1""")
@output_option("Output folder (models, asset.glb, maps, report.json, demo.json) [default: demo-out].",
               folder=True, required=False, old_spelling=True)
@verbosity_options
def command(output, config):
    """Fit, coarsen, bake and report on a bundled sample (about 4 minutes on 2 CPU cores).

    Every setting below is a field of the demo's config: a --config file sets them first, the options
    given override it."""
    from dataclasses import replace

    from neural_bake.pipelines.demo import run_demo

    if verbosity() < 0:
        config = replace(config, progress=False)
    say(f"settings: {config}", 1)
    run_demo(output or "demo-out", config, log=say)
