"""`neural-bake fit sdf MESH -o MODEL`: fit a fine SIREN SDF to a mesh (thin verb)."""

from __future__ import annotations

import json

import click

from neural_bake.constants import POOL_REFRESH_MAX_SHARE

from .config_options import ConfigCommand, ConfigSpec
from .options import lock_outputs, output_option, refuse_nonpositive, say, verbosity, verbosity_options

__all__ = ["command"]


def _resolve(preset, values):
    from neural_bake.fit.sdf_config import config_from

    return config_from(preset=preset, **values)


def _config_class():
    from neural_bake.fit.sdf_config import SdfFitConfig

    return SdfFitConfig


SPEC = ConfigSpec(load=_config_class, resolve=_resolve, default_preset="default",
                  presets=("quick", "default", "high", "64x1", "128x2", "256x2", "256x3"),
                  described=("quick", "default", "high", "64x1", "128x2", "256x2", "256x3"),
                  preset_help="Network (W, D) and time budget (default: a 64x3 coarse level and a 128x3 residual level, "
                              "one 192x3, for 5 minutes)",
                  required=("mesh", "output"), pass_preset=True)


@click.command(cls=ConfigCommand, config=SPEC, epilog="""\b
Examples:
  neural-bake fit sdf samples/bumpy_sphere.obj -o bumpy.sdf --preset quick
  neural-bake fit sdf mesh.obj -o mesh.sdf --minutes 3 --seed 1 --device cuda
  neural-bake fit sdf mesh.obj -o mesh.sdf --preset quick --budget steps   # the same result under any load
  neural-bake fit sdf --preset quick --print-config > sdf.toml
  neural-bake fit sdf mesh.obj -o mesh.sdf --config sdf.toml --steps 2000""")
@click.argument("mesh", type=click.Path(dir_okay=False), required=False)
@output_option("Model file to write (safetensors + JSON metadata, kind 'sdf').", required=False)
@click.option("--metrics/--no-metrics", default=True, help="Measure Chamfer/Hausdorff/normal error at the end.")
@verbosity_options
def command(mesh, output, config, preset, metrics):
    """Fit a SIREN SDF to MESH and write it to OUTPUT (prints progress and the final metrics).

    Every setting below is a field of the SDF fit's config: a --config file sets them first, the options
    given override it."""
    from dataclasses import asdict, replace

    from neural_bake.fit.sdf import fit_sdf
    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.mesh.shells import buried_faces

    refuse_nonpositive(steps=config.steps, minutes=config.minutes, lr=config.lr, batch=config.batch)
    if config.resume and config.checkpoint is None:
        config = replace(config, checkpoint=output + ".ckpt")
    if verbosity() < 0:
        config = replace(config, progress=False)
    lock_outputs(output, config.checkpoint)  # checks their folders; one writer per file
    say(f"settings: {config}", 1)
    m = load_mesh(mesh)
    # the preset again: the budget is accounted against it
    fit = fit_sdf(m, preset=preset, **asdict(config))
    label = getattr(fit, "label", f"{fit.config.width}x{fit.config.depth}")
    last = fit.history[-1] if fit.history else {}
    b = fit.budget
    how = (fit.stopped_reason if b is None else b["stopped"]) + ("; loss compiled" if fit.config.compile == "on" else "")
    if b is not None and b.get("budget") == "steps":
        how += (f"; the preset's steps on the quiet reference machine, ~{b['estimated_seconds']:.0f} s "
                "estimated on this one")
    elif b is not None and b["expected_steps"]:
        how += f"; this machine makes ~{b['expected_steps']} Adam steps in {b['budget_seconds']:.0f} s"
        if b.get("asset_seconds_per_step"):
            how += f" with this mesh's sampling ({1e3 * b['asset_seconds_per_step']:.1f} ms a step)"
    skipped = ((b or {}).get("pool_refreshes") or {}).get("skipped")
    if skipped:
        how += (f"; {skipped} pool refresh(es) skipped (building them would have taken over "
                f"{100 * POOL_REFRESH_MAX_SHARE:.0f} % of the time)")
    if fit.config.construction != "plain":
        how += f"; the steps of its fine level, whose band is |h| < {fit.band:.4g}" if getattr(fit, "band", None) else ""
        how += f"; its coarse level made {fit.coarse.steps}" if getattr(fit, "coarse", None) else ""
        audit = getattr(fit, "audit", None)
        how += (f"; its band audit kept {audit['kept']} of {audit['candidates']} candidates in {audit['seconds']:.1f} s"
                if audit else "")
        how += " (the expected steps are both levels')" if b is not None and b.get("expected_steps") else ""
    say(f"fit sdf {label}: {fit.steps} steps in {fit.seconds:.1f} s ({how}); "
        f"final loss {last.get('loss', float('nan')):.4g}"
        + (f"; {fit.restarts} divergence restart(s)" if fit.restarts else ""))
    if b is not None and b.get("note"):
        say(b["note"])
    buried = int(buried_faces(m).sum())  # kept from the fit's sampling
    if buried:
        say(f"{m.name}: {buried:,} of {m.n_faces:,} faces lie inside another of its shells; the field is the shells' "
            "union, and those faces are not its surface")
    if fit.micro_batch_tuning:
        last_tuning = fit.micro_batch_tuning[-1]
        ms = ", ".join(f"{k}: {1e3 * t:.1f} ms" for k, t in last_tuning["seconds"].items())
        say(f"micro-batches: {last_tuning['choice']} (last of {len(fit.micro_batch_tuning)} tunings, "
            f"step {last_tuning['step']}: {ms})")
    if fit.polish:
        p = {k: ("n/a" if v is None else f"{v:.4g}" if isinstance(v, float) else v) for k, v in fit.polish.items()}
        say(f"L-BFGS polish: {p['evals']} evaluations in {p['seconds']} s, loss {p['loss_before']} -> "
            f"{p['loss_after']}, held-out {p['check_before']} -> {p['check_after']} "
            f"({'kept' if fit.polish['kept'] else 'not kept: ' + p['reason']})")
    if metrics:
        from neural_bake.fit.metrics import sdf_metrics

        res = sdf_metrics(fit.model, m, n=50_000, resolution=128)
        say("metrics (unit frame): " + json.dumps({k: round(v, 6) if isinstance(v, float) else v
                                                   for k, v in res.items()}))
    fit.save(output)
    say(f"wrote {output}")
