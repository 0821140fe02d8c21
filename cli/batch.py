"""`neural-bake batch MANIFEST -o OUT`: fit and bake many assets, resumable, on a local pool or Ray (thin verb)."""

from __future__ import annotations

import click

__all__ = ["command"]

def _stage_option(ctx, param, values):
    """``--set STAGE.FIELD=VALUE`` pairs as ``{stage: {field: text}}``."""
    from .options import key_values

    out: dict[str, dict] = {}
    for key, value in key_values(values, form="STAGE.FIELD=VALUE", example="bake.size=1024"):
        stage, dot, name = key.partition(".")
        if not dot or not name:
            raise click.BadParameter(f"{key}={value!r}: expected STAGE.FIELD=VALUE, e.g. bake.size=1024")
        out.setdefault(stage, {})[name] = value
    return out

def _check_set(stages: dict[str, dict]) -> None:
    """Every ``--set STAGE.FIELD=VALUE`` names a setting of its stage: one line (exit 2) otherwise, before any work."""
    from neural_bake.errors import NeuralBakeError
    from neural_bake.pipelines.stages import unknown_setting

    for stage, opts in stages.items():
        for name, value in opts.items():
            problem = unknown_setting(stage, name)
            if problem:
                raise NeuralBakeError(f"--set {stage}.{name}={value}: {problem}")


@click.command(epilog="""\b
Example:
  neural-bake samples -o meshes/
  neural-bake batch 'meshes/*.obj' -o baked/ --preset quick
  neural-bake batch assets.csv -o baked/ --set bake.size=1024 --workers 2
  neural-bake batch --preset quick --print-config > batch.toml
  neural-bake batch assets.csv -o baked/ --config batch.toml
Re-running the same command skips every stage whose inputs and settings are unchanged.""")
@click.argument("manifest", required=False)
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="TOML settings file: batch settings at the top, a table per stage ([sdf], [bake], …); "
                   "the command line's options override it.")
@click.option("--print-config", is_flag=True,
              help="Print the resolved settings (every stage field) as TOML and exit; the output is a valid --config.")
@click.option("-o", "--output", "out", type=click.Path(file_okay=False),
              help="Output folder: one folder per asset and batch.json (the summary).")
@click.option("--preset", default="default", show_default=True, metavar="NAME[,NAME…]",
              help="Stage settings: quick (about a minute per asset on a 2-core CPU), default (the fits' default "
                   "presets: about 10 minutes), high (the largest networks: about 25 minutes). Several, "
                   "comma-separated (quick,default,high), run the batch once per preset into OUT/PRESET/ and "
                   "write a page per asset comparing them (OUT/compare/ASSET/), linked from OUT/index.html.")
@click.option("--set", "stages", multiple=True, callback=_stage_option, metavar="STAGE.FIELD=VALUE",
              help="A stage setting for every asset (repeatable; a manifest row's own value wins).")
@click.option("--workers", type=int, default=0, show_default=True,
              help="Assets at once (0: usable cores // 2, at least 1).")
@click.option("--threads", type=int, default=0, show_default=True,
              help="Torch threads per worker (0: cores // workers).")
@click.option("--executor", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="local: a process pool on this machine; ray: Ray tasks (pip install -e '.[ray]').")
@click.option("--address", default=None, help="Ray cluster address (default: a local Ray instance).")
@click.option("--seed", type=int, default=None, help="Seed of every fit (default: each stage's own).")
@click.option("--device", default=None, help="Torch device of the fits: cpu, cuda, cuda:1, … (default cpu).")
@click.option("--quiet", "-q", is_flag=True, help="Print only the summary.")
@click.option("--verbose", "-v", is_flag=True, help="Also print each bake's own lines.")
def command(manifest, config_path, print_config, out, preset, stages, workers, threads, executor, address, seed,
            device, quiet, verbose):
    """Fit and bake every asset of MANIFEST into OUT, resumably; failures are isolated.

    MANIFEST is a CSV or JSON file (per-asset name, texture and STAGE.FIELD overrides), a text file with
    one mesh path per line, or a glob. Exit code 1 if any asset failed.
    """
    from neural_bake.errors import NeuralBakeError
    from neural_bake.io.tomlio import read_toml, toml_text
    from neural_bake.pipelines.batch import (batch_config, parse_presets, resolved_config, run_batch,
                                             run_preset_batches)

    ctx = click.get_current_context()
    presets = parse_presets(preset)
    preset = presets[0]
    given = {k: v for k, v in dict(preset=preset, stages=stages, workers=workers, threads=threads, executor=executor,
                                   address=address, seed=seed, device=device, quiet=quiet, verbose=verbose).items()
             if ctx.get_parameter_source(k) == click.core.ParameterSource.COMMANDLINE}
    _check_set(stages)
    table = read_toml(config_path) if config_path else {}
    cfg = batch_config(table, where=config_path or "config", **given)
    if print_config:
        if len(presets) > 1:
            raise NeuralBakeError("--print-config prints one preset's settings: give one --preset")
        click.echo(toml_text(*resolved_config(cfg)), nl=False)
        return
    if manifest is None or out is None:
        raise click.UsageError("give MANIFEST and -o OUT (or --print-config)")
    if len(presets) > 1:
        summary = run_preset_batches(manifest, out, cfg, presets, log=click.echo)
    else:
        summary = run_batch(manifest, out, cfg, log=click.echo)
    if summary["failed"]:
        raise click.exceptions.Exit(1)
