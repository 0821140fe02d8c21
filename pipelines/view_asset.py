"""Look at a bake: the HTML report of an output folder (opened in the browser), or headless turntable frames.

The job behind `neural-bake view`. Only library calls: :func:`neural_bake.view.report.write_asset_report`
and the turntable renderer.
"""

from __future__ import annotations

import contextlib
import shutil
import webbrowser
from pathlib import Path
from typing import Callable

__all__ = ["view_path"]


def _resolve(path) -> tuple[Path | None, Path]:
    """(bake folder or None, GLB) of a folder or GLB path; ViewError for anything else."""
    from neural_bake.view.meshes import ViewError

    p = Path(path)
    if p.is_dir():
        if not (p / "asset.glb").is_file():
            raise ViewError(f"{p}: no asset.glb in this folder (expected a bake's output folder or a GLB file)")
        return p, p / "asset.glb"
    if not p.exists():
        raise ViewError(f"{p}: no such file or folder")
    if p.suffix.lower() != ".glb":
        raise ViewError(f"{p}: expected a bake's output folder or a .glb file")
    if p.name == "asset.glb" and (p.parent / "report.json").is_file():
        return p.parent, p
    return None, p


def view_path(path, *, headless: bool = False, out=None, views: int = 8, size: int = 320, open_browser: bool = True,
              log: Callable[[str], None] = print) -> Path:
    """Report on ``path`` (a bake folder or a GLB) and open it, or with ``headless`` write its turntable.

    Returns the report's index.html, or (headless) the GIF. A GLB outside a bake folder gets a folder of its
    own beside it, ``STEM-view/``, holding a copy of it and the report.
    """
    from neural_bake.constants import MAX_VIEW_SIDE, MAX_VIEWS
    from neural_bake.io.outdir import OutputLock, record_in_set
    from neural_bake.limits import check_count
    from neural_bake.view.meshes import load_view_mesh
    from neural_bake.view.report import ReportConfig, write_asset_report
    from neural_bake.view.turntable import write_turntable

    views = check_count(views, "views", MAX_VIEWS)  # before anything is rendered or allocated
    size = check_count(size, "size", MAX_VIEW_SIDE, minimum=16)
    folder, glb = _resolve(path)
    if headless:
        target = Path(out) if out else ((folder / "turntable") if folder else glb.parent / f"{glb.stem}-turntable")
        mesh = load_view_mesh(glb)
        inside = folder is not None and target.absolute().parent == folder.absolute()
        # writing into a bake folder: hold its lock, so a bake into it cannot swap the folder meanwhile
        with OutputLock(folder) if inside else contextlib.nullcontext():
            gif = write_turntable(mesh, target, views=views, size=size)
            if inside:
                record_in_set(folder, target.name, locked=True)  # part of the bake's set from now on
        log(f"wrote {views} frames and {gif}")
        return gif
    if folder is None:
        folder = glb.parent / f"{glb.stem}-view"
        folder.mkdir(exist_ok=True)
        shutil.copy2(glb, folder / "asset.glb")
    with OutputLock(folder):  # one writer: a bake into the folder waits for the report, or the report fails
        index = write_asset_report(folder, ReportConfig(views=views, size=size), log=log)
        record_in_set(folder, index.relative_to(folder).parts[0], locked=True)  # the report joins the bake's set
    if open_browser:
        opened = webbrowser.open(index.resolve().as_uri())
        if not opened:
            log(f"no browser found: open {index} yourself")
    return index
