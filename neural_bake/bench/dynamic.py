"""`neural-bake bench dynamic`: space-time SDFs — the two morph methods at equal steps (Hausdorff to the end
shapes at t = 0 and 1, eikonal residual against t, measured cost per step), a sequence fit against every frame
of an animated sample and half-way between frames (interpolation between frames against the eikonal term
alone, at equal steps), nesting at every sampled t, per-frame render and bake cost, and storage (the 4-D network
in KB against per-frame meshes in MB). ``real``: the morph of Spot into the bunny from the data folder.

Baselines a user would otherwise pick: per-frame meshes for playback (the storage row) and, for the morph, the
other method at the same number of steps; for the sequence, the eikonal term alone between frames. Target: a morph between two samples renders 60 frames at 256² with
normal mapping in under 5 minutes.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import torch

__all__ = ["run", "TARGET_RENDER_MINUTES", "EIKONAL_TIMES"]

#: Minutes the 60 frames at 256² may take (the target).
TARGET_RENDER_MINUTES = 5.0

#: Times at which the morphs' eikonal residual is measured.
EIKONAL_TIMES = (0.0, 0.25, 0.5, 0.75, 1.0)


def _mesh(sample, t=None, res=3000):
    from ..io.mesh_io import mesh_from_arrays

    m = sample.mesh(res, 16) if t is None else sample.mesh(t, res)
    return mesh_from_arrays(m.vertices, m.faces)


def _hausdorff(fit, mesh, t, n, res):
    from ..errors import FitError
    from ..fit.spacetime import spacetime_metrics

    try:
        r = spacetime_metrics(fit, mesh, t, n=n, resolution=res)
    except FitError:  # no zero set at t (a fit too short to form one): no distance
        return None, None
    return round(r["hausdorff"], 5), round(r["chamfer_l1"], 6)


def eikonal_residual(fit, t: float, *, n: int = 4000, band: float = 0.1, seed: int = 0) -> float | None:
    """Mean |1 − |∇ₓf(·, t)|| over ``n`` points of [-1, 1]³ with |f(·, t)| < ``band`` (GEMM gradient); None when
    f(·, t) has no such point."""
    from ..fit.nested import band_samples
    from ..nets.gemm import gemm_gradient

    sl = fit.at(t)
    x = band_samples(sl, n, band, seed=seed, max_tries=20)
    if x.shape[0] == 0:
        return None
    with torch.no_grad():
        _, g = gemm_gradient(sl, x)
    return round(float((1.0 - g.double().norm(dim=1)).abs().mean()), 5)


def _ratio(a, b):
    return round(a / b, 3) if a is not None and b else None


def _morph_rows(a, b, steps, net, pools, n_metric, res_metric, progress, *, align="source"):
    """Both morph methods for the same number of steps: rows, the residual-against-t table, and the fits."""
    from ..fit.spacetime import fit_morph

    rows, fits = [], {}
    for method in ("lse", "interpolate"):
        fit = fit_morph(a, b, method=method, steps=steps, progress=progress, align=align, **net, **pools)
        fits[method] = fit
        ma, mb = (a, b) if align == "source" else (_unit(a), _unit(b))
        h0, c0 = _hausdorff(fit, ma, 0.0, n_metric, res_metric)
        h1, c1 = _hausdorff(fit, mb, 1.0, n_metric, res_metric)
        rows.append({"method": method, "network": f"{fit.config.width}x{fit.config.depth}", "steps": fit.steps,
                     "seconds": round(fit.seconds, 1), "ms_per_step": round(1000 * fit.seconds / max(fit.steps, 1), 2),
                     "hausdorff_t0": h0, "hausdorff_t1": h1, "chamfer_t0": c0, "chamfer_t1": c1})
    lse, itp = rows
    rows.append({"method": "interpolate / lse", "network": "", "steps": _ratio(itp["steps"], lse["steps"]),
                 "seconds": _ratio(itp["seconds"], lse["seconds"]),
                 "ms_per_step": _ratio(itp["ms_per_step"], lse["ms_per_step"]),
                 "hausdorff_t0": _ratio(itp["hausdorff_t0"], lse["hausdorff_t0"]),
                 "hausdorff_t1": _ratio(itp["hausdorff_t1"], lse["hausdorff_t1"]),
                 "chamfer_t0": _ratio(itp["chamfer_t0"], lse["chamfer_t0"]),
                 "chamfer_t1": _ratio(itp["chamfer_t1"], lse["chamfer_t1"])})
    eik = []
    for t in EIKONAL_TIMES:
        r = {"t": t, **{m: eikonal_residual(f, t, seed=11) for m, f in fits.items()}}
        r["interpolate / lse"] = _ratio(r["interpolate"], r["lse"])
        eik.append(r)
    return rows, eik, fits


def _direction_colours(sample, frame):
    """A static texture field: the sample's analytic colour of the direction from the origin (source frame)."""
    from ..fields.texture import TextureField

    def fn(p):
        return torch.as_tensor(sample.albedo(frame.to_source(p.double().cpu().numpy())), dtype=p.dtype)

    return TextureField(fn, frame=frame, name=f"{sample.name} colours")


