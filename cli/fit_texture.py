"""`neural-bake fit texture MESH --sdf MODEL -o MODEL`: fit a gradient-orthogonal colour MLP (thin verb)."""

from __future__ import annotations

import click

from .config_options import ConfigCommand, ConfigSpec
from .options import lock_outputs, output_option, refuse_nonpositive, say, verbosity, verbosity_options

__all__ = ["command"]


def _config_class():
    from neural_bake.fit.texture import TextureFitConfig

    return TextureFitConfig


def _resolve(preset, values):
    from neural_bake.fit.texture import TextureFitConfig, _resolve_config

    return _resolve_config(TextureFitConfig(progress=True), {**values, **({"preset": preset} if preset else {})})


SPEC = ConfigSpec(load=_config_class, resolve=_resolve, presets=("quick", "default", "high", "fast", "medium", "fine"),
                  described=("quick", "default", "high"), costs={"quick": "feature grid + 64x1, 4M samples, 1 min",
                                                                      "default": "feature grid + 64x2, 8M samples, 4 min"},
                  preset_help="Network size and time budget (fast, medium and fine are older names of quick, "
                              "default and high; none: 256x3 for --steps)",
                  required=("mesh", "sdf_path", "output"), pass_preset=True)


@click.command(cls=ConfigCommand, config=SPEC, epilog="""\b
Examples:
  neural-bake fit texture samples/bumpy_sphere.obj --sdf bumpy.sdf -o bumpy.tex --preset quick
  neural-bake fit texture mesh.obj --sdf mesh.nested -o mesh.tex --minutes 2 --lam 1e-3 --device cuda
  neural-bake fit texture mesh.obj --sdf mesh.sdf -o mesh.tex --preset quick --budget steps
  neural-bake fit texture --preset default --print-config > texture.toml""")
@click.argument("mesh", type=click.Path(dir_okay=False), required=False)
@click.option("--sdf", "sdf_path", type=click.Path(dir_okay=False), default=None,
              help="The fitted SDF of this mesh: a `fit sdf` file (its sampled distance error is the default band δ) "
                   "or a `fit nested` file (normals from its fine level, band δ of its coarsest level).")
@output_option("Texture model file to write (safetensors + JSON metadata).", required=False)
@click.option("--texture", "texture_path", type=click.Path(dir_okay=False), default=None,
              help="Texture image to fit instead of the one the mesh file names (8/16-bit sRGB or float linear).")
@click.option("--uv-policy", type=click.Choice(["wrap", "clamp"]), default="wrap", show_default=True,
              help="UVs outside [0, 1]: repeat the texture or clamp to its border.")
@click.option("--metrics/--no-metrics", default=True,
              help="After fitting, print surface PSNR, colour change across the band and render-space MSE.")
@verbosity_options
def command(mesh, sdf_path, output, config, preset, texture_path, uv_policy, metrics):
    """Fit a colour MLP g to MESH's texture; bakes read it at the SDF's closest points (--lam: λ·⟨∇g, ∇f⟩² in the δ-band).

    Every setting below is a field of the texture fit's config: a --config file sets them first, the
    options given override it."""
    from dataclasses import asdict, replace

    from neural_bake.fit.texture import fit_texture, texture_metrics
    from neural_bake.io.mesh_io import load_mesh

    refuse_nonpositive(steps=config.steps, minutes=config.minutes, lr=config.lr, batch=config.batch,
                       width=config.width)
    if verbosity() < 0:
        config = replace(config, progress=False)
    lock_outputs(output, config.checkpoint)  # checks their folders; one writer per file
    say(f"settings: {config}", 1)
    m = load_mesh(mesh, texture_path, uv_policy=uv_policy)
    # the preset again, as `fit sdf` does: the budget is accounted against its step cost
    fit = fit_texture(m, sdf_path, None, preset=preset, **asdict(config))
    fit.save(output)
    cfg = fit.config
    b = fit.budget
    how = fit.stopped_reason if b is None else b["stopped"]
    if b is not None and b.get("budget") == "steps":
        how += (f"; the preset's steps on the quiet reference machine, ~{b['estimated_seconds']:.0f} s "
                "estimated on this one")
    elif b is not None and b["expected_steps"]:
        how += f"; this machine makes ~{b['expected_steps']} in the budget"
    net = f"feature grid + ({cfg.width}, {cfg.depth})" if cfg.network == "grid" else f"({cfg.width}, {cfg.depth})"
    say(f"fitted {net} texture of {m.name}: {fit.steps} steps in {fit.seconds:.1f} s "
        f"({how}), λ = {fit.lam:g}, δ = {fit.delta:g} (unit frame), {fit.encoding} colours")
    if metrics:
        q = texture_metrics(fit.field(), m, sdf_path, delta=fit.delta, n=20000, n_views=4,
                            resolution=96)
        change = "n/a" if q["band_change"] is None else f"{q['band_change']:.4g}"
        render = "n/a" if q["render_mse"] is None else f"{q['render_mse']:.4g}"
        say(f"surface PSNR {q['surface_psnr']:.2f} dB (MSE {q['surface_mse']:.3g}), per texel "
            f"{q['texel_psnr']:.2f} dB ({q['texel_psnr_srgb']:.2f} dB sRGB), colour change across the band "
            f"{change}, render MSE {render} (linear RGB)")
    say(f"wrote {output}")
