"""`neural-bake bench bake`: texel throughput, and error against time beside the mesh-to-mesh baseline."""

from __future__ import annotations

import click

from .bench import bench_options, report


@click.command("bake")
@bench_options
@click.option("--sdf-model", type=click.Path(dir_okay=False), default=None,
              help="A trained SDF model of the bumpy sphere sample: adds error rows with its ∇f.")
@click.option("--anchor-model", type=click.Path(dir_okay=False), default=None,
              help="A (256,3) SDF model of the anchor mesh (Spot when the reference data is there, else the bumpy "
                   "sphere) for the 'against the anchor' table; default a randomly initialised one.")
@click.option("--anchor-mesh", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Another mesh as the anchor (e.g. one of the data folder), with its SDF as --anchor-model: the "
                   "anchor and user's command tables on that asset.")
@click.option("--anchor-size", "anchor_sizes", type=click.IntRange(min=16), multiple=True,
              help="A map size of the anchor and user's command tables, repeatable (default 2048 and 4096; "
                   "--quick 256 and 512).")
@click.option("--no-anchor", is_flag=True, help="Skip the 'against the anchor' table.")
@click.option("--blender-python", type=click.Path(dir_okay=False), default=None,
              help="The Python interpreter with bpy for the Blender rows (default $NEURAL_BAKE_BLENDER_PYTHON, else "
                   ".cache/blender-venv/bin/python, which `make setup-blender` makes).")
@click.option("--repeats", type=click.IntRange(min=1), default=None,
              help="Rounds of the user's command table, our command and Blender's script in turn; each figure the "
                   "best of its rounds (default 3; --quick 1).")
def command(quick: bool, json_path: str | None, sdf_model: str | None, anchor_model: str | None,
            anchor_mesh: str | None, anchor_sizes: tuple[int, ...], no_anchor: bool, blender_python: str | None,
            repeats: int | None) -> None:
    """Texels per second of tangent-space normal maps from a (256, 3) SIREN (GEMM vs autograd normals), and
    the error of baked normals against time as map size and coarse face count vary on the bumpy sphere,
    beside the classical mesh-to-mesh bake; and our bake (full or adaptive, float32 or auto precision) of 2048²
    and 4096² maps (quick: 256², 512²) against the open3d baseline and Blender's Cycles bake (run in its own
    process when its interpreter is set up: `make setup-blender`), every map scored by the same decoder."""
    from neural_bake.bench.bake import run

    report(run(quick=quick, sdf_model=sdf_model, anchor=not no_anchor, anchor_model=anchor_model,
               anchor_mesh=anchor_mesh, anchor_sizes=list(anchor_sizes) or None, blender_python=blender_python,
               repeats=repeats), json_path)