def _unit(mesh):
    from dataclasses import replace

    from ..types import Frame

    return replace(mesh, frame=Frame())


def _real_rows(data, steps, net, pools, n_metric, res_metric, progress, notes) -> list[dict]:
    """Spot into the bunny (each centred and scaled into the unit cube), both methods at equal steps."""
    from ..io.mesh_io import load_mesh
    from .common import data_folder

    folder = data_folder(data)
    spot = folder / "spot" / "spot_triangulated.obj" if folder else None
    bunny = folder / "bunny" / "bunny_closed.obj" if folder else None
    if spot is None or not (spot.is_file() and bunny.is_file()):
        notes.append("real: skipped, no data folder with spot/ and bunny/ (set NEURAL_BAKE_DATA)")
        return []
    a, b = load_mesh(spot), load_mesh(bunny)
    rows, eik, _ = _morph_rows(a, b, steps, net, pools, n_metric, res_metric, progress, align="unit")
    for r in rows:
        r["morph"] = "spot -> bunny"
        r["eikonal_t0.5"] = next((e[r["method"]] for e in eik if e["t"] == 0.5 and r["method"] in e), None)
    notes.append(f"real: Spot ({a.n_vertices} vertices) into the bunny ({b.n_vertices}), each in its own unit "
                 f"frame (align='unit'); Hausdorff in unit-frame units")
    return rows


