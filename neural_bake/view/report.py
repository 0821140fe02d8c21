"""An HTML report of one bake folder: viewer, turntables, difference images, error heat maps, metrics, timings.

:func:`write_asset_report` reads a bake's output folder (``asset.glb``, ``report.json``, the maps and error
maps, the model files it names) and writes ``FOLDER/report/`` with ``index.html`` and every file it uses
beside it (no network): the model-viewer script, ``models.js`` (the baked and the source GLB and the sun HDR
as data URIs), the renders, GIFs and plots, and ``view.json`` (the figures, for batch indexes and tests).
The folder is built in a staging folder and swapped in whole: a reader sees the old report or the new one.

Renders of one view (same camera, lights, material; :mod:`neural_bake.view.raycast`):
source mesh with its own normals and texture, coarse mesh with the baked maps, coarse mesh without maps,
and the neural preview of the fitted fields (:mod:`neural_bake.render`, the model files the bake's
report.json names). Differences are measured against the source, and between the bake and the preview.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..io.images import read_image, write_image
from ..render.camera import Camera
from ..render.shading import Material
from .compare import difference_image, image_metrics, silhouette_iou
from .meshes import ViewError, ViewMesh, view_mesh_from_glb, view_mesh_from_mesh
from .html import esc as _esc
from .html import fmt as _fmt
from .raycast import DEFAULT_BACKGROUND, MeshRender, render_mesh
from .stages import StageNode, stage_bar_svg, stage_tree
from .turntable import to_srgb8, turntable_cameras, view_camera, write_gif

__all__ = ["ReportConfig", "write_asset_report", "REPORT_DIR", "source_of", "fit_histories"]

#: The report's folder inside a bake's output folder.
REPORT_DIR = "report"
_UV_MAPS = (("error_normal.png", "normal error (angle to the truth; white ≥ the scale in report.json)"),
            ("error_baseline.png", "classical mesh-to-mesh bake's normal error, same scale"),
            ("miss.png", "texels off the nesting band (white)"),
            ("hybrid.png", "texels that took the classical normal (white)"),
            ("hybrid_color.png", "texels that took the source texture's colour (white)"),
            ("normal.png", "baked tangent-space normal map (+Y green up)"),
            ("albedo.png", "baked albedo"))


@dataclass
class ReportConfig:
    """Settings of :func:`write_asset_report`; one line per field."""

    views: int = 8
    """Turntable views (equal steps about +Y)."""
    size: int = 320
    """Side of each render, pixels."""
    model_viewer: str | None = None
    """model-viewer UMD script to copy beside the report; None: find it (see :func:`find_model_viewer`)."""


def source_of(folder: Path, report: dict) -> tuple[Path | None, str]:
    """The source mesh a bake names in its report (as given, else beside the folder), or (None, why not)."""
    name = report.get("mesh")
    if not name:
        return None, "report.json names no source mesh"
    p = Path(name)
    for cand in (p, folder / p.name, folder.parent / p.name):
        if cand.is_file():
            return cand, ""
    return None, f"source mesh {name} not found"


def _model_path(folder: Path, name) -> Path | None:
    for cand in (folder / Path(name).name, Path(name)):  # beside the bake first: the files it was made with
        if cand.is_file():
            return cand
    return None


def fit_histories(folder: Path, report: dict) -> dict[str, list[dict]]:
    """Every fit's loss history the model files named by a bake's report record, ``{label: rows}`` (rows:
    step, seconds, losses): the SDF fit, each nested level's distillation and the fine fit a nested file
    keeps, the texture fit. Files that are missing or unreadable give no curve."""
    from ..fields import fit_records

    out: dict[str, list[dict]] = {}
    for key, label in (("sdf", "SDF fit"), ("texture_model", "texture fit")):
        name = report.get(key)
        path = _model_path(folder, name) if name else None
        if path is None:
            continue
        try:
            records = fit_records(path)
        except Exception:  # noqa: BLE001 - a report without a plot beats no report
            continue
        for r in records:
            hist = list(r["training"].get("history") or [])
            if not hist:
                continue
            if r["fit"] == "fine":
                out["SDF fit (fine level f)"] = hist
            elif r["fit"] == "level":
                out[f"nested level {r['level']} ({r['width']}x{r['depth']})"] = hist
            else:
                out[label] = hist
    return out


def _plot_fits(histories: dict[str, list[dict]], path: Path) -> bool:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not histories:
        return False
    cols = min(3, len(histories))
    nrows = -(-len(histories) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 3.4 * nrows), squeeze=False)
    for ax in axes.flat[len(histories):]:
        ax.set_visible(False)
    for ax, (label, hist) in zip(axes.flat, histories.items()):
        keys = [k for k in hist[0] if k not in ("step", "seconds", "lr") and isinstance(hist[0][k], (int, float))]
        t = [h.get("seconds", 0.0) for h in hist]
        for k in keys:
            y = [h.get(k) for h in hist]
            if all(isinstance(v, (int, float)) and v > 0 for v in y):
                ax.plot(t, y, label=k)
        ax.set_yscale("log")
        ax.set_xlabel("seconds")
        ax.set_ylabel("loss (log)")
        ax.set_title(f"{label}: loss against time", fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def _source_glb(mesh, path: Path) -> Path:
    from ..bake.export import export_glb
    from ..mesh.unwrap import split_uv_seams

    if mesh.uv is not None and mesh.texture is not None:
        split = split_uv_seams(mesh)[0]
        tex = mesh.texture if mesh.texture.shape[2] in (3, 4) else np.repeat(mesh.texture[..., :1], 3, axis=2)
        return export_glb(path, split, albedo=tex, name="source")
    return export_glb(path, mesh, name="source")


def _heat_render(baked: ViewMesh, heat: np.ndarray, camera: Camera) -> np.ndarray:
    """The baked mesh wearing an error map (display values) as its colour, unlit: the errors over the model."""
    from dataclasses import replace

    painted = replace(baked, texture=heat[..., :3] if heat.shape[2] >= 3 else np.repeat(heat, 3, axis=2),
                      normal_map=None)
    out = render_mesh(painted, camera, lights=[], material=Material(ambient=1.0, specular=0.0),
                      background=(0.2, 0.2, 0.2))
    return out.rgb


def write_asset_report(folder, config: ReportConfig | None = None, *,
                       neural: Callable[[Camera], MeshRender] | str | None = "auto", neural_note: str = "",
                       log: Callable[[str], None] = print, name=None) -> Path:
    """Write ``folder/report/index.html`` for the bake in ``folder``; return the path of index.html.

    - ``name``: the folder as the report names it (title, heading, view.json), when ``folder`` is a staging
      folder that becomes it; default ``folder``.

    - ``neural``: a renderer camera → :class:`MeshRender` of the fitted fields (the neural preview);
      "auto": the SDF and texture models report.json names (:func:`neural_renderer_from_report`), when
      found; None: no preview. Without one the slot says why (``neural_note``, or what "auto" found).
    Raises :class:`ViewError` for a folder without ``asset.glb``.
    """
    from ..io.atomic import atomic_write_text
    from ..io.mesh_io import load_mesh
    from .environment import sun_environment, write_hdr
    from .viewer import MODEL_VIEWER_SCRIPT, find_model_viewer, model_viewer_attributes, models_js

    cfg = config or ReportConfig()
    folder = Path(folder)
    glb = folder / "asset.glb"
    if not folder.is_dir():
        raise ViewError(f"{folder}: no such output folder")
    if not glb.is_file():
        raise ViewError(f"{folder}: no asset.glb (not a bake output folder)")
    report_path = folder / "report.json"
    report = json.loads(report_path.read_text()) if report_path.is_file() else {}
    if isinstance(neural, str):
        if neural != "auto":
            raise ViewError(f"neural preview {neural!r}: expected a renderer, 'auto' or None")
        from .neural import neural_renderer_from_report

        neural, found_note = neural_renderer_from_report(folder, report)
        neural_note = neural_note or found_note
    shown = Path(name) if name is not None else folder
    try:
        stage = Path(tempfile.mkdtemp(prefix=".report-", dir=folder))
    except OSError as exc:  # a write-protected folder, say: name it, not the staging folder
        raise OSError(exc.errno, exc.strerror, str(shown)) from None
    try:
        (stage / "views").mkdir()
        baked = view_mesh_from_glb(glb)
        src_path, src_note = source_of(folder, report)
        source_mesh = source = None
        if src_path is not None:
            try:
                source_mesh = load_mesh(src_path)
                source = view_mesh_from_mesh(source_mesh, "source")
            except Exception as exc:  # noqa: BLE001 - the report still shows the bake
                src_note = f"source mesh {src_path} unreadable: {exc}"
        bare = baked.without_maps()
        camera = view_camera(source or baked, width=cfg.size, height=cfg.size)
        cams = turntable_cameras(camera, cfg.views)
        log(f"report: rendering {len(cams)} views of {cfg.size}² (source, baked, no maps"
            f"{', neural' if neural else ''})")
        pairs = {"baked_vs_source": [], "bare_vs_source": [], "neural_vs_source": [], "baked_vs_neural": []}
        gif_frames = []
        for k, cam in enumerate(cams):
            r_baked = render_mesh(baked, cam)
            r_bare = render_mesh(bare, cam)
            r_src = render_mesh(source, cam) if source is not None else None
            r_neu = None
            if neural is not None:
                try:
                    r_neu = neural(cam)
                except Exception as exc:  # noqa: BLE001 - a preview that cannot draw leaves its slot, not the report
                    if k > 0:
                        raise
                    neural, neural_note = None, f"the preview renderer failed: {' '.join(str(exc).split())}"
            panels = []
            for name, r in (("source", r_src), ("baked", r_baked), ("bare", r_bare), ("neural", r_neu)):
                if r is not None:
                    write_image(stage / "views" / f"{name}_{k}.png", r.rgb, colour="srgb")
                    panels.append(to_srgb8(r.rgb))
            for key, a, b in (("baked_vs_source", r_baked, r_src), ("bare_vs_source", r_bare, r_src),
                              ("neural_vs_source", r_neu, r_src), ("baked_vs_neural", r_baked, r_neu)):
                if a is None or b is None:
                    continue
                m = {"union": image_metrics(b.rgb, a.rgb, b.mask, a.mask),
                     "interior": image_metrics(b.rgb, a.rgb, b.mask, a.mask, region="interior"),
                     "silhouette_iou": silhouette_iou(a.mask, b.mask)}
                pairs[key].append(m)
                diff = difference_image(b.rgb, a.rgb)
                write_image(stage / "views" / f"diff_{key}_{k}.png", diff, colour="data")
                if key == "baked_vs_source":
                    panels.append(np.round(diff * 255).astype(np.uint8))
            gif_frames.append(np.concatenate(panels, axis=1))
        write_gif(stage / "turntable.gif", gif_frames)
        metrics = {k: _mean_metrics(v) for k, v in pairs.items() if v}

        # error maps over the UV layout (copied) and over the model (the coarse mesh wearing them)
        uv_maps = []
        for name, caption in _UV_MAPS:
            if (folder / name).is_file():
                shutil.copy2(folder / name, stage / name)
                uv_maps.append((name, caption))
        turns = (0, len(cams) // 2) if len(cams) > 1 else (0,)
        heat_views = []
        if (folder / "error_normal.png").is_file() and baked.uv is not None:
            heat = read_image(folder / "error_normal.png", colour="data")
            for k in turns:
                write_image(stage / f"heat_model_{k}.png", _heat_render(baked, heat, cams[k]), colour="data")
                heat_views.append((f"heat_model_{k}.png", f"normal error on the coarse mesh, {_turn(k, len(cams))}"))
        colour, colour_note = _colour_section(baked, source_mesh, stage, cams, turns)

        has_fit_plot = _plot_fits(fit_histories(folder, report), stage / "fits.png")
        stages = stage_tree(report.get("seconds") or {}, report.get("seconds_total"))

        # the interactive viewer
        mv_path, mv_note = (Path(cfg.model_viewer), "") if cfg.model_viewer else find_model_viewer()
        if mv_path is not None and not mv_path.is_file():
            mv_path, mv_note = None, f"model-viewer script {mv_path}: no such file"
        models = {"baked": glb}
        if source_mesh is not None:
            models["source"] = _source_glb(source_mesh, stage / "source.glb")
        shutil.copy2(glb, stage / "asset.glb")
        from ..render.shading import default_lights

        sun = -np.asarray(default_lights(camera)[0].direction)
        write_hdr(stage / "sun.hdr", sun_environment(sun))
        if mv_path is not None:
            shutil.copy2(mv_path, stage / MODEL_VIEWER_SCRIPT)
            atomic_write_text(stage / "models.js", models_js(models, stage / "sun.hdr"))
        summary = {"folder": str(shown), "views": len(cams), "size": cfg.size, "camera": camera.to_dict(),
                   "metrics": metrics, "source": str(src_path) if src_path else None, "source_note": src_note,
                   "neural": neural is not None, "neural_note": neural_note,
                   "model_viewer": mv_path is not None, "model_viewer_note": mv_note,
                   "viewer_attributes": model_viewer_attributes(camera),
                   "background": list(DEFAULT_BACKGROUND),
                   "colour_error": colour, "colour_note": colour_note}
        atomic_write_text(stage / "view.json", json.dumps(summary, indent=2, default=str))
        page = _html(shown, report, summary, uv_maps, heat_views, has_fit_plot, stages, sorted(models),
                     {p.name for p in (stage / "views").iterdir()})
        atomic_write_text(stage / "index.html", page)
        final = folder / REPORT_DIR
        old = None
        if final.exists():
            old = Path(tempfile.mkdtemp(prefix=".report-old-", dir=folder))
            final.replace(old / "report")
        stage.replace(final)
        stage = None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if stage is not None:
            shutil.rmtree(stage, ignore_errors=True)
    log(f"report: {final / 'index.html'}")
    return final / "index.html"


def _turn(k: int, views: int) -> str:
    """How a turntable view is named in captions."""
    return "first view" if k == 0 else f"view {k + 1} of {views} (turned {360 * k // views}°)"


def _colour_section(baked: ViewMesh, source_mesh, stage: Path, cams: list[Camera], turns) -> tuple[dict | None, str]:
    """Write the source texture read through the bake's UV layout, the colour error map over the UVs and
    over the model into ``stage``; return (the error's figures and file names, or None; why not)."""
    from .colour import COLOUR_ERROR_SCALE, colour_heat, compare_colours

    if baked.texture is None:
        return None, "the bake has no albedo map"
    if source_mesh is None or source_mesh.texture is None or source_mesh.uv is None:
        return None, "the source mesh has no texture (or was not found)"
    cmp = compare_colours(baked, source_mesh)
    write_image(stage / "colour_source.png", cmp.source, colour="srgb")
    write_image(stage / "colour_baked.png", cmp.baked, colour="srgb")
    heat = colour_heat(cmp.error, cmp.coverage)
    write_image(stage / "error_colour.png", heat, colour="data")
    models = []
    for k in turns:
        write_image(stage / f"heat_colour_{k}.png", _heat_render(baked, heat, cams[k]), colour="data")
        models.append((f"heat_colour_{k}.png", f"colour error on the coarse mesh, {_turn(k, len(cams))}"))
    return {**cmp.stats, "scale_levels": COLOUR_ERROR_SCALE, "models": models}, ""


def _mean_metrics(rows: list[dict]) -> dict:
    """Per region: the MSE averaged over views and the PSNR of that mean; the mean silhouette IoU."""
    out = {}
    for region in ("union", "interior"):
        mses = [r[region]["mse"] for r in rows if r[region]["mse"] is not None]
        mse = float(np.mean(mses)) if mses else None
        psnr = None if mse is None else (float("inf") if mse == 0 else float(10 * np.log10(1.0 / mse)))
        out[region] = {"mse": mse, "psnr_db": psnr}
    ious = [r["silhouette_iou"] for r in rows if r["silhouette_iou"] is not None]
    out["silhouette_iou"] = float(np.mean(ious)) if ious else None
    out["views"] = len(rows)
    return out


_CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222;max-width:1400px}
h1{font-size:1.4em} h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:0.9em} td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#f3f3f3} td:first-child,th:first-child{text-align:left}
.row{display:flex;flex-wrap:wrap;gap:10px} figure{margin:0} figcaption{font-size:0.8em;color:#555;max-width:340px}
img.map{width:256px;height:256px;image-rendering:pixelated;border:1px solid #ccc}
model-viewer{display:block;background:#e7e7e7}
.note{background:#fff6d5;border:1px solid #e6d58a;padding:6px 10px;display:inline-block}
"""


def _html(folder: Path, report: dict, s: dict, uv_maps, heat_views, fit_plot: bool, stages: StageNode,
          models: list[str], views: set[str]) -> str:
    from .viewer import MODEL_VIEWER_SCRIPT

    attrs = " ".join(f'{k}="{_esc(v)}"' for k, v in s["viewer_attributes"].items())
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>neural-bake report: {_esc(folder.name)}</title>",
             f"<style>{_CSS}</style>"]
    if s["model_viewer"]:
        parts.append(f"<script src='{MODEL_VIEWER_SCRIPT}'></script><script src='models.js'></script>")
    parts.append("</head><body>")
    parts.append(f"<h1>Bake report: {_esc(folder.absolute())}</h1>")
    # viewer
    parts.append("<h2>Interactive viewer</h2>")
    if s["model_viewer"]:
        toggle = "".join(f"<button onclick=\"show('{m}')\">{_esc(m)}</button> " for m in models)
        parts.append(f"<div>{toggle}<span id='which'></span></div>"
                     f"<model-viewer id='viewer' camera-controls interaction-prompt='none' tone-mapping='neutral' "
                     f"shadow-intensity='0' exposure='1' style='width:{s['size']}px;height:{s['size']}px' {attrs}>"
                     "</model-viewer>"
                     "<p>Lit by one sun (a generated HDR) from where the turntables' key light comes, so normal-map "
                     "detail shows.</p>"
                     "<script>const mv=document.getElementById('viewer');"
                     "function show(m){mv.src=window.NEURAL_BAKE_MODELS[m];"
                     "document.getElementById('which').textContent=' showing: '+m;}"
                     "mv.environmentImage=window.NEURAL_BAKE_ENV;"
                     "mv.addEventListener('load',()=>{window.NEURAL_BAKE_LOADED=(window.NEURAL_BAKE_LOADED||0)+1;});"
                     "mv.addEventListener('model-visibility',(e)=>{if(e.detail.visible){window.NEURAL_BAKE_VISIBLE=true;}});"
                     "mv.addEventListener('error',(e)=>{window.NEURAL_BAKE_ERROR=String(e.detail&&e.detail.type);});"
                     "show('baked');</script>")
    else:
        parts.append(f"<p class='note'>No interactive viewer: {_esc(s['model_viewer_note'])}. The pictures below "
                     f"are rendered by neural-bake itself.</p>")
    # renders
    parts.append("<h2>Turntable</h2><p>Panels: " + ", ".join(
        p for p, ok in (("source mesh", s["source"]), ("baked maps on the coarse mesh", True),
                        ("coarse mesh without maps", True), ("neural preview", s["neural"]),
                        ("difference baked − source", s["source"])) if ok) + ".</p>")
    parts.append("<img src='turntable.gif' alt='turntable'>")
    if not s["source"]:
        parts.append(f"<p class='note'>No source render: {_esc(s['source_note'])}.</p>")
    if not s["neural"]:
        parts.append(f"<p class='note'>No neural preview: {_esc(s['neural_note'] or 'no renderer given')}.</p>")
    parts.append("<h2>One view, side by side</h2><div class='row'>")
    for name, label in (("source", "source mesh, own normals and texture"), ("baked", "coarse mesh + baked maps"),
                        ("bare", "coarse mesh, no maps"), ("neural", "neural preview"),
                        ("diff_baked_vs_source", "|baked − source|"), ("diff_bare_vs_source", "|no maps − source|"),
                        ("diff_neural_vs_source", "|neural − source|"), ("diff_baked_vs_neural", "|baked − neural|")):
        if f"{name}_0.png" in views:
            parts.append(f"<figure><img src='views/{name}_0.png'><figcaption>{_esc(label)}</figcaption></figure>")
    parts.append("</div>")
    # metrics of the renders
    parts.append("<h2>Render differences (mean over the turntable, sRGB)</h2><table><tr><th>pair</th>"
                 "<th>PSNR dB (union of masks)</th><th>PSNR dB (interior)</th><th>MSE (union)</th>"
                 "<th>silhouette IoU</th></tr>")
    for key, m in s["metrics"].items():
        parts.append(f"<tr><td>{_esc(key.replace('_', ' '))}</td><td>{_fmt(m['union']['psnr_db'])}</td>"
                     f"<td>{_fmt(m['interior']['psnr_db'])}</td><td>{_fmt(m['union']['mse'], 5)}</td>"
                     f"<td>{_fmt(m['silhouette_iou'], 4)}</td></tr>")
    parts.append("</table>")
    # bake metrics
    parts.append("<h2>Bake metrics (report.json)</h2><table><tr><th>figure</th><th>median</th><th>p95</th>"
                 "<th>max</th></tr>")
    for key, label in (("vs_truth_deg", "normal error vs truth, °"), ("vs_gradient_deg", "encoding error vs ∇f, °"),
                       ("gradient_vs_truth_deg", "∇f vs truth, °"), ("geometric_vs_truth_deg", "coarse geometry vs truth, °"),
                       ("faces_vs_truth_deg", "source face normals vs truth (its exact SDF), °")):
        st = report.get(key)
        if isinstance(st, dict):
            parts.append(f"<tr><td>{_esc(label)}</td><td>{_fmt(st.get('median'))}</td><td>{_fmt(st.get('p95'))}</td>"
                         f"<td>{_fmt(st.get('max'))}</td></tr>")
    base = (report.get("baseline") or {}).get("vs_truth_deg")
    if isinstance(base, dict):
        parts.append(f"<tr><td>classical bake vs truth, °</td><td>{_fmt(base.get('median'))}</td>"
                     f"<td>{_fmt(base.get('p95'))}</td><td>{_fmt(base.get('max'))}</td></tr>")
    control = ((report.get("bake") or {}).get("error_control") or {}).get("angle_deg")
    if isinstance(control, dict):  # adaptive / reduced-precision bake against a full float32 evaluation
        parts.append(f"<tr><td>∇f vs full float32 evaluation (sampled), °</td><td>{_fmt(control.get('median'), 4)}"
                     f"</td><td>{_fmt(control.get('p95'), 4)}</td><td>{_fmt(control.get('max'), 4)}</td></tr>")
    parts.append("</table><table style='margin-top:6px'>")
    for key, label in (("color_psnr_db", "colour PSNR, dB"), ("coverage", "UV coverage"),
                       ("miss_fraction", "texels off the band"), ("truth", "ground truth")):
        if key in report:
            parts.append(f"<tr><td>{_esc(label)}</td><td>{_fmt(report[key], 4)}</td></tr>")
    fraction = (report.get("bake") or {}).get("evaluated_fraction")
    if fraction is not None:
        parts.append(f"<tr><td>texel samples evaluated (the rest interpolated)</td><td>{_fmt(fraction, 4)}</td></tr>")
    parts.append("</table>")
    # error maps
    parts.append("<h2>Errors over the UV layout</h2><div class='row'>")
    for name, caption in uv_maps:
        parts.append(f"<figure><img class='map' src='{name}'><figcaption>{_esc(name)}: {_esc(caption)}</figcaption></figure>")
    parts.append("</div>")
    if heat_views:
        parts.append("<h2>Errors over the model</h2><div class='row'>")
        for name, caption in heat_views:
            parts.append(f"<figure><img src='{name}'><figcaption>{_esc(caption)} (white ≥ "
                         f"{_fmt(report.get('error_map_scale_deg', 10.0), 0)}°)</figcaption></figure>")
        parts.append("</div>")
    parts.append(_colour_html(s.get("colour_error"), s.get("colour_note", "")))
    # timings: nested stages inside their parent, the top row summing to the run's wall time
    parts.append("<h2>Time by stage</h2>")
    if stages.children:
        parts.append("<p>Top row: the run, stage by stage, adding up to its wall time; each row below splits "
                     "the stage above it (“other”: time outside the listed sub-stages).</p>")
        parts.append(stage_bar_svg(stages))
        parts.append("<table><tr><th>stage</th><th>seconds</th><th>share of the run</th></tr>")
        for depth, node in _walk(stages):
            parts.append(f"<tr><td style='padding-left:{8 + 18 * depth}px'>{_esc(node.name)}</td>"
                         f"<td>{_fmt(node.seconds)}</td><td>{100 * node.seconds / stages.seconds:.1f} %</td></tr>")
        parts.append(f"<tr><th>run (wall time)</th><th>{_fmt(stages.seconds)}</th><th>100 %</th></tr></table>")
    else:
        parts.append("<p class='note'>report.json records no stage times.</p>")
    parts.append("<h2>Fits: loss against time</h2>")
    parts.append("<img src='fits.png'>" if fit_plot else "<p class='note'>No fit history found (model files not "
                 "beside the bake).</p>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _walk(node: StageNode, depth: int = 0):
    for c in node.children:
        yield depth, c
        yield from _walk(c, depth + 1)


def _colour_html(colour: dict | None, note: str) -> str:
    """The colour section: source texture and baked albedo at the same surface points, the error map."""
    head = "<h2>Colour: source texture and baked albedo at the same surface points</h2>"
    if colour is None:
        return head + f"<p class='note'>No colour comparison: {_esc(note)}.</p>"
    parts = [head, "<p>Each texel of the bake's UV layout is a point of the coarse mesh; the source texture is read "
             "at its closest point on the source mesh, through the source's own UVs. Colour error: mean over R, G, "
             "B of |sRGB difference|, in 8-bit levels (white ≥ "
             f"{_fmt(colour['scale_levels'], 0)}). Median {_fmt(colour['median'])}, p95 {_fmt(colour['p95'])}, "
             f"max {_fmt(colour['max'])} levels over {colour['count']} texels.</p><div class='row'>"]
    for name, caption in (("colour_source.png", "source texture, read through the bake's UV layout"),
                          ("colour_baked.png", "baked albedo"),
                          ("error_colour.png", "colour error over the UV layout")):
        parts.append(f"<figure><img class='map' src='{name}'><figcaption>{_esc(caption)}</figcaption></figure>")
    for name, caption in colour["models"]:
        parts.append(f"<figure><img src='{name}'><figcaption>{_esc(caption)}</figcaption></figure>")
    parts.append("</div>")
    return "".join(parts)
