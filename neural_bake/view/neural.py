"""The neural preview in the reports: the fitted fields sphere-traced by :mod:`neural_bake.render` with the
same camera, lights, material and background as the mesh renders, returned as a :class:`MeshRender`."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from ..render.camera import Camera
from .raycast import DEFAULT_BACKGROUND, MeshRender

__all__ = ["neural_renderer", "neural_renderer_from_report"]


def neural_renderer(asset, *, background=DEFAULT_BACKGROUND) -> Callable[[Camera], MeshRender]:
    """A function camera → :class:`MeshRender` drawing ``asset`` (a :class:`~neural_bake.render.RenderAsset`)
    with neural normal mapping (GEMM normals of f), its texture field when it has one, Blinn-Phong under
    the camera's default key light and the default material: what :func:`render_mesh` does for meshes."""
    from ..render import Scene, render

    effects = ("shading", "normal_mapping") + (("texture",) if asset.texture is not None else ())
    scene = Scene(background=tuple(float(c) for c in background), effects=effects,
                  channels=("color", "depth", "normal", "hit"))

    def draw(camera: Camera) -> MeshRender:
        res = render(asset, scene, camera=camera)
        return MeshRender(np.asarray(res["color"], dtype=np.float32), np.asarray(res["hit"], dtype=bool),
                          np.asarray(res["normal"], dtype=np.float32), np.asarray(res["depth"], dtype=np.float32))

    return draw


def _model_file(folder: Path, name) -> Path | None:
    if not name:
        return None
    for cand in (Path(name), folder / Path(name).name):
        if cand.is_file():
            return cand
    return None


def neural_renderer_from_report(folder, report: dict) -> tuple[Callable[[Camera], MeshRender] | None, str]:
    """(renderer of the SDF and texture models a bake's report names, "") or (None, why not, one line)."""
    from ..render import load_asset

    folder = Path(folder)
    sdf = _model_file(folder, report.get("sdf"))
    if sdf is None:
        return None, ("report.json names no SDF model" if not report.get("sdf")
                      else f"SDF model {report.get('sdf')} not found")
    tex = _model_file(folder, report.get("texture_model"))
    try:
        asset = load_asset(sdf, texture=tex)
    except Exception as exc:  # noqa: BLE001 - the report still shows the meshes
        return None, f"SDF model {sdf} not renderable: {exc}"
    return neural_renderer(asset), ""
