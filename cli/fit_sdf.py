"""`neural-bake fit sdf MESH -o MODEL`: fit a fine SIREN SDF to a mesh (thin verb)."""

from __future__ import annotations

import json

import click

__all__ = ["command"]


@click.command()
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Model file to write (safetensors + JSON metadata, kind 'sdf').")
@click.option("--preset", type=click.Choice(["64x1", "128x2", "256x2", "256x3", "quick", "default", "high"]),
              default="256x3", show_default=True,
              help="Network (W, D) and time budget: 64x1 ≈2 min, 128x2 ≈5, 256x2 ≈8, 256x3 ≈10 min; quick, "
                   "default and high are 64x1, 128x2 and 256x3.")
@click.option("--steps", type=int, default=None, help="Maximum optimiser steps (default: the preset's).")
@click.option("--minutes", type=float, default=None, help="Wall-clock budget in minutes (default: the preset's).")
@click.option("--seed", type=int, default=None, help="Seed of weights and samples (same seed, same model).")
@click.option("--lr", type=float, default=None, help="Initial Adam learning rate (default: the preset's).")
@click.option("--lr-min-factor", type=float, default=None,
              help="Final learning rate of the cosine schedule as a fraction of --lr (default: the preset's).")
@click.option("--batch", type=int, default=None, help="Surface points per step (default 4096).")
@click.option("--checkpoint", type=click.Path(dir_okay=False), default=None,
              help="Checkpoint file written during training (default: OUTPUT.ckpt when --resume).")
@click.option("--hard-fraction", type=float, default=None,
              help="Part of each surface and near batch drawn from the worst-fitted samples (default 0.25; 0: off).")
@click.option("--zero-fraction", type=float, default=None,
              help="Part of each near batch drawn from mined points of the network's own zero level set, "
                   "trained to their true distance (default 0: off).")
@click.option("--focus-tau", type=float, default=None,
              help="Worst-point focus: residuals above this (unit frame) weigh up to 17x more, leaning the loss "
                   "towards the maximum error (default: the preset's; 0: off).")
@click.option("--w-surface", type=float, default=None, help="Weight of f^2 on surface samples (default 3000).")
@click.option("--w-normal", type=float, default=None,
              help="Weight of the normal alignment 1 - cos(grad f, n) on surface samples (default 100).")
@click.option("--w-eikonal", type=float, default=None,
              help="Weight of (1 - |grad f|)^2 on every point (default 50; the 64x1 preset 10).")
@click.option("--w-sdf", type=float, default=None,
              help="Weight of (f - d)^2 on near and uniform samples (default 3000; on Spot, 64x1, 300 lowered "
                   "Hausdorff but raised it on the Stanford bunny: BENCHMARKS.md).")
@click.option("--resume", is_flag=True, help="Continue from the checkpoint if it exists.")
@click.option("--gemm-dtype", type=click.Choice(["auto", "float32", "bfloat16"]), default=None,
              help="Hidden GEMMs of the first 75% of the run: auto (default: bfloat16 where measured 1.5x "
                   "faster, W >= 128), float32 or bfloat16.")
@click.option("--compile", "compile_", type=click.Choice(["auto", "on", "off"]), default=None,
              help="torch.compile the loss (fuses its element-wise work; 5-20 s once): auto (default) "
                   "compiles runs of 5 minutes or more where a C++ compiler is available.")
@click.option("--micro-batches", type=int, default=None,
              help="Run each step in this many micro-batches, each forward and backward on its own (same "
                   "gradients; default 0: auto — on a CPU, runs with a time budget time the counts up to "
                   "the cache-sized rule's and keep the fastest, runs with a step count use the rule; one "
                   "elsewhere).")
@click.option("--polish-evals", type=int, default=None,
              help="L-BFGS polish after Adam: this many full-batch loss evaluations, their time taken from the "
                   "budget; kept only if a held-out loss falls (default: the preset's; 0: off).")
