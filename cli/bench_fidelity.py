"""`neural-bake bench fidelity`: baked normal error on the real meshes beside the classical bake (thin verb)."""

from __future__ import annotations

import click

from .bench import bench_options, report
from .options import key_values


@click.command("fidelity")
@bench_options
@click.option("--mesh", "meshes", multiple=True,
              help="A mesh of the data folder by name (nefertiti, fandisk, cabinet, …), the generated dots sample "
                   "(dots), or a mesh file; repeatable (default: all of the data folder's; --quick: fandisk).")
@click.option("--preset", "presets", multiple=True, help="SDF preset, repeatable (default quick and high; --quick: quick).")
@click.option("--faces", type=int, default=None, help="Decimation target (default 3000; --quick 1000).")
@click.option("--size", type=int, default=None, help="Map side in texels (default 1024; --quick 256).")
@click.option("--minutes", type=float, default=None, help="Override every preset's time budget.")
@click.option("--texture/--no-texture", default=None, help="Fit and bake textures of textured assets (default: "
              "yes, not with --quick).")
@click.option("--sampling", default=None, metavar="LIST",
              help="Comma-separated SDF sampling variants to compare in one run: uniform, curvature, error, "
                   "curvature+error, sign / no-sign (the sign-error mining of the uniform batch on or off), audit / "
                   "no-audit (the residual construction's band audit with sign mining, or without the audit), texel / "
                   "no-texel (half the surface samples by UV area, or none), preset "
                   "(default: the preset's own). Rows get ratios against uniform.")
@click.option("--sdf-construction", "constructions", default=None, metavar="LIST",
              help="Comma-separated SDF constructions fitted at the same budget, one row each: plain (one network "
                   "of the preset's width), residual (a coarse level 64 wide at ω0 15 for a quarter of the budget, then "
                   "the rest of the width fitted as a residual inside the coarse level's band; the quick, default and high presets' own), "
                   "residual-warm (the whole width started from the coarse level), tiles (the same coarse level, "
                   "then small SIRENs over a grid of tiles fitted as its residual). Default: the preset's own. Rows "
                   "get ratios against plain.")
@click.option("--steps", default=None, metavar="LIST",
              help="Comma-separated step counts: fit each case for exactly that many steps, no time budget.")
@click.option("--texture-steps", type=int, default=None,
              help="Adam steps of every texture fit (default: the preset's steps on the reference machine, "
                   "--budget steps; --quick: 200).")
@click.option("--texture-network", "texture_networks", default=None, metavar="LIST",
              help="Comma-separated colour-network constructions fitted side by side, one texture row each: siren "
                   "(the preset's SIREN), siren-wide (twice as wide, one matrix deeper), grid (the preset's feature "
                   "grid and MLP, at a SIREN preset a grid + 64x1 MLP; half the samples at the texture's edges), "
                   "grid-uniform (the grid, no edge samples), grid-normals (the grid's MLP also reading the surface "
                   "normal), grid-auto (reading it on open meshes); default: the preset's own network. Anything but "
                   "that alone runs every texture fit at the preset's time budget (equal time) unless "
                   "--texture-steps or --texture-minutes is given.")
@click.option("--texture-minutes", type=float, default=None,
              help="Time budget of every texture fit (equal time; the steps made follow the machine).")
@click.option("--only-textures", is_flag=True,
              help="Only the texture rows, on the textured assets (default: all of them; --quick: spot).")
@click.option("--sdf-set", "sdf_set", multiple=True, metavar="FIELD=VALUE",
              help="An SDF fit setting (a field of fit sdf's config, e.g. coarse_share=0.1) set on every fit over the "
                   "preset's; repeatable. Rows and saved models' names carry it.")
@click.option("--save-models", "save_dir", type=click.Path(file_okay=False), default=None, metavar="DIRECTORY",
              help="Also save every fitted SDF as DIR/MESH-PRESET.sdf (e.g. for bench bake --anchor-model).")
def command(quick, json_path, meshes, presets, faces, size, minutes, texture, sampling, constructions, steps,
            texture_steps, texture_networks, texture_minutes, only_textures, sdf_set, save_dir) -> None:
    """Per real mesh and preset at its budget: baked normal error (median, p95) against the source mesh beside
    ∇f alone, the classical mesh-to-mesh bake and the coarse mesh's own normals; Hausdorff (open meshes also
    without their caps); times; texture PSNR; storage. Textured assets add a texture row: the albedo of the
    network alone, of the hybrid colour rule and of the classical transfer against the source texture (PSNR,
    SSIM) and the time of each bake. Meshes not present are skipped, saying so."""
    from neural_bake.bench.fidelity import SAMPLINGS, TEXTURE_NETWORKS, run
    from neural_bake.fit.residual import CONSTRUCTIONS

    variants = None if sampling is None else [v.strip() for v in sampling.split(",") if v.strip()]
    bad = [v for v in variants or [] if v not in SAMPLINGS]
    if bad or variants == []:
        raise click.BadParameter(f"choose among {', '.join(SAMPLINGS)}, got {sampling!r}", param_hint="--sampling")
    kinds = None if constructions is None else [v.strip() for v in constructions.split(",") if v.strip()]
    if kinds is not None and (not kinds or any(v not in CONSTRUCTIONS for v in kinds) or len(set(kinds)) != len(kinds)):
        raise click.BadParameter(f"choose distinct names among {', '.join(CONSTRUCTIONS)}, got {constructions!r}",
                                 param_hint="--sdf-construction")
    try:
        counts = None if steps is None else [int(n) for n in steps.split(",") if n.strip()]
    except ValueError:
        counts = []
    nets = None if texture_networks is None else [v.strip() for v in texture_networks.split(",") if v.strip()]
    if nets is not None and (not nets or any(v not in TEXTURE_NETWORKS for v in nets)):
        raise click.BadParameter(f"choose among {', '.join(TEXTURE_NETWORKS)}, got {texture_networks!r}",
                                 param_hint="--texture-network")
    if texture_minutes is not None and not texture_minutes > 0:
        raise click.BadParameter(f"expected a positive number, got {texture_minutes}", param_hint="--texture-minutes")
    if texture_steps is not None and texture_steps < 1:
        raise click.BadParameter(f"expected a positive integer, got {texture_steps}", param_hint="--texture-steps")
    if counts is not None and (not counts or min(counts) < 1):
        raise click.BadParameter(f"expected positive integers separated by commas, got {steps!r}",
                                 param_hint="--steps")
    settings = {key.replace("-", "_"): value for key, value in key_values(
        sdf_set, form="FIELD=VALUE", example="coarse_share=0.1", param_hint="--sdf-set")}
    report(run(quick=quick, meshes=list(meshes) or None, presets=list(presets) or None, faces=faces, size=size,
               minutes=minutes, texture=texture, sampling=variants, steps=counts, save_dir=save_dir,
               texture_steps=texture_steps, only_textures=only_textures, texture_networks=nets,
               texture_minutes=texture_minutes, constructions=kinds, sdf_settings=settings or None,
               log=click.echo),
           json_path)
