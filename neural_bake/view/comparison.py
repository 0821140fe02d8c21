"""One page comparing bakes of one asset side by side: what accuracy costs in time.

:func:`write_comparison` takes two or more bake output folders (each with ``asset.glb`` and the bake's
``report.json``) and writes an output folder (committed as a unit, :class:`~neural_bake.io.outdir.OutputFolder`)
holding ``index.html`` and every file it uses (no network): the bakes rendered from the same cameras with the
same lights (a turntable GIF, one column per bake, the source first), a table of their figures, their stage
times on one scale, a plot of normal error against time, and one model-viewer per bake whose cameras orbit
together (dragging one turns the others the same way). ``comparison.json`` holds the figures.

Figures per bake, from its ``report.json`` and the model files it names: normal error against the
ground truth (median, p95), colour error against the source texture at the same surface points
(:mod:`.colour`), render PSNR against the source and against the first bake (same camera), map size, file
sizes, wall time and time by stage, and each fit's steps, seconds and budget. Where two bakes share the
coarse mesh and UV layout (a neural and a classical bake of the same texels), the angle between their normal
maps and the colour error between their albedos, texel by texel, are in ``pairs``.
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .meshes import ViewError, ViewMesh
from .html import esc as _esc
from .html import fmt as _fmt

__all__ = ["CompareConfig", "write_comparison", "read_bake", "fit_summaries", "figures_rows", "error_time_svg",
           "COMPARISON_JSON"]

#: The figures of a comparison, beside its index.html.
COMPARISON_JSON = "comparison.json"


@dataclass
class CompareConfig:
    """Settings of :func:`write_comparison`; one line per field."""

    views: int = 8
    """Turntable views (equal steps about +Y)."""
    size: int = 256
    """Side of each render and of each interactive viewer, pixels."""
    model_viewer: str | None = None
    """model-viewer UMD script to copy beside the page; None: find it (see :func:`~.viewer.find_model_viewer`)."""


def read_bake(folder) -> dict:
    """The ``report.json`` of bake output folder ``folder``; :class:`ViewError` (one line naming the folder)
    for a folder that is not a bake's: missing, without ``asset.glb`` or ``report.json``, or whose
    report.json is not a bake report (a JSON object naming the source ``mesh`` and the ``coarse`` mesh)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ViewError(f"{folder}: no such bake output folder")
    rep = folder / "report.json"
    if not rep.is_file():
        raise ViewError(f"{folder}: not a bake output folder (no report.json)")
    try:
        report = json.loads(rep.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise ViewError(f"{rep}: unreadable report ({exc})") from None
    if not isinstance(report, dict) or "mesh" not in report or "coarse" not in report:
        raise ViewError(f"{rep}: not a bake report (expected the report.json a bake writes)")
    if not (folder / "asset.glb").is_file():
        raise ViewError(f"{folder}: not a bake output folder (no asset.glb)")
    return report


def _model_path(folder: Path, name) -> Path | None:
    if not name:
        return None
    for cand in (folder / Path(name).name, Path(name)):  # beside the bake first: the files it was made with
        if cand.is_file():
            return cand
    return None


def fit_summaries(folder, report: dict) -> list[dict]:
    """The fits behind a bake, from the model files its report names: ``[{"fit", "steps", "seconds",
    "budget_seconds", "expected_steps"}]`` (None where a file does not record it): the SDF fit (or a nested
    file's fine fit and each level's distillation) and the texture fit. Missing files give no row."""
    from ..fields import fit_records

    folder = Path(folder)
    rows: list[dict] = []

    def row(fit: str, training: dict, budget=None) -> dict:
        budget = budget if isinstance(budget, dict) else (training.get("budget") or {})
        return {"fit": fit, "steps": training.get("steps"), "seconds": training.get("seconds"),
                "budget_seconds": budget.get("budget_seconds"), "expected_steps": budget.get("expected_steps")}

    for key, label in (("sdf", "SDF"), ("texture_model", "texture")):
        path = _model_path(folder, report.get(key))
        if path is None:
            continue
        try:
            records = fit_records(path)
        except Exception:  # noqa: BLE001 - a comparison without a fit's row beats no comparison
            continue
        for r in records:
            t = r["training"]
            if r["fit"] == "fine":
                rows.append(row("SDF (fine level)", t))
            elif r["fit"] == "level":
                if t.get("steps"):
                    rows.append(row(f"nested level {r['level']} ({r['width']}x{r['depth']})", t, t.get("budget")))
            else:
                rows.append(row(label, t))
    return rows


def _stat(d, key="median"):
    v = (d or {}).get(key) if isinstance(d, dict) else None
    return float(v) if isinstance(v, (int, float)) else None


def _file_size(path: Path) -> int | None:
    try:
        return path.stat().st_size
    except OSError:
        return None


def figures_rows(folder, report: dict) -> dict:
    """The figures of one bake (JSON-ready) read from its folder and report: normal error against the truth,
    the classical baseline's on the same texels, colour PSNR, map size, supersampling, coarse faces, GLB size
    and the size of every file the bake wrote, the bake's wall time, its fits (:func:`fit_summaries`) and
    the total with them (``seconds_with_fits``)."""
    folder = Path(folder)
    bake = report.get("bake") or {}
    size = bake.get("size")
    files = [f for f in report.get("files") or [] if isinstance(f, str)]
    sizes = [_file_size(folder / f) for f in files]
    fits = fit_summaries(folder, report)
    wall = report.get("seconds_total")
    fit_seconds = sum(float(f["seconds"]) for f in fits if isinstance(f.get("seconds"), (int, float)))
    return {
        "normal_median_deg": _stat(report.get("vs_truth_deg")),
        "normal_p95_deg": _stat(report.get("vs_truth_deg"), "p95"),
        "baseline_median_deg": _stat((report.get("baseline") or {}).get("vs_truth_deg")),
        "truth": report.get("truth"),
        "color_psnr_db": report.get("color_psnr_db"),
        "map_size": list(size) if isinstance(size, (list, tuple)) else None,
        "supersample": bake.get("supersample"),
        "coarse_faces": (report.get("coarse") or {}).get("faces"),
        "glb_bytes": _file_size(folder / "asset.glb"),
        "files_bytes": sum(s for s in sizes if s is not None) if files else None,
        "seconds_total": float(wall) if isinstance(wall, (int, float)) else None,
        "fits": fits,
        "fit_seconds": fit_seconds,
        "seconds_with_fits": (float(wall) + fit_seconds) if isinstance(wall, (int, float)) else None,
        "method": report.get("method", "neural"),
    }


def _texel_angles(a: ViewMesh, b: ViewMesh) -> dict | None:
    """Angle (degrees) between two bakes' normal maps and colour error between their albedos, texel by
    texel, over the covered texels — only when both share one coarse mesh, UV layout and map size."""
    from .colour import _texel_points, colour_error

    if a.uv is None or b.uv is None or a.positions.shape != b.positions.shape or a.faces.shape != b.faces.shape:
        return None
    if not (np.array_equal(a.faces, b.faces) and np.allclose(a.positions, b.positions, atol=1e-5)
            and np.allclose(a.uv, b.uv, atol=1e-6)):
        return None
    out: dict = {}
    if a.normal_map is not None and b.normal_map is not None and a.normal_map.shape == b.normal_map.shape:
        pixel, _ = _texel_points(a, a.normal_map.shape[:2])
        na = a.normal_map[pixel[:, 0], pixel[:, 1]].astype(np.float64) * 2 - 1
        nb = b.normal_map[pixel[:, 0], pixel[:, 1]].astype(np.float64) * 2 - 1
        na /= np.maximum(np.linalg.norm(na, axis=1, keepdims=True), 1e-12)
        nb /= np.maximum(np.linalg.norm(nb, axis=1, keepdims=True), 1e-12)
        ang = np.degrees(np.arccos(np.clip((na * nb).sum(axis=1), -1.0, 1.0)))
        out["normal_map_angle_deg"] = {"median": float(np.median(ang)), "p95": float(np.percentile(ang, 95)),
                                       "max": float(ang.max()), "count": int(ang.size)}
    if a.texture is not None and b.texture is not None and a.texture.shape == b.texture.shape:
        pixel, _ = _texel_points(a, a.texture.shape[:2])
        err = colour_error(a.texture[pixel[:, 0], pixel[:, 1]], b.texture[pixel[:, 0], pixel[:, 1]])
        out["albedo_error_levels"] = {"median": float(np.median(err)), "p95": float(np.percentile(err, 95)),
                                      "max": float(err.max()), "count": int(err.size)}
    return out or None


def _unique_names(folders: list[Path], names) -> list[str]:
    base = [str(n) for n in names] if names is not None else [f.name or str(f) for f in folders]
    out: list[str] = []
    for n in base:
        cand, k = n, 2
        while cand in out:
            cand, k = f"{n} ({k})", k + 1
        out.append(cand)
    return out


def write_comparison(folders, out, config: CompareConfig | None = None, *, names=None,
                     log: Callable[[str], None] = print) -> Path:
    """Compare the bakes in ``folders`` (two or more) on one page written to folder ``out``; return its
    index.html. ``names``: how the page names each bake (default the folders' names).

    Every folder is checked first (:func:`read_bake`): a folder that is not a bake is a one-line
    :class:`ViewError` naming it, and nothing is written. ``out`` is committed as a unit: a reader sees the
    old comparison or the new one; a failed run leaves it as it was.
    """
    from ..io.outdir import OutputFolder

    cfg = config or CompareConfig()
    folders = [Path(f) for f in folders]
    if len(folders) < 2:
        raise ViewError(f"compare: give at least two bake output folders, got {len(folders)}")
    if names is not None and len(names) != len(folders):
        raise ViewError(f"compare: {len(names)} names for {len(folders)} bake folders")
    from ..limits import check_count
    from ..constants import MAX_VIEW_SIDE, MAX_VIEWS

    views = check_count(cfg.views, "views", MAX_VIEWS)
    size = check_count(cfg.size, "size", MAX_VIEW_SIDE, minimum=16)
    reports = [read_bake(f) for f in folders]  # every folder checked before anything is written
    labels = _unique_names(folders, names)
    with OutputFolder(out) as stage:
        _write(stage, folders, reports, labels, views, size, cfg, log)
    index = Path(out) / "index.html"
    log(f"compare: {index} ({len(folders)} bakes: {', '.join(labels)})")
    return index


def _write(stage: Path, folders: list[Path], reports: list[dict], labels: list[str], views: int, size: int,
           cfg: CompareConfig, log: Callable[[str], None]) -> dict:
    from ..io.atomic import atomic_write_text
    from ..io.images import write_image
    from ..io.mesh_io import load_mesh
    from ..render.shading import default_lights
    from .compare import image_metrics
    from .colour import compare_colours
    from .environment import sun_environment, write_hdr
    from .meshes import view_mesh_from_glb, view_mesh_from_mesh
    from .raycast import DEFAULT_BACKGROUND, render_mesh
    from .report import source_of
    from .stages import stage_tree
    from .turntable import to_srgb8, turntable_cameras, view_camera, write_gif
    from .viewer import MODEL_VIEWER_SCRIPT, find_model_viewer, model_viewer_attributes, models_js

    meshes = [view_mesh_from_glb(f / "asset.glb") for f in folders]
    source_mesh = source = None
    src_note = ""
    for f, r in zip(folders, reports):
        path, src_note = source_of(f, r)
        if path is not None:
            try:
                source_mesh = load_mesh(path)
                source = view_mesh_from_mesh(source_mesh, "source")
                src_note = ""
                break
            except Exception as exc:  # noqa: BLE001 - the page still compares the bakes
                src_note = f"source mesh {path} unreadable: {exc}"
    camera = view_camera(source or meshes[0], width=size, height=size)
    cams = turntable_cameras(camera, views)
    log(f"compare: rendering {len(cams)} views of {size}² ({len(meshes)} bakes{' and the source' if source else ''})")
    (stage / "views").mkdir()
    vs_source: list[list[dict]] = [[] for _ in meshes]
    vs_first: list[list[dict]] = [[] for _ in meshes]
    frames = []
    for k, cam in enumerate(cams):
        r_src = render_mesh(source, cam) if source is not None else None
        panels = []
        if r_src is not None:
            write_image(stage / "views" / f"source_{k}.png", r_src.rgb, colour="srgb")
            panels.append(to_srgb8(r_src.rgb))
        first = None
        for i, m in enumerate(meshes):
            r = render_mesh(m, cam)
            write_image(stage / "views" / f"bake{i}_{k}.png", r.rgb, colour="srgb")
            panels.append(to_srgb8(r.rgb))
            if r_src is not None:
                vs_source[i].append(image_metrics(r_src.rgb, r.rgb, r_src.mask, r.mask, region="interior"))
            if first is None:
                first = r
            else:
                vs_first[i].append(image_metrics(first.rgb, r.rgb, first.mask, r.mask, region="interior"))
        frames.append(np.concatenate(panels, axis=1))
    write_gif(stage / "turntable.gif", frames)

    bakes = []
    for i, (f, r, m) in enumerate(zip(folders, reports, meshes)):
        row = figures_rows(f, r)
        row.update(name=labels[i], folder=str(f), render_psnr_vs_source_db=_mean_psnr(vs_source[i]),
                   render_psnr_vs_first_db=_mean_psnr(vs_first[i]) if i else None,
                   stages=_tree_dict(stage_tree(r.get("seconds") or {}, r.get("seconds_total"))))
        row["colour_error_levels"] = None
        if m.texture is not None and source_mesh is not None and source_mesh.texture is not None \
                and source_mesh.uv is not None:
            row["colour_error_levels"] = compare_colours(m, source_mesh).stats
        bakes.append(row)
    pairs = []
    for i in range(len(meshes)):
        for j in range(i + 1, len(meshes)):
            t = _texel_angles(meshes[i], meshes[j])
            if t is not None:
                pairs.append({"a": labels[i], "b": labels[j], **t})

    mv_path, mv_note = (Path(cfg.model_viewer), "") if cfg.model_viewer else find_model_viewer()
    if mv_path is not None and not mv_path.is_file():
        mv_path, mv_note = None, f"model-viewer script {mv_path}: no such file"
    sun = -np.asarray(default_lights(camera)[0].direction)
    write_hdr(stage / "sun.hdr", sun_environment(sun))
    models = {}
    for i, f in enumerate(folders):
        shutil.copy2(f / "asset.glb", stage / f"bake{i}.glb")
        models[f"bake{i}"] = stage / f"bake{i}.glb"
    if mv_path is not None:
        shutil.copy2(mv_path, stage / MODEL_VIEWER_SCRIPT)
        atomic_write_text(stage / "models.js", models_js(models, stage / "sun.hdr"))
    summary = {"bakes": bakes, "pairs": pairs, "views": len(cams), "size": size, "camera": camera.to_dict(),
               "source": str(source_mesh.source) if source_mesh is not None else None, "source_note": src_note,
               "model_viewer": mv_path is not None, "model_viewer_note": mv_note,
               "viewer_attributes": model_viewer_attributes(camera), "background": list(DEFAULT_BACKGROUND)}
    atomic_write_text(stage / COMPARISON_JSON, json.dumps(summary, indent=2, default=str))
    atomic_write_text(stage / "index.html", _page(summary, source is not None, MODEL_VIEWER_SCRIPT))
    return summary


def _mean_psnr(rows: list[dict]) -> float | None:
    mses = [r["mse"] for r in rows if r.get("mse") is not None]
    if not mses:
        return None
    mse = float(np.mean(mses))
    return math.inf if mse == 0 else float(10 * np.log10(1.0 / mse))


def _tree_dict(node) -> dict:
    return {"name": node.name, "seconds": node.seconds, "children": [_tree_dict(c) for c in node.children]}


def _tree_node(d: dict):
    from .stages import StageNode

    return StageNode(d["name"], float(d["seconds"]), [_tree_node(c) for c in d.get("children", [])])


# ---------------------------------------------------------------------------------------------------- page

def _bytes(n) -> str:
    if n is None:
        return "–"
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return "–"


_COLOURS = ("#4a7fb5", "#e08a3c", "#5aa469", "#c95b5b", "#8c6bb1", "#3caab4", "#b5954a", "#d47fb0")


def error_time_svg(points: list[tuple[str, float | None, float | None, float | None]], *, width: int = 520,
                   height: int = 300) -> str:
    """An SVG plot of normal error against time: ``points`` are (label, seconds, median °, p95 °); the
    median is a dot, the p95 a whisker above it. Points without seconds or median are left out (and listed
    under the plot)."""
    good = [(n, t, m, p) for n, t, m, p in points if t is not None and m is not None]
    left, right, top, bottom = 52, 16, 14, 40
    out = [f"<svg class='errtime' width='{width}' height='{height}' font-family='system-ui,sans-serif' "
           f"font-size='11'>"]
    if not good:
        out.append("<text x='10' y='20'>no bake records both a time and a normal error</text></svg>")
        return "".join(out)
    tmax = max(t for _, t, _, _ in good) * 1.1 or 1.0
    emax = max(max(m, p or m) for _, _, m, p in good) * 1.15 or 1.0
    w, h = width - left - right, height - top - bottom

    def x(t):
        return left + w * t / tmax

    def y(e):
        return top + h * (1 - e / emax)

    out.append(f"<rect x='{left}' y='{top}' width='{w}' height='{h}' fill='#fafafa' stroke='#bbb'/>")
    for k in range(5):  # ticks
        tv, ev = tmax * k / 4, emax * k / 4
        out.append(f"<text x='{x(tv):.1f}' y='{top + h + 14}' text-anchor='middle' fill='#555'>{tv:.0f}</text>")
        out.append(f"<text x='{left - 4}' y='{y(ev) + 4:.1f}' text-anchor='end' fill='#555'>{ev:.1f}</text>")
    out.append(f"<text x='{left + w / 2}' y='{height - 6}' text-anchor='middle'>seconds (fits + bake)</text>")
    out.append(f"<text x='12' y='{top + h / 2}' transform='rotate(-90 12 {top + h / 2})' text-anchor='middle'>"
               f"normal error vs truth, ° (median; whisker p95)</text>")
    for i, (n, t, m, p) in enumerate(good):
        c = _COLOURS[i % len(_COLOURS)]
        if p is not None:
            out.append(f"<line x1='{x(t):.1f}' y1='{y(m):.1f}' x2='{x(t):.1f}' y2='{y(p):.1f}' stroke='{c}' "
                       f"stroke-width='2'/>")
        out.append(f"<g><title>{_esc(n)}: {t:.1f} s, median {m:.2f}°</title><circle cx='{x(t):.1f}' "
                   f"cy='{y(m):.1f}' r='5' fill='{c}'/></g>")
        out.append(f"<text x='{x(t) + 8:.1f}' y='{y(m) + 4:.1f}'>{_esc(n)}</text>")
    out.append("</svg>")
    return "".join(out)


#: The script that links the viewers: a user's orbit of one is copied to the others (their camera changes
#: then carry no user source, so they are not copied back).
_SYNC_JS = """
const mvs=[...document.querySelectorAll('model-viewer.linked')];
window.NEURAL_BAKE_LOADED=0;
mvs.forEach((mv,i)=>{
  mv.environmentImage=window.NEURAL_BAKE_ENV;
  mv.addEventListener('load',()=>{window.NEURAL_BAKE_LOADED+=1;});
  mv.addEventListener('error',(e)=>{window.NEURAL_BAKE_ERROR=String(e.detail&&e.detail.type);});
  mv.addEventListener('camera-change',(e)=>{
    if(e.detail.source!=='user-interaction')return;
    const o=mv.getCameraOrbit(), t=mv.getCameraTarget();
    const orbit=o.theta+'rad '+o.phi+'rad '+o.radius+'m', target=t.x+'m '+t.y+'m '+t.z+'m';
    const fov=mv.getFieldOfView()+'deg';
    mvs.forEach((other)=>{if(other!==mv){other.cameraOrbit=orbit;other.cameraTarget=target;
      other.fieldOfView=fov;other.jumpCameraToGoal();}});
  });
  mv.src=window.NEURAL_BAKE_MODELS['bake'+i];
});
"""


def _page(s: dict, has_source: bool, script_name: str) -> str:
    from .report import _CSS
    from .stages import stage_bar_svg

    bakes = s["bakes"]
    attrs = " ".join(f'{k}="{_esc(v)}"' for k, v in s["viewer_attributes"].items())
    p = ["<!doctype html><html><head><meta charset='utf-8'><title>neural-bake comparison: "
         + _esc(", ".join(b["name"] for b in bakes)) + "</title>", f"<style>{_CSS}</style>"]
    if s["model_viewer"]:
        p.append(f"<script src='{script_name}'></script><script src='models.js'></script>")
    p.append("</head><body><h1>Comparison: " + _esc(" · ".join(b["name"] for b in bakes)) + "</h1>")
    # linked viewers
    p.append("<h2>Interactive viewers (linked: drag one, all turn)</h2>")
    if s["model_viewer"]:
        p.append("<div class='row'>")
        for i, b in enumerate(bakes):
            p.append(f"<figure><model-viewer id='viewer{i}' class='linked' camera-controls interaction-prompt='none' "
                     f"tone-mapping='neutral' shadow-intensity='0' exposure='1' "
                     f"style='width:{s['size']}px;height:{s['size']}px' {attrs}></model-viewer>"
                     f"<figcaption>{_esc(b['name'])}</figcaption></figure>")
        p.append(f"</div><script>{_SYNC_JS}</script>")
    else:
        p.append(f"<p class='note'>No interactive viewer: {_esc(s['model_viewer_note'])}. The pictures below are "
                 "rendered by neural-bake itself.</p>")
    # figures
    p.append("<h2>Figures</h2><table><tr><th>figure</th>" + "".join(f"<th>{_esc(b['name'])}</th>" for b in bakes)
             + "</tr>")

    def line(label, cells):
        p.append(f"<tr><td>{_esc(label)}</td>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")

    line("method", [_esc(b["method"]) for b in bakes])
    line("normal error vs truth, median °", [_fmt(b["normal_median_deg"]) for b in bakes])
    line("normal error vs truth, p95 °", [_fmt(b["normal_p95_deg"]) for b in bakes])
    line("colour error vs source texture, median (8-bit levels)",
         [_fmt((b["colour_error_levels"] or {}).get("median")) for b in bakes])
    line("colour error vs source texture, p95 (8-bit levels)",
         [_fmt((b["colour_error_levels"] or {}).get("p95")) for b in bakes])
    line("colour PSNR vs truth, dB (report.json)", [_fmt(b["color_psnr_db"], 1) for b in bakes])
    line("render PSNR vs source, dB (interior)", [_fmt(b["render_psnr_vs_source_db"], 1) for b in bakes])
    line(f"render PSNR vs {bakes[0]['name']}, dB (interior)", [_fmt(b["render_psnr_vs_first_db"], 1) for b in bakes])
    line("map size", ["×".join(map(str, b["map_size"])) if b["map_size"] else "–" for b in bakes])
    line("supersampling", [_fmt(b["supersample"]) for b in bakes])
    line("coarse mesh faces", [_fmt(b["coarse_faces"]) for b in bakes])
    line("asset.glb size", [_bytes(b["glb_bytes"]) for b in bakes])
    line("files the bake wrote, total", [_bytes(b["files_bytes"]) for b in bakes])
    line("bake wall time, s", [_fmt(b["seconds_total"], 1) for b in bakes])
    line("fits' time, s", [_fmt(b["fit_seconds"], 1) for b in bakes])
    line("total (fits + bake), s", [_fmt(b["seconds_with_fits"], 1) for b in bakes])
    fit_names = list(dict.fromkeys(f["fit"] for b in bakes for f in b["fits"]))
    for fit in fit_names:
        cells = []
        for b in bakes:
            f = next((x for x in b["fits"] if x["fit"] == fit), None)
            if f is None:
                cells.append("–")
                continue
            budget = "" if f["budget_seconds"] is None else f" of a {f['budget_seconds']:.0f}-s budget"
            expected = "" if f["expected_steps"] is None else f" (~{f['expected_steps']} expected)"
            cells.append(f"{_fmt(f['steps'])} steps{_esc(expected)} in {_fmt(f['seconds'], 1)} s{_esc(budget)}")
        line(f"fit: {fit}", cells)
    p.append("</table>")
    if s["pairs"]:
        p.append("<h3>Bake against bake, texel by texel (same coarse mesh and UV layout)</h3><table><tr><th>pair</th>"
                 "<th>normal maps' angle, median °</th><th>p95 °</th><th>albedo difference, median levels</th>"
                 "<th>p95 levels</th></tr>")
        for pr in s["pairs"]:
            n, a = pr.get("normal_map_angle_deg") or {}, pr.get("albedo_error_levels") or {}
            p.append(f"<tr><td>{_esc(pr['a'])} vs {_esc(pr['b'])}</td><td>{_fmt(n.get('median'))}</td>"
                     f"<td>{_fmt(n.get('p95'))}</td><td>{_fmt(a.get('median'))}</td><td>{_fmt(a.get('p95'))}</td></tr>")
        p.append("</table>")
    # accuracy against time
    p.append("<h2>What accuracy costs in time</h2>")
    p.append(error_time_svg([(b["name"], b["seconds_with_fits"], b["normal_median_deg"], b["normal_p95_deg"])
                             for b in bakes]))
    p.append("<h2>Time by stage (one scale)</h2>")
    scale = max((b["stages"]["seconds"] for b in bakes), default=1.0) or 1.0
    for b in bakes:
        p.append(stage_bar_svg(_tree_node(b["stages"]), width=900, scale_seconds=scale, label=b["name"]))
    # renders
    cols = (["source"] if has_source else []) + [b["name"] for b in bakes]
    p.append("<h2>Turntable, same camera and lights</h2><p>Columns: " + _esc(", ".join(cols)) + ".</p>"
             "<img src='turntable.gif' alt='turntable'>")
    if not has_source:
        p.append(f"<p class='note'>No source render: {_esc(s['source_note'] or 'no source mesh found')}.</p>")
    p.append("<div class='row'>")
    if has_source:
        p.append("<figure><img src='views/source_0.png'><figcaption>source mesh</figcaption></figure>")
    for i, b in enumerate(bakes):
        p.append(f"<figure><img src='views/bake{i}_0.png'><figcaption>{_esc(b['name'])}</figcaption></figure>")
    p.append("</div>")
    p.append("</body></html>")
    return "\n".join(p)

