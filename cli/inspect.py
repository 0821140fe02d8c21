"""`neural-bake inspect MESH`: what a mesh file holds and what is wrong with it."""

from __future__ import annotations

import json

import click


@click.command(epilog="""\b
Example:
  neural-bake inspect samples/bumpy_sphere.obj
  neural-bake inspect scan.ply --texture scan.png --json""")
@click.argument("mesh", metavar="MESH")
@click.option("--texture", "texture", metavar="IMG", default=None,
              help="Base-colour image for a mesh whose file names none (PNG, JPEG, EXR, TIFF).")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
def command(mesh: str, texture: str | None, as_json: bool) -> None:
    """Report a mesh: counts, UVs, texture, watertightness, genus, winding, bounding box, warnings.

    MESH is an OBJ (+MTL), PLY, GLB or glTF file.
    """
    from neural_bake.io.inspect import format_report, inspect_mesh

    report = inspect_mesh(mesh, texture)
    click.echo(json.dumps(report, indent=2) if as_json else format_report(report))