@click.option("--polish-share", type=float, default=None,
              help="With a time budget: the part of it set aside for the polish, which then runs until its "
                   "evaluations or the budget end (0: set aside its estimated cost; the 64x1 preset 0.25).")
@click.option("--metrics/--no-metrics", default=True, help="Measure Chamfer/Hausdorff/normal error at the end.")
@click.option("--progress/--no-progress", default=True, help="Show a progress bar on stderr.")
def command(mesh, output, preset, steps, minutes, seed, lr, lr_min_factor, batch, checkpoint, hard_fraction,
            zero_fraction, focus_tau, w_surface, w_normal, w_eikonal, w_sdf, resume, gemm_dtype, compile_,
            micro_batches, polish_evals, polish_share, metrics, progress):
    """Fit a SIREN SDF to MESH and write it to OUTPUT (prints progress and the final metrics)."""
    from neural_bake.fit.sdf import fit_sdf
    from neural_bake.io.mesh_io import load_mesh

    from .options import lock_outputs, refuse_nonpositive

    refuse_nonpositive(steps=steps, minutes=minutes, lr=lr, batch=batch)
    if resume and checkpoint is None:
        checkpoint = output + ".ckpt"
    lock_outputs(output, checkpoint)  # checks their folders; one writer per file
    m = load_mesh(mesh)
    given = {"steps": steps, "minutes": minutes, "seed": seed, "lr": lr, "lr_min_factor": lr_min_factor,
             "batch": batch, "checkpoint": checkpoint, "hard_fraction": hard_fraction,
             "zero_fraction": zero_fraction, "focus_tau": focus_tau, "w_surface": w_surface, "w_normal": w_normal,
             "w_eikonal": w_eikonal, "w_sdf": w_sdf, "gemm_dtype": gemm_dtype,
             "compile": compile_, "micro_batches": micro_batches, "polish_evals": polish_evals,
             "polish_share": polish_share}
    fit = fit_sdf(m, preset=preset, resume=resume, progress=progress,
                  **{k: v for k, v in given.items() if v is not None})  # unset options keep the preset's
    last = fit.history[-1] if fit.history else {}
    b = fit.budget
    how = (fit.stopped_reason if b is None else b["stopped"]) + ("; loss compiled" if fit.config.compile == "on" else "")
    if b is not None and b["expected_steps"]:
        how += f"; this machine makes ~{b['expected_steps']} Adam steps in {b['budget_seconds']:.0f} s"
    click.echo(f"fit sdf {fit.config.width}x{fit.config.depth}: {fit.steps} steps in {fit.seconds:.1f} s ({how}); "
               f"final loss {last.get('loss', float('nan')):.4g}"
               + (f"; {fit.restarts} divergence restart(s)" if fit.restarts else ""))
    if fit.micro_batch_tuning:
        last_tuning = fit.micro_batch_tuning[-1]
        ms = ", ".join(f"{k}: {1e3 * t:.1f} ms" for k, t in last_tuning["seconds"].items())
        click.echo(f"micro-batches: {last_tuning['choice']} (last of {len(fit.micro_batch_tuning)} tunings, "
                   f"step {last_tuning['step']}: {ms})")
    if fit.polish:
        p = {k: ("n/a" if v is None else f"{v:.4g}" if isinstance(v, float) else v) for k, v in fit.polish.items()}
        click.echo(f"L-BFGS polish: {p['evals']} evaluations in {p['seconds']} s, loss {p['loss_before']} -> "
                   f"{p['loss_after']}, held-out {p['check_before']} -> {p['check_after']} "
                   f"({'kept' if fit.polish['kept'] else 'not kept: ' + p['reason']})")
    if metrics:
        from neural_bake.fit.metrics import sdf_metrics

        res = sdf_metrics(fit.model, m, n=50_000, resolution=128)
        click.echo("metrics (unit frame): " + json.dumps({k: round(v, 6) if isinstance(v, float) else v
                                                          for k, v in res.items()}))
    fit.save(output)
    click.echo(f"wrote {output}")
