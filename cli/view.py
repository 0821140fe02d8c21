"""`neural-bake view PATH`: look at a bake: an HTML report in the browser, or turntable frames and a GIF."""

from __future__ import annotations

import click

from .options import output_option, say, verbosity_options


@click.command(epilog="""\b
Examples:
  neural-bake view baked/
  neural-bake view baked/asset.glb --headless -o turntable/ --views 12""")
@click.argument("path", metavar="PATH")
@click.option("--headless", is_flag=True,
              help="Write the turntable frames and a GIF (no browser); see --output.")
@output_option("Folder of the --headless frames (default PATH/turntable, or beside a GLB).", folder=True,
               required=False, old_spelling=True)
@click.option("--views", type=int, default=8, show_default=True, help="Turntable views.")
@click.option("--size", type=int, default=320, show_default=True, help="Side of each render, pixels.")
@click.option("--no-open", "no_open", is_flag=True, help="Write the report but do not open a browser.")
@verbosity_options
def command(path: str, headless: bool, output: str | None, views: int, size: int, no_open: bool) -> None:
    """Check a bake by eye. PATH is a bake's output folder (with asset.glb) or a GLB file.

    Writes PATH/report/index.html (an interactive glTF viewer of the baked asset beside its source,
    turntables, difference images, error heat maps, metrics, timings) and opens it in the browser.
    With --headless, renders the turntable of the GLB instead: frame_NNN.png and turntable.gif.
    """
    from neural_bake.pipelines.view_asset import view_path

    view_path(path, headless=headless, out=output, views=views, size=size, open_browser=not no_open, log=say)
