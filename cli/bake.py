"""`neural-bake bake MESH --sdf MODEL -o OUT`: bake neural normals (and colours) onto a coarse mesh (thin verb).

Parses the options and calls :func:`neural_bake.pipelines.bake_asset.bake_asset`, which writes OUT/asset.glb,
the loose maps, OUT/report.json and the error maps atomically (a failed run leaves OUT as it was).
"""

from __future__ import annotations

import click

__all__ = ["command"]

@click.command()
@click.argument("mesh", metavar="MESH", type=click.Path(dir_okay=False))
@click.option("--sdf", "sdf_path", required=True, metavar="MODEL", help="Fine SDF model file (kind 'sdf').")
@click.option("--texture-model", "tex_path", metavar="MODEL", default=None,
              help="Texture model file (kind 'texture'): bakes the albedo map.")
@click.option("--coarse", default="decimate:2000", show_default=True,
              help="Coarse mesh: decimate:FACES, decimate:RATIO, march:RESOLUTION, level:I:RESOLUTION (a nested sequence's level I marched) or keep.")
@click.option("--maps", "maps_spec", default=None,
              help="What to bake, comma-separated: normal, albedo (needs --texture-model), vertex (per-vertex "
                   "GLB). Default: normal,albedo with a texture model, else normal.")
@click.option("--size", type=int, default=2048, show_default=True, help="Map side in texels.")
@click.option("--texture", metavar="IMG", default=None,
              help="Base-colour image for a mesh whose file names none (ground truth of the report).")
@click.option("--normal-space", type=click.Choice(["tangent", "object"]), default="tangent", show_default=True,
              help="Tangent-space (glTF) or object-space normal map.")
@click.option("--directx", is_flag=True, help="DirectX convention: green points down (-Y).")
@click.option("--bits", type=click.Choice(["8", "16"]), default="8", show_default=True,
              help="Bit depth of the loose PNG maps (the GLB always embeds 8-bit PNGs).")
@click.option("--exr", is_flag=True, help="Also write the maps as float EXR.")
@click.option("--supersample", type=int, default=1, show_default=True, help="s×s samples per texel.")
@click.option("--padding", type=click.Choice(["pull-push", "dilate", "none"]), default="pull-push",
              show_default=True, help="Edge padding of the charts.")
@click.option("--delta", type=float, default=None,
              help="Nesting band half-width δ (unit frame): texels with |f| > δ are flagged as misses "
                   "(default: the model file's δ, if any).")
@click.option("--baseline/--no-baseline", default=True, help="Also run the classical mesh-to-mesh bake.")
@click.option("--cage", type=float, default=None, help="Baseline ray distance (unit frame; default 0.05).")
@click.option("--truth", default="auto", show_default=True,
              help="Ground truth of the report: auto (analytic if MESH is a bundled sample), mesh, sample:NAME.")
@click.option("--texels", "texels_mode", type=click.Choice(["auto", "cache", "stream"]), default="auto",
              show_default=True,
              help="cache: keep every texel sample in memory (report over all of them); stream: bake band by band "
                   "in bounded memory (report on a seeded uniform subsample); auto: cache up to 2^23 samples.")
@click.option("--hybrid/--no-hybrid", default=True, show_default=True,
              help="Texels where the neural field is not faithful (|f| at the source surface above --hybrid-tol, or "
                   "∇f more than --hybrid-angle off the source normal) take the classical mesh-to-mesh normal.")
@click.option("--hybrid-tol", type=float, default=None, help="Hybrid bake: |f| tolerance (unit frame; default 0.01).")
@click.option("--hybrid-angle", type=float, default=None, help="Hybrid bake: angle threshold in degrees (default 20).")
@click.option("--report-samples", type=int, default=None,
              help="Texel samples a streamed bake keeps for the report's per-sample errors (default 2^18).")
@click.option("--adaptive", type=click.Choice(["on", "off"]), default="on", show_default=True,
              help="on: evaluate the fields on a coarse lattice per chart, refined where interpolation would exceed "
                   "--tolerance, and interpolate the rest within charts; off: evaluate every texel.")
@click.option("--tolerance", "tolerance_deg", type=float, default=None, metavar="DEG",
              help="Adaptive bake: largest angle between an interpolated normal and the field's (default 0.25°, "
                   "half an 8-bit step).")
@click.option("--precision", type=click.Choice(["fp32", "auto"]), default="auto", show_default=True,
              help="Hidden GEMMs of the networks: fp32, or auto (bfloat16 where a quick check on this device "
                   "measures it faster and within 0.05° of float32).")
@click.option("--force", is_flag=True,
              help="Bake even when the SDF does not describe MESH (frames differ, or median |f| on its surface "
                   "above the threshold).")
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False), help="Output folder.")
def command(mesh, sdf_path, tex_path, coarse, maps_spec, size, texture, normal_space, directx, bits, exr,
            supersample, padding, delta, baseline, cage, truth, texels_mode, hybrid, hybrid_tol, hybrid_angle,
            report_samples, adaptive, tolerance_deg, precision, force, out):
    """Bake the neural normals (and colours) of MESH's fitted fields onto a coarse mesh; write a GLB, maps
    and a quality report into OUT."""
    from neural_bake.pipelines.bake_asset import BakeAssetConfig, bake_asset

    given = {"report_samples": report_samples, "hybrid_tol": hybrid_tol, "hybrid_angle": hybrid_angle,
             "tolerance_deg": tolerance_deg}  # unset: default
    config = BakeAssetConfig(coarse=coarse, maps=maps_spec, size=size, texture=texture, normal_space=normal_space,
                             directx=directx, bits=int(bits), exr=exr, supersample=supersample, padding=padding,
                             delta=delta, baseline=baseline, cage=cage, truth=truth, hybrid=hybrid, force=force,
                             adaptive=adaptive == "on", precision=precision,
                             cache_texels={"auto": None, "cache": True, "stream": False}[texels_mode],
                             **{k: v for k, v in given.items() if v is not None})
    bake_asset(mesh, sdf_path, out, config, texture_model=tex_path, log=click.echo)
