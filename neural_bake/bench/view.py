"""Benchmark of the visual checks: our mesh renderer against the analytic render of a sample, beside the
viewer a user would otherwise open (model-viewer in headless Chromium) and the bare coarse mesh.

Accuracy: interior PSNR and fine-detail correlation against the analytic render of the bumpy sphere (its
exact normals and colours at the fine mesh's hits), silhouette IoU; time per view. The bake is analytic
(:func:`~neural_bake.view.analytic.analytic_bake`), so the figures measure the renderers, not a fit.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from .common import load_note, machine_info

__all__ = ["run", "COLUMNS"]

COLUMNS = ["method", "views", "size", "seconds_per_view", "interior_psnr_db", "detail_corr", "silhouette_iou"]


def _score(ref, rgb, mask) -> dict:
    from ..view.compare import detail_correlation, image_metrics, silhouette_iou

    from scipy.ndimage import binary_erosion

    inner = binary_erosion(ref.mask & mask, iterations=3)
    return {"interior_psnr_db": image_metrics(ref.rgb, rgb, ref.mask, mask, region="interior")["psnr_db"],
            "detail_corr": detail_correlation(ref.rgb, rgb, inner), "silhouette_iou": silhouette_iou(ref.mask, mask)}


def _mean(rows: list[dict]) -> dict:
    return {k: float(np.mean([r[k] for r in rows if r[k] is not None])) for k in rows[0]}


def run(quick: bool = False, *, views: int | None = None, size: int | None = None) -> dict:
    from ..io.images import read_image
    from ..view.analytic import analytic_bake
    from ..view.browser import browser_missing, screenshot_viewer
    from ..view.meshes import view_mesh_from_glb, view_mesh_from_mesh
    from ..view.raycast import render_mesh
    from ..view.report import ReportConfig, write_asset_report
    from ..view.turntable import turntable_cameras, view_camera

    views = views or (2 if quick else 8)
    size = size or (160 if quick else 320)
    notes = []
    with tempfile.TemporaryDirectory(prefix="neural_bake_bench_view_") as d:
        folder = Path(d)
        bake = analytic_bake(folder, faces=1500, size=128 if quick else 512)
        src = view_mesh_from_mesh(bake.fine, "source")
        baked = view_mesh_from_glb(bake.glb)
        cams = turntable_cameras(view_camera(src, width=size, height=size), views)
        refs = [render_mesh(src, c, normals_fn=bake.sample.normal, albedo_fn=bake.sample.albedo) for c in cams]
        render_mesh(baked, cams[0])  # warm-up: open3d's first scene, imports
        rows = []
        for label, mesh in (("ours: coarse mesh + baked maps", baked), ("coarse mesh without maps", baked.without_maps()),
                            ("ours: source mesh, own normals", src)):
            t0 = time.perf_counter()
            outs = [render_mesh(mesh, c) for c in cams]
            per_view = (time.perf_counter() - t0) / views
            scores = [_score(r, o.rgb, o.mask) for r, o in zip(refs, outs)]
            rows.append({"method": label, "views": views, "size": size, "seconds_per_view": per_view, **_mean(scores)})
        why = browser_missing()
        if why:
            notes.append(f"model-viewer row skipped: {why}")
        else:
            import json

            (folder / "report.json").write_text(json.dumps({}))
            index = write_asset_report(folder, ReportConfig(views=1, size=size), log=lambda m: None)
            shot = folder / "shot.png"
            info = screenshot_viewer(index, shot)
            img = read_image(shot, colour="srgb")[..., :3]  # the page's sRGB pixels, decoded to linear
            bg = read_image(index.parent / "views" / "baked_0.png", colour="srgb")[0, 0, :3]
            drawn = np.abs(img - bg).max(axis=2) > 0.01
            rows.append({"method": "model-viewer in headless Chromium (first view)", "views": 1, "size": size,
                         "seconds_per_view": info["seconds_to_load"], **_score(refs[0], img, drawn)})
            notes.append("model-viewer's time is page load to the model visible (SwiftShader WebGL on the CPU); its "
                         "shading is PBR under a sun HDR, so its PSNR measures agreement, not error")
    notes.append(load_note())
    return {"name": "view", "title": "visual checks: mesh renderer against the analytic render (bumpy sphere)",
            "machine": machine_info(), "quick": quick, "rows": rows, "notes": notes}