def run(quick: bool = False, *, steps: int | None = None, frames: int | None = None, size: int | None = None,
        real: bool = False, data: str | None = None, progress: bool = False) -> dict:
    """Run the benchmark; ``quick`` shrinks networks, steps, frames and images (under two minutes).

    Args:
        steps: optimiser steps of every space-time fit (each morph method gets the same number).
        frames, size: rendered frames and their square size in pixels.
        real: also morph Spot into the bunny from the data folder (``data``, else ``$NEURAL_BAKE_DATA``).
    """
    from ..bake.frames import bake_frames
    from ..errors import NeuralBakeError
    from ..fit.spacetime import fit_sequence, nest_spacetime, nesting_by_time
    from ..nets.timeslice import fix_last_input
    from ..samples import ANIMATED, SAMPLES

    net = dict(width=32, depth=1, lr=1e-3) if quick else dict(width=128, depth=2, lr=2e-4)
    pools = (dict(pool_surface=8000, pool_near=8000, pool_uniform=2000, pool_between=8000, batch=1024,
                  batch_near=1024, batch_uniform=256, batch_between=512) if quick else {})
    n_steps = steps if steps is not None else (300 if quick else 2000)
    n_frames = frames if frames is not None else (6 if quick else 60)
    px = size if size is not None else (64 if quick else 256)
    for name, v in (("steps", n_steps), ("frames", n_frames), ("size", px)):
        if int(v) != v or v < 1:
            raise NeuralBakeError(f"bench dynamic: {name} must be a positive integer, got {v!r}")
    n_metric, res_metric = (5000, 64) if quick else (30000, 128)
    notes: list[str] = []
    a, b = _mesh(SAMPLES["sphere"]), _mesh(SAMPLES["torus"])
    rows_morph, rows_eik, fits = _morph_rows(a, b, n_steps, net, pools, n_metric, res_metric, progress)

    # a sequence through the frames of an animated sample, measured at every frame and half-way between
    anim = ANIMATED["splitting_sphere"]
    times = list(anim.times)
    frames_m = [_mesh(anim, t) for t in times]
    # (the default interpolation between frames, and the eikonal term alone as the baseline, at equal steps)
    seq = fit_sequence(frames_m, times, steps=n_steps, progress=progress, **net, **pools)
    seq_eik = fit_sequence(frames_m, times, steps=n_steps, method="eikonal", progress=progress, **net, **pools)
    rows_seq = []
    for t in sorted(set(times) | {0.5 * (x + y) for x, y in zip(times[:-1], times[1:])}):
        truth = _mesh(anim, t)
        h, c = _hausdorff(seq, truth, t, n_metric, res_metric)
        h0, c0 = _hausdorff(seq_eik, truth, t, n_metric, res_metric)
        rows_seq.append({"t": t, "frame": t in times, "hausdorff": h, "chamfer_l1": c, "hausdorff_eikonal": h0,
                         "chamfer_l1_eikonal": c0, "hausdorff_ratio": _ratio(h, h0)})

    # nesting of the morph over space-time, checked at each sampled t
    lse, itp = rows_morph[0], rows_morph[1]
    best = min(("lse", lse), ("interpolate", itp), key=lambda r: (r[1]["hausdorff_t0"] or 9.0)
               + (r[1]["hausdorff_t1"] or 9.0))[0]
    fine = fits[best]
    t0 = time.perf_counter()
    nested = nest_spacetime(fine, levels=[(16, 1) if quick else (64, 1)], steps=200 if quick else 1500,
                            pool=20_000 if quick else 100_000, eval_samples=4000 if quick else 20_000,
                            n_estimate=10_000 if quick else 50_000, stability_samples=(),
                            max_boxes=2000 if quick else 200_000, progress=progress,
                            check_times=6 if quick else 11)
    nest_s = time.perf_counter() - t0
    info = nested.levels_info[0]
    check_t = np.linspace(0, 1, 11)
    check = nesting_by_time(nested, check_t, n=5000 if quick else 20000, seed=3)
    cert = info.get("certify") or {}
    sup_c = info.get("sup_certified")
    rows_nest = [{"level": f"{info['width']}x{info['depth']}", "sup_estimated": round(info["sup_estimated"], 5),
                  "sup_certified": round(sup_c, 5) if sup_c is not None else None,
                  "certified_over_estimated": _ratio(sup_c, info["sup_estimated"]),
                  "certify_boxes": cert.get("boxes_bounded"), "certify_s": cert.get("seconds"),
                  "delta_estimated": round(info["delta_estimated"], 5), "delta": round(info["delta"], 5),
                  "delta_source": info["delta_source"], "guaranteed": info["nesting_guaranteed"],
                  "seconds": round(nest_s, 1), "times_checked": len(check_t),
                  "holds_at_all_t": all(r["holds"] for r in check),
                  "worst_t_sup_over_allowed": round(max(r["sup"] / r["allowed"] for r in check), 3)}]
    rows_by_t = [{"t": r["t"], "sup": round(r["sup"], 5), "allowed": round(r["allowed"], 5), "holds": r["holds"]}
                 for r in check]

    # render the morph (single network: sphere tracing with its own GEMM normals) and bake frames
    from .common import last_error_line, run_command

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        model = d / "morph.safetensors"
        fine.save(model)
        render_s, proc = run_command(["render", str(model), "-o", str(d / "morph.gif"), "--frames", str(n_frames),
                                      "--size", str(px), "--effects", "shading,normal_mapping"])
        rendered = proc.returncode == 0
        if not rendered:
            notes.append(f"render: `neural-bake render` failed: {last_error_line(proc)}")

        def coarse_at(t):
            return fix_last_input(nested.levels[0], float(fine.tau(t)))

        bake_times = np.linspace(0, 1, 3 if quick else 10)
        res = 48 if quick else 96
        texture = _direction_colours(SAMPLES["sphere"], fine.frame)
        t0 = time.perf_counter()
        try:
            baked = bake_frames(coarse_at, fine.at, fine.frame, bake_times, d / "bake", resolution=res,
                                texture=texture)
            bake_level = "coarse"
        except NeuralBakeError as exc:  # a coarse level too weak to hold the surface at some t: march the fine one
            notes.append(f"bake: the coarse level failed ({exc}); marched the fine level instead")
            baked = bake_frames(fine.at, fine.at, fine.frame, bake_times, d / "bake", resolution=res,
                                texture=texture)
            bake_level = "fine"
        bake_s = time.perf_counter() - t0
        model_kb = model.stat().st_size / 1024
        frames_mb = sum(f.stat().st_size for f in baked.files) / len(baked.files) * n_frames / 2**20
    rows_cost = [{"frames": n_frames, "size": f"{px}x{px}", "render_total_s": round(render_s, 3),
                  "render_per_frame_s": round(render_s / n_frames, 3), "rendered": rendered,
                  "target_render_s": 60 * TARGET_RENDER_MINUTES,
                  "target_met": rendered and render_s < 60 * TARGET_RENDER_MINUTES,
                  "bake_frames": len(baked.files), "bake_marched": bake_level,
                  "bake_per_frame_s": round(bake_s / len(baked.files), 3),
                  "bake_colours_s": round(float(np.mean([s["colours_s"] for s in baked.stats])), 4),
                  "bake_vertices": int(np.mean([s["vertices"] for s in baked.stats])),
                  "model_kb": round(model_kb, 1), "ply_frames_mb": round(frames_mb, 3),
                  "storage_ratio": round(frames_mb * 1024 / model_kb, 1)}]
    if n_frames != 60 or px != 256:
        notes.append(f"target: 60 frames at 256x256 in under {TARGET_RENDER_MINUTES:g} min; this run rendered "
                     f"{n_frames} at {px}x{px}, so target_met says nothing about the target")
    tables = {"morph sphere -> torus (equal steps)": rows_morph, "morph eikonal residual against t": rows_eik,
              "sequence splitting_sphere": rows_seq, "nesting over space-time": rows_nest,
              "nesting at each sampled t": rows_by_t, "render and bake cost, storage": rows_cost}
    if real:
        tables["morph spot -> bunny (equal steps)"] = _real_rows(data, n_steps, net, pools, n_metric, res_metric,
                                                               progress, notes)
    notes.append(f"morphs: both methods run {n_steps} steps; ms_per_step is each one's measured cost, so quality "
                 f"per minute is Hausdorff at equal steps against ms_per_step; Hausdorff in common-unit-frame units")
    notes.append("eikonal residual: mean |1 - |grad_x f(., t)|| within 0.1 of f(., t) = 0")
    notes.append(f"nesting, bake: the {best} morph (the better one at equal steps); delta is the certified bound "
                 f"(range analysis over space-time boxes, certify_s its cost: guaranteed at every t), "
                 f"delta_estimated the sampled fallback (tighter, not guaranteed)")
    notes.append(f"render: `neural-bake render` of the morph's file to a GIF in a process of its own, as a user runs "
                 f"it (render_total_s: its wall time, start-up included); one space-time network (no coarse level), "
                 f"shading + neural normals, fixed camera; "
                 f"storage: the model file against {n_frames} PLY frames of the per-frame bake; bake: marching + "
                 f"GEMM normals + per-vertex colours (the sphere sample's analytic colours) + PLY")
    from .common import load_note

    notes.append(load_note())
    return {"name": "dynamic", "title": "dynamic SDFs: morph methods, sequence, nesting, render/bake cost, storage",
            "tables": tables, "notes": notes}
