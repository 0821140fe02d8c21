"""`neural-bake bake [MESH] --sdf MODEL -o OUT`: bake neural normals (and colours) onto a coarse mesh (thin verb).

Parses the options and calls :func:`neural_bake.pipelines.bake_asset.bake_asset`, which writes OUT/asset.glb
(and with --formats asset.usd, asset.usdz), the loose maps, OUT/report.json and the error maps atomically
(a failed run leaves OUT as it was).
"""

from __future__ import annotations

import click

from neural_bake.constants import ADAPTIVE_TOLERANCE_DEG

from .config_options import ConfigCommand, ConfigSpec
from .options import output_option, say, verbosity_options

__all__ = ["command"]


def _config_class():
    from neural_bake.pipelines.bake_asset import BakeAssetConfig

    return BakeAssetConfig


def _resolve(preset, values):
    from neural_bake.pipelines.bake_asset import bake_config

    return bake_config(preset, **values)


SPEC = ConfigSpec(load=_config_class, resolve=_resolve, presets=("quick", "default", "high"),
                  costs={"quick": "1000 faces, 512² maps: about 6 s",
                         "default": "2000 faces, 2048² maps: about 20 s",
                         "high": "5000 faces, 4096² maps, 2×2 samples: about 10 min"},
                  preset_help="Coarse mesh and maps (none: the defaults below)", required=("sdf_path", "output"))

_TEXELS = {"auto": None, "cache": True, "stream": False}


@click.command(cls=ConfigCommand, config=SPEC, epilog="""\b
Examples:
  neural-bake bake samples/bumpy_sphere.obj --sdf bumpy.sdf -o baked/ --preset quick
  neural-bake bake mesh.obj --sdf mesh.nested --texture-model mesh.tex --coarse decimate:2000 --size 1024 -o out/
  neural-bake bake --sdf model.sdf --coarse march:128 -o out/ --formats glb,usd,usdz
  neural-bake bake --preset high --print-config > bake.toml""")
@click.argument("mesh", metavar="MESH", type=click.Path(dir_okay=False), required=False)
@click.option("--sdf", "sdf_path", metavar="MODEL", default=None, help="Fine SDF model file (kind 'sdf').")
@click.option("--texture-model", "tex_path", metavar="MODEL", default=None,
              help="Texture model file (kind 'texture'): bakes the albedo map.")
@output_option("Output folder.", folder=True, required=False)
@click.option("--adaptive", "config__adaptive", type=click.Choice(["on", "off"]), default=None,
              help="on: evaluate the fields on a coarse lattice per chart, refined where interpolation would exceed "
                   "--tolerance; off: evaluate every texel [default: on].")
@click.option("--tolerance", "config__tolerance_deg", type=float, default=None, metavar="DEG",
              help="Adaptive bake: tolerance (degrees) of the interpolation test; the report states the measured "
                   f"angle to a full evaluation [default: {ADAPTIVE_TOLERANCE_DEG:g}].")
@click.option("--texels", "texels_mode", type=click.Choice(list(_TEXELS)), default=None, hidden=True,
              help="Older spelling of --cache-texels: cache (yes), stream (no), auto (none).")
@verbosity_options
def command(mesh, sdf_path, tex_path, output, config, texels_mode):
    """Bake the neural normals (and colours) of MESH's fitted fields onto a coarse mesh; write a GLB (and
    USD/USDZ with --formats), maps and a quality report into OUTPUT. Without MESH the coarse mesh is the
    model marched (--coarse march:RES or level:I:RES; a decimate spec becomes march:128) and the map is
    measured against ∇f, with no classical baseline.

    Every setting below is a field of the bake's config: a --config file sets them first, the options
    given override it."""
    from dataclasses import replace

    from neural_bake.pipelines.bake_asset import bake_asset

    if texels_mode is not None:
        config = replace(config, cache_texels=_TEXELS[texels_mode])
    say(f"settings: {config}", 1)
    bake_asset(mesh, sdf_path, output, config, texture_model=tex_path, log=say)
