"""`neural-bake bench fit`: SDF fitting — accuracy against training time, and the cost of a training step.

Two tables, measured in the same run:

- **training step**: one step of :func:`~neural_bake.fit.sdf.sdf_loss_terms` + ``backward()`` (∇f by the
  differentiable GEMM gradient, one backward), run as a time-budgeted ``fit_sdf`` runs it — in
  micro-batches (:func:`~neural_bake.fit.sdf.sdf_step_backward`), at the fastest of the counts its tuner
  tries (:class:`~neural_bake.fit.sdf.MicroBatchTuner`; every count's time is in ``eager_ms_by_parts`` and
  ``compiled_ms_by_parts``, measured in the same rounds) — against the baseline a user would write — the
  same losses with ∇f from ``torch.autograd.grad(create_graph=True)`` (double-backward), in one batch — and
  against this machine's roofline (:mod:`neural_bake.bench.roofline`). The step's roofline counts the
  forward with GEMM gradients (``siren_cost(grad="reverse")``) and its backward as 2× those GEMM FLOPs
  (input and weight gradients of every product) plus one more sin/cos per unit and twice the element-wise
  work: an approximation stated as such (float32 roofline), priced at the best rates read in the step
  timing's own interleaved rounds (``sgemm_gflops``). ``fraction`` = roofline time / measured time (1.0 =
  at the roofline).
  ``autograd_graph_s``: the same step with ∇f's formulas on torch's autograd graph instead of the
  hand-written backward (:class:`~neural_bake.nets.gemm._ReverseScalar`; ``fused_backward_speedup`` is
  the ratio); ``ours_bf16_s``: the same step with the hidden GEMMs in bfloat16 (``SdfFitConfig.gemm_dtype``);
  ``compiled_s``: the same step with the loss through ``torch.compile`` (``SdfFitConfig.compile``, what
  fits of five minutes or more run), with the one-off ``compile_once_s`` it cost in this process.
- **accuracy vs time**: for each mesh and preset, :func:`~neural_bake.fit.sdf.fit_sdf` with the preset's
  time budget, then :func:`~neural_bake.fit.metrics.sdf_metrics` (Chamfer-L1, Hausdorff, normal error against
  the mesh's faces; unit frame; for the bundled samples also ∇f's normal error against the analytic surface,
  beside the mesh's own face normals' error against it) and the fit's targets ((256, 3): Hausdorff ≤ 0.005
  and median normal error ≤ 3° in 10 minutes; (64, 1): Hausdorff ≤ 0.01 in 2 minutes). A preset with an
  L-BFGS polish (``SdfFitConfig.polish_evals``) is also fitted without it, Adam for the whole budget — the
  loop a user would otherwise run — and the polished row carries the ratios ``*_vs_no_polish``.

Scope. Full run: the bundled samples ``bumpy_sphere``, ``torus``, ``jack`` plus ``spot`` and ``bunny`` from
the data folder (:func:`~neural_bake.bench.common.data_folder`) when present, × the six presets at their
budgets (2 + 2 + 5 + 8 + 10 + 10 minutes per mesh, and 2 more for 64x1 without its polish): about 40 minutes
per mesh, three and a half hours in all — run it on an otherwise idle machine. ``--quick``: the bumpy sphere only,
(64, 1) for 30 s and (256, 3) for 20 s with small pools, metrics on 20k samples at grid 96, and the step
timing at the default batch without the compiled column — under two minutes; its accuracy figures are NOT
the targets'.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from ..constants import LOSS_GRAD_FLOOR
from .common import data_folder, load_note, machine_info, timeit_interleaved

__all__ = ["run", "step_timing", "DATA_DIR"]

#: Where the shared real meshes live (spot, bunny); absent meshes are skipped with a note.
DATA_DIR = data_folder() or Path("shared") / "data"

TARGETS = {"256x3": {"hausdorff": 0.005, "normal_median_deg": 3.0}, "64x1": {"hausdorff": 0.01}}


def _autograd_terms(model, surf_p, surf_n, vol_p, vol_d, cfg) -> dict:
    """The baseline: the same losses with ∇f by autograd (create_graph=True → double-backward)."""
    from ..fit.sdf import focused_squares
    from ..fit.sdf_loss import smooth_angle

    s = surf_p.shape[0]
    pts = torch.cat([surf_p, vol_p]).requires_grad_(True)
    f = model(pts)
    (g,) = torch.autograd.grad(f.sum(), pts, create_graph=True)
    f = f[:, 0]
    gn = torch.linalg.vector_norm(g, dim=1)
    sq_surf = focused_squares(f[:s] ** 2, cfg.focus_tau)
    sq_vol = focused_squares((f[s:] - vol_d) ** 2, cfg.focus_tau)
    miss = 1.0 - (g[:s] * surf_n).sum(1) / gn[:s].clamp_min(LOSS_GRAD_FLOOR)
    loss = (cfg.w_surface * sq_surf.mean() + cfg.w_normal * miss.mean()
            + cfg.w_eikonal * ((1.0 - gn) ** 2).mean() + cfg.w_sdf * sq_vol.mean())
    if cfg.w_angle > 0:
        loss = loss + cfg.w_angle * smooth_angle(miss).mean()
    return {"loss": loss}


def step_timing(width: int, depth: int, *, batch: int = 4096, batch_near: int = 4096, batch_uniform: int = 1024,
                roof: dict | None = None, repeat: int = 5, seed: int = 0, compiled: bool = True) -> dict:
    """Seconds of one training step: GEMM-gradient losses (eager, bf16 GEMMs, and, with ``compiled``, through
    torch.compile where a compiler is available) vs double-backward autograd vs the roofline.

    ``ours_s`` and ``compiled_s`` are the steps a time-budgeted ``fit_sdf`` runs: the fastest of the
    micro-batch counts its tuner tries (:class:`~neural_bake.fit.sdf.MicroBatchTuner`), all timed in the same
    interleaved rounds (``eager_ms_by_parts``, ``compiled_ms_by_parts``: milliseconds by count;
    ``micro_batches`` is the rule's count, ``ours_micro_batches`` and ``compiled_micro_batches`` the fastest).
    The variants compared with ours (the autograd graph, bf16 GEMMs) run at the rule's count, and their ratios
    are to ours at that count."""
    from ..fit.sdf import MicroBatchTuner, SdfFitConfig, micro_batch_count, sdf_loss_terms, sdf_step_backward
    from ..nets.compiled import CompiledFn, compiler_available
    from ..nets.gemm import autograd_graph_only
    from ..nets.heap import keep_freed_memory
    from ..nets.siren import Siren
    from .roofline import best_rates, measure_roofline, roofline_seconds, siren_cost

    keep_freed_memory()  # as the training loop does: the steps timed here are the steps fit_sdf runs
    gen = torch.Generator().manual_seed(seed)
    model = Siren(width, depth, generator=gen)
    cfg = SdfFitConfig(width=width, depth=depth)
    sp = torch.rand(batch, 3, generator=gen) * 2 - 1
    sn = torch.nn.functional.normalize(torch.randn(batch, 3, generator=gen), dim=1)
    nv = batch_near + batch_uniform
    vp = torch.rand(nv, 3, generator=gen) * 2 - 1
    vd = torch.rand(nv, generator=gen) - 0.5
    opt = torch.optim.Adam(model.parameters(), lr=1e-5)

    micro = micro_batch_count(cfg, batch + nv, "cpu")
    counts = MicroBatchTuner(micro).candidates

    def step(fn, k=micro, low_precision=False):  # what fit_sdf runs: micro-batches, each forward + backward
        def go():
            opt.zero_grad(set_to_none=True)
            sdf_step_backward(fn, model, sp, sn, vp, vd, cfg, micro_batches=k, low_precision=low_precision)
            opt.step()
        return go

    def baseline():
        opt.zero_grad(set_to_none=True)
        _autograd_terms(model, sp, sn, vp, vd, cfg)["loss"].backward()
        opt.step()

    # interleaved (as bench normals): every method sees the same machine state; best of the repetitions
    def graph_step():  # the same step with ∇f on torch's autograd graph instead of the hand-written backward
        with autograd_graph_only():
            step(sdf_loss_terms)()

    methods = {("eager", k): step(sdf_loss_terms, k) for k in counts}
    methods.update({"graph": graph_step, "bf16": step(sdf_loss_terms, low_precision=True), "auto": baseline})
    compiled_fn = CompiledFn(sdf_loss_terms, enabled=compiled and compiler_available("cpu"),
                             desc=f"bench fit {width}x{depth}")
    t_compile = None
    if compiled_fn.enabled:
        t_compile = time.perf_counter()
        step(compiled_fn)()  # the compile itself (TorchInductor's on-disk cache makes repeats cheaper)
        t_compile = time.perf_counter() - t_compile
        if compiled_fn.compiled:
            methods.update({("compiled", k): step(compiled_fn, k) for k in counts})
    for fn in methods.values():
        fn()  # warm-up (and the compiles of the other counts' shapes)
    # the roofline is probed inside the same rounds (as in bench normals): this VM's sgemm rate drifts by
    # up to 2x over minutes, so a peak read at another moment would misstate the step's fraction
    probes = [roof] if roof else []
    methods["_roofline probe"] = lambda: probes.append(measure_roofline(quick=True, width=width))
    best = timeit_interleaved(methods, repeat)
    roof = best_rates(probes)
    eager = {k: best[("eager", k)] for k in counts}
    by_comp = {k: best[("compiled", k)] for k in counts if ("compiled", k) in best}
    k_ours = min(eager, key=eager.get)
    k_comp = min(by_comp, key=by_comp.get) if by_comp else None
    t_ours, t_rule, t_bf16, t_auto = eager[k_ours], eager[micro], best["bf16"], best["auto"]
    t_comp = by_comp[k_comp] if by_comp else None
    n = batch + nv
    c = siren_cost(width, depth, n, grad="reverse")
    train_cost = {"gemm_flops": 3 * c["gemm_flops"], "sines": 1.5 * c["sines"],
                  "flops": 3 * c["gemm_flops"] + 2 * (c["flops"] - c["gemm_flops"])}
    t_roof = roofline_seconds(train_cost, roof)
    return {"network": f"{width}x{depth}", "points": n, "ours_s": t_ours, "ours_bf16_s": t_bf16,
            "autograd_graph_s": best["graph"], "fused_backward_speedup": best["graph"] / t_rule,
            "autograd_2x_backward_s": t_auto, "speedup_vs_autograd": t_auto / t_ours,
            "bf16_speedup": t_rule / t_bf16, "roofline_s": t_roof, "fraction_of_roofline": t_roof / t_ours,
            "ours_over_roofline": t_ours / t_roof, "compiled_s": t_comp, "compile_once_s": t_compile,
            "compiled_speedup_vs_autograd": t_auto / t_comp if t_comp else None,
            "compiled_over_roofline": t_comp / t_roof if t_comp else None, "sgemm_gflops": roof["gflops_sgemm"],
            "micro_batches": micro, "ours_micro_batches": k_ours, "compiled_micro_batches": k_comp,
            "eager_ms_by_parts": _ms(eager), "compiled_ms_by_parts": _ms(by_comp) if by_comp else None}


def _parts(fit) -> str:
    """The micro-batch counts a fit ran at: how often its tuner chose each ("2x20 1x4": 2 parts in 20 of its
    tunings, 1 in 4), else the fixed count."""
    if fit.micro_batch_tuning:
        from collections import Counter

        return " ".join(f"{k}x{n}" for k, n in Counter(t["choice"] for t in fit.micro_batch_tuning).most_common())
    return str(fit.config.micro_batches or "rule")


def _ms(seconds_by_count: dict) -> dict:
    return {str(k): round(v * 1e3, 1) for k, v in sorted(seconds_by_count.items())}


def _meshes(quick: bool, names) -> tuple[list[tuple[str, object]], list[str]]:
    from ..io.mesh_io import load_mesh
    from ..samples import sample_path

    notes = []
    wanted = names or (["bumpy_sphere"] if quick else ["bumpy_sphere", "torus", "jack", "spot", "bunny"])
    out = []
    for name in wanted:
        if name in ("spot", "bunny"):
            folder = DATA_DIR / name
            objs = sorted(folder.glob("*.obj")) if folder.is_dir() else []
            if not objs:
                notes.append(f"{name}: no mesh under {folder}; skipped")
                continue
            out.append((name, load_mesh(objs[0])))
        else:
            out.append((name, load_mesh(sample_path(name))))
    return out, notes


def _analytic_normal(name: str, mesh):
    """The bundled sample ``name``'s analytic normals as a callable of unit-frame points (None for other meshes)."""
    from ..samples import SAMPLES, unit_frame_normals

    sample = SAMPLES.get(name)
    return None if sample is None else unit_frame_normals(sample, mesh.frame)


def run(quick: bool = False, *, meshes=None, presets=None, seed: int = 0, minutes: float | None = None,
        step_networks=None, save_dir=None, compare_polish: bool | None = None, clock=None) -> dict:
    """Run the benchmark (module docstring); returns the result dict of :mod:`neural_bake.bench.common`.

    Args:
        quick: the shrunken run (< 2 minutes).
        meshes: names among bumpy_sphere, torus, jack, sphere, spot, bunny (default: see the scope).
        presets: preset names (default: all six; quick: 64x1 and 256x3).
        seed: seed of every fit.
        minutes: override every preset's time budget.
        step_networks: (W, D) list of the step timing (default (64, 1) and (256, 3)).
        save_dir: also save each fitted model as ``save_dir/MESH-PRESET.nbm`` (the folder is created).
        compare_polish: for presets with an L-BFGS polish, also fit without it (default: in full runs only).
        clock: the clock the fits' budgets measure (default: the wall clock; tests pass a simulated one).
    """
    import warnings

    from ..errors import NeuralBakeWarning
    from ..fit.metrics import sdf_metrics
    from ..fit.sdf import PRESETS, fit_sdf
    from .roofline import measure_roofline

    t0 = time.perf_counter()
    roof = measure_roofline(quick=True)
    # --quick skips the compiled step: a cold TorchInductor cache alone can cost ~40 s of its two minutes
    step_rows = [step_timing(w, d, roof=roof, repeat=2 if quick else 5, compiled=not quick)
                 for w, d in (step_networks or [(64, 1), (256, 3)])]

    mesh_list, notes = _meshes(quick, meshes)
    presets = list(presets or (["64x1", "256x3"] if quick else list(PRESETS)))
    rows = []
    for name, mesh in mesh_list:
        for preset in presets:
            budget = minutes if minutes is not None else (
                {"64x1": 0.5, "256x3": 1 / 3}.get(preset, 0.25) if quick else PRESETS[preset]["minutes"])
            extra = dict(pool_surface=50_000, pool_near=50_000, pool_uniform=10_000) if quick else {}
            # a preset that polishes is also run without its polish (Adam for the whole budget), side by side
            variants = [("", {})]
            if PRESETS[preset].get("polish_evals") and (not quick if compare_polish is None else compare_polish):
                variants.append((" (no polish)", {"polish_evals": 0}))
            for suffix, change in variants:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", NeuralBakeWarning)
                    # face normals: the target this bench scores against (sdf_metrics' normal error)
                    fit = fit_sdf(mesh, preset=preset, minutes=budget, seed=seed, progress=False, clock=clock, **extra,
                                  **{"surface_normals": "face", **change})
                if save_dir is not None:
                    Path(save_dir).mkdir(parents=True, exist_ok=True)
                    fit.save(Path(save_dir) / f"{name}-{preset}{'-nopolish' if suffix else ''}.nbm")
                m = sdf_metrics(fit.model, mesh, n=20_000 if quick else 100_000, resolution=96 if quick else 256,
                                seed=seed, truth_normal=_analytic_normal(name, mesh))
                polish = fit.polish or {}
                row = {"mesh": name, "preset": preset + suffix, "minutes": budget, "steps": fit.steps,
                       "polish_evals": polish.get("evals", 0),
                       "polish_s": round(polish["seconds"], 3) if polish else 0.0,
                       "seconds": round(fit.seconds, 1), "micro_batches": _parts(fit),
                       "chamfer_l1": m["chamfer_l1"], "hausdorff": m["hausdorff"],
                       "normal_median_deg": m["normal_median_deg"], "normal_p95_deg": m["normal_p95_deg"],
                       "analytic_median_deg": m.get("normal_truth_median_deg"),
                       "mesh_faces_analytic_median_deg": m.get("mesh_normal_truth_median_deg")}
                target = TARGETS.get(preset)
                if target and not quick:
                    row["target_met"] = all(m[k] <= v for k, v in target.items())
                if suffix:  # the polished run's figures as ratios of this one's, measured in the same run
                    base = rows[-1]
                    for key in ("chamfer_l1", "hausdorff", "normal_median_deg"):
                        base[f"{key}_vs_no_polish"] = round(base[key] / row[key], 3) if row[key] else None
                rows.append(row)

    notes += [
        load_note(),
        f"roofline: {roof['gflops_sgemm']:.1f} GFLOP/s sgemm, {roof['gsin_per_s']:.3f} Gsin/s at the start "
        f"({roof['threads']} threads); each step row is priced at the best of that and of the probes read in "
        "its own interleaved rounds (its sgemm_gflops); the step's roofline is an approximation (module docstring)",
        "baseline: the same losses with ∇f from torch.autograd.grad(create_graph=True), i.e. double-backward",
        "normal errors at 100k mesh samples: normal_* against the mesh's face normals (floored by the mesh's "
        "faceting); for the bundled samples analytic_median_deg is ∇f against the analytic surface, beside "
        "mesh_faces_analytic_median_deg, the mesh's own face normals against it (the baseline: the mesh itself)",
        "polish: presets with an L-BFGS polish (SdfFitConfig.polish_evals) spend polish_s of their budget on it "
        "(Adam runs the rest); full runs also fit them without it ('(no polish)' rows: Adam for the whole "
        "budget), and *_vs_no_polish is the polished figure over that one (< 1: the polish lowered it)",
        "targets: (256,3) Hausdorff <= 0.005 and median normal error <= 3 deg within 10 min (bumpy sphere, spot); "
        "(64,1) Hausdorff <= 0.01 within 2 min" + ("; NOT checked in --quick (shortened budgets)" if quick else ""),
        f"total bench time {time.perf_counter() - t0:.0f} s",
    ]
    return {"name": "fit", "title": "SDF fitting: accuracy vs training time, and the training step",
            "machine": machine_info(), "quick": quick, "roofline": roof,
            "tables": {"training step": step_rows, "accuracy vs time": rows}, "notes": notes}
