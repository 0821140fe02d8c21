"""`neural-bake compare OUT_A OUT_B [...] -o REPORT/`: one offline page comparing bakes side by side (thin verb)."""

from __future__ import annotations

import click

from .options import output_option, say, verbosity_options

__all__ = ["command"]


@click.command(epilog="""\b
Examples:
  neural-bake compare baked-quick/ baked-high/ -o compare/
  neural-bake compare demo/ demo/classical/ --name neural --name classical -o demo-compare/""")
@click.argument("folders", nargs=-1, required=True, metavar="OUT_A OUT_B [...]")
@output_option("Folder of the comparison page (index.html and the files it uses).", folder=True)
@click.option("--name", "names", multiple=True,
              help="Name of each bake on the page, in the order of the folders (default: the folders' names).")
@click.option("--views", type=int, default=8, show_default=True, help="Turntable views.")
@click.option("--size", type=int, default=256, show_default=True, help="Side of each render and viewer, pixels.")
@verbosity_options
def command(folders: tuple[str, ...], output: str, names: tuple[str, ...], views: int, size: int) -> None:
    """Compare two or more bakes of one asset on one page: same camera, lights and turntable, their figures
    (normal and colour error, sizes, times by stage, fits), error against time, and linked 3-D viewers.

    Each OUT is a bake's output folder (asset.glb and report.json). The page opens offline.
    """
    from neural_bake.view.comparison import CompareConfig, write_comparison

    write_comparison(folders, output, CompareConfig(views=views, size=size), names=list(names) or None, log=say)
