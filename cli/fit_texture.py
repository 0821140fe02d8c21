"""`neural-bake fit texture MESH --sdf MODEL -o MODEL`: fit a gradient-orthogonal colour MLP (thin verb)."""

from __future__ import annotations

import ast
import inspect
from functools import lru_cache

import click

__all__ = ["command"]


@lru_cache(maxsize=None)
def _field_docs() -> dict[str, str]:
    """Field name -> the docstring line under it in TextureFitConfig (the help text of the options)."""
    from neural_bake.fit.texture import TextureFitConfig

    tree = ast.parse(inspect.getsource(TextureFitConfig))
    body = tree.body[0].body
    docs = {}
    for a, b in zip(body, body[1:]):
        if isinstance(a, ast.AnnAssign) and isinstance(b, ast.Expr) and isinstance(b.value, ast.Constant):
            docs[a.target.id] = " ".join(str(b.value.value).split())
    return docs


def _help(name: str) -> str:
    try:
        return _field_docs().get(name, "")
    except (OSError, TypeError, SyntaxError):  # source not available (frozen install): no help text
        return ""


class _ConfigHelpCommand(click.Command):
    """Fills each option's help from the config's field docstrings when help is shown."""

    def get_params(self, ctx):
        params = super().get_params(ctx)
        for p in params:
            field = getattr(p, "config_field", None)
            if field and not p.help:
                p.help = _help(field)
        return params


def _opt(*decls, field: str, **kwargs):
    def deco(fn):
        fn = click.option(*decls, **kwargs)(fn)
        fn.__click_params__[-1].config_field = field
        return fn

    return deco


@click.command(cls=_ConfigHelpCommand)
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.option("--sdf", "sdf_path", required=True, type=click.Path(dir_okay=False),
              help="The fitted SDF of this mesh: a `fit sdf` file (its sampled distance error is the default band δ) "
                   "or a `fit nested` file (normals from its fine level, band δ of its coarsest level).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Texture model file to write (safetensors + JSON metadata).")
@click.option("--preset", type=click.Choice(["quick", "default", "high", "fast", "medium", "fine"]), default=None,
              help="Network size and time budget preset: quick (64x1, ≈1 min), default (128x2, ≈4 min), high "
                   "(256x3, ≈10 min); fast, medium and fine are their earlier names.")
@click.option("--texture", "texture_path", type=click.Path(dir_okay=False), default=None,
              help="Texture image to fit instead of the one the mesh file names (8/16-bit sRGB or float linear).")
@click.option("--uv-policy", type=click.Choice(["wrap", "clamp"]), default="wrap", show_default=True,
              help="UVs outside [0, 1]: repeat the texture or clamp to its border.")
@_opt("--lam", field="lam", type=float, default=None)
@_opt("--delta", field="delta", type=float, default=None)
@_opt("--minutes", field="minutes", type=float, default=None)
@_opt("--steps", field="steps", type=int, default=None)
@_opt("--width", field="width", type=int, default=None)
@_opt("--depth", field="depth", type=int, default=None)
@_opt("--batch", field="batch", type=int, default=None)
@_opt("--lr", field="lr", type=float, default=None)
@_opt("--seed", field="seed", type=int, default=None)
@_opt("--checkpoint", field="checkpoint", type=click.Path(dir_okay=False), default=None)
@_opt("--resume", field="resume", is_flag=True, default=False)
@click.option("--progress/--no-progress", default=True, help="Show a progress bar on stderr.")
@click.option("--metrics/--no-metrics", default=True,
              help="After fitting, print surface PSNR, colour change across the band and render-space MSE.")
def command(mesh, sdf_path, output, preset, texture_path, uv_policy, lam, delta, minutes, steps, width, depth,
            batch, lr, seed, checkpoint, resume, progress, metrics):
    """Fit a colour MLP g to MESH's texture, constant along the normals of the SDF (λ·⟨∇g, ∇f⟩² in the δ-band)."""
    from neural_bake.fit.texture import fit_texture, texture_metrics
    from neural_bake.io.mesh_io import load_mesh

    from .options import lock_outputs, refuse_nonpositive

    refuse_nonpositive(steps=steps, minutes=minutes, lr=lr, batch=batch, width=width)
    lock_outputs(output, checkpoint)  # checks their folders; one writer per file
    m = load_mesh(mesh, texture_path, uv_policy=uv_policy)
    overrides = {k: v for k, v in dict(lam=lam, delta=delta, minutes=minutes, steps=steps, width=width,
                                       depth=depth, batch=batch, lr=lr, seed=seed, checkpoint=checkpoint).items()
                 if v is not None}
    if resume:
        overrides["resume"] = True
    if preset is not None:
        overrides["preset"] = preset
    fit = fit_texture(m, sdf_path, progress=progress, **overrides)
    fit.save(output)
    cfg = fit.config
    b = fit.budget
    how = fit.stopped_reason if b is None else b["stopped"]
    if b is not None and b["expected_steps"]:
        how += f"; this machine makes ~{b['expected_steps']} in the budget"
    click.echo(f"fitted ({cfg.width}, {cfg.depth}) texture of {m.name}: {fit.steps} steps in {fit.seconds:.1f} s "
               f"({how}), λ = {fit.lam:g}, δ = {fit.delta:g} (unit frame)")
    if metrics:
        q = texture_metrics(fit.model, m, sdf_path, delta=fit.delta, n=20000, n_views=4,
                            resolution=96)
        change = "n/a" if q["band_change"] is None else f"{q['band_change']:.4g}"
        render = "n/a" if q["render_mse"] is None else f"{q['render_mse']:.4g}"
        click.echo(f"surface PSNR {q['surface_psnr']:.2f} dB (MSE {q['surface_mse']:.3g}), colour change across "
                   f"the band {change}, render MSE {render} (linear RGB)")
    click.echo(f"wrote {output}")
