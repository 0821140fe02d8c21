"""A batch index page over many bake output folders: thumbnail, status, headline metrics, failures, links.

:func:`write_batch_index` takes a list of output folders (a batch run's) and writes one ``index.html``
(with a ``thumbs/`` folder beside it). A folder is "ok" when it holds ``asset.glb`` and ``report.json``;
otherwise it is listed as failed with the reason (a missing folder, no report, or the one-line error a
failed run left in ``error.txt``).
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

from .meshes import ViewError

__all__ = ["write_batch_index", "asset_summary"]


def asset_summary(folder) -> dict:
    """Status and headline figures of one output folder (JSON-ready)."""
    folder = Path(folder)
    out: dict = {"folder": str(folder), "name": folder.name, "status": "failed", "reason": None}
    if not folder.is_dir():
        out["reason"] = "no such folder"
        return out
    err = folder / "error.txt"
    rep_path = folder / "report.json"
    if err.is_file():
        text = err.read_text(errors="replace").strip()
        out["reason"] = text.splitlines()[0] if text else "failed (error.txt)"
        return out
    if not (folder / "asset.glb").is_file():
        out["reason"] = "no asset.glb"
        return out
    if not rep_path.is_file():
        out["reason"] = "no report.json (the bake did not finish)"
        return out
    try:
        rep = json.loads(rep_path.read_text())
    except ValueError as exc:
        out["reason"] = f"report.json unreadable ({exc})"
        return out
    out["status"] = "ok"
    truth = rep.get("vs_truth_deg") or {}
    base = (rep.get("baseline") or {}).get("vs_truth_deg") or {}
    out.update(normal_median_deg=truth.get("median"), normal_p95_deg=truth.get("p95"),
               baseline_median_deg=base.get("median"), color_psnr_db=rep.get("color_psnr_db"),
               coverage=rep.get("coverage"), seconds=rep.get("seconds_total"))
    view = folder / "report" / "view.json"
    if view.is_file():
        try:
            m = json.loads(view.read_text()).get("metrics", {}).get("baked_vs_source", {})
            out["render_psnr_db"] = (m.get("interior") or {}).get("psnr_db")
        except ValueError:
            pass
    return out


def _json_value(v):
    return str(v) if isinstance(v, Path) else float(v)


def _thumbnail(folder: Path, dest: Path, size: int) -> bool:
    from ..io.images import read_image, write_image

    made = folder / "report" / "views" / "baked_0.png"
    if made.is_file():
        write_image(dest, read_image(made, colour="data"), colour="data")
        return True
    from .meshes import view_mesh_from_glb
    from .raycast import render_mesh
    from .turntable import view_camera

    try:
        mesh = view_mesh_from_glb(folder / "asset.glb")
    except Exception:  # noqa: BLE001 - a broken asset still gets its row, without a picture
        return False
    write_image(dest, render_mesh(mesh, view_camera(mesh, width=size, height=size)).rgb, colour="srgb")
    return True


def _link_or_cell(v, page_dir: Path) -> str:
    """A table cell: a path is a link to it (relative to the page), anything else :func:`_cell`."""
    if isinstance(v, Path):
        return f"<a href='{html.escape(os.path.relpath(v, page_dir))}'>{html.escape(v.parent.name or v.name)}</a>"
    return _cell(v)


def _cell(v, nd=2) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return html.escape(str(v))


def write_batch_index(folders, out_html, *, thumb_size: int = 128, names=None, reasons=None,
                      extra=None) -> Path:
    """Write ``out_html`` (its folder must exist) indexing the bake output ``folders``; return its path.

    ``names`` (one per folder) name the rows instead of the folders' own names; ``reasons`` (one per folder,
    None where none) are failures known to the caller (a batch's one-line reasons): such a row is failed.
    ``extra`` (one dict per folder, ``{column: value}``) adds columns before the failure's, in the order the
    keys first appear, and the same keys to each row of the JSON index; a :class:`~pathlib.Path` value is a
    link to that file (relative to the page).

    One row per folder, in the order given: thumbnail (the report's first view, else a fresh render of the
    GLB), status, normal error against the truth (median, p95, and the classical bake's median), colour
    PSNR, render PSNR against the source (when the folder has a report), coverage, seconds, and the failure
    reason. Links point at each folder's ``report/index.html`` when it exists, else at the folder.
    """
    from ..io.atomic import atomic_write_text

    out_html = Path(out_html)
    if not out_html.parent.is_dir():
        raise ViewError(f"{out_html}: folder {out_html.parent} does not exist")
    folders = [Path(f) for f in folders]
    if not folders:
        raise ViewError("batch index: no output folders given")
    thumbs = out_html.parent / "thumbs"
    thumbs.mkdir(exist_ok=True)
    for given, what in ((names, "names"), (reasons, "reasons"), (extra, "extra")):
        if given is not None and len(given) != len(folders):
            raise ViewError(f"batch index: {len(given)} {what} for {len(folders)} folders")
    columns = list(dict.fromkeys(c for e in (extra or []) for c in (e or {})))
    rows, summaries = [], []
    for k, folder in enumerate(folders):
        s = asset_summary(folder)
        if names is not None:
            s["name"] = str(names[k])
        if reasons is not None and reasons[k]:
            s.update(status="failed", reason=str(reasons[k]))
        more = (extra[k] or {}) if extra is not None else {}
        s.update({c: more.get(c) for c in columns})
        summaries.append(s)
        thumb = ""
        if s["status"] == "ok" and _thumbnail(folder, thumbs / f"{k:04d}.png", thumb_size):
            thumb = f"<img src='thumbs/{k:04d}.png' width='{thumb_size}'>"
        target = folder / "report" / "index.html"
        link = os.path.relpath(target if target.is_file() else folder, out_html.parent)
        cls = "ok" if s["status"] == "ok" else "failed"
        rows.append(
            f"<tr class='{cls}'><td>{thumb}</td><td><a href='{html.escape(link)}'>{html.escape(s['name'])}</a></td>"
            f"<td>{s['status']}</td><td>{_cell(s.get('normal_median_deg'))}</td><td>{_cell(s.get('normal_p95_deg'))}</td>"
            f"<td>{_cell(s.get('baseline_median_deg'))}</td><td>{_cell(s.get('color_psnr_db'), 1)}</td>"
            f"<td>{_cell(s.get('render_psnr_db'), 1)}</td><td>{_cell(s.get('coverage'), 3)}</td>"
            f"<td>{_cell(s.get('seconds'), 1)}</td>" + "".join(f"<td>{_link_or_cell(more.get(c), out_html.parent)}</td>"
                                                               for c in columns)
            + f"<td>{_cell(s.get('reason'))}</td></tr>")
    ok = sum(s["status"] == "ok" for s in summaries)
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>neural-bake batch</title><style>"
            "body{font-family:system-ui,sans-serif;margin:1.5em} table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:4px 8px} tr.failed{background:#fde8e8}"
            "</style></head><body>"
            f"<h1>Batch: {ok} of {len(summaries)} assets baked</h1><table><tr><th></th><th>asset</th><th>status</th>"
            "<th>normal error median °</th><th>p95 °</th><th>classical median °</th><th>colour PSNR dB</th>"
            "<th>render PSNR dB</th><th>coverage</th><th>seconds</th>"
            + "".join(f"<th>{html.escape(c)}</th>" for c in columns) + "<th>failure</th></tr>"
            + "\n".join(rows) + "</table></body></html>")
    atomic_write_text(out_html, page)
    atomic_write_text(out_html.with_suffix(".json"), json.dumps(summaries, indent=2, default=_json_value))
    return out_html
