"""`neural-bake bench nested`: nested sequences — what each level's δ costs in time, and how sure it is.

For each mesh a fine SDF f is fitted (or loaded with ``model_path``), then the coarse levels are built two
ways in the same run, with the same seed:

- **distilled** — :func:`~neural_bake.fit.nested.fit_nested` (Adam on the teacher's band, keeping the step
  with the smallest sup-norm; each level learns the next finer one);
- **direct fit** — the baseline a user would otherwise pick: each coarse level fitted to the mesh itself by
  :func:`~neural_bake.fit.sdf.fit_sdf` (same width and depth, the time the distilled level took), its
  sup-norm measured against the same finer level as the distilled one's.

Per level: training seconds, the sampled sup-norm |h − g| on the Δ-band (``sup_estimated``, with the
seconds the estimate took), the certified one (range analysis: a guaranteed bound) with its seconds and its
ratio to the estimate, the resulting δ (Prop. 1), and ``sup_vs_direct`` (distilled over direct: < 1, the
distilled level nests tighter). The second table is the estimate's stability over sample sizes and Δ (the
paper's Table 5) for the distilled sequence.

Scope. Full run: the bumpy sphere and, when present, Spot; f is the 128x2 preset (5 minutes); levels 64x1 and
256x1, 2,000 Adam steps each; about 9 minutes per mesh (17 in all here). ``--quick``: the bumpy sphere, f a 64x1 fit of 20 s,
levels 16x1 and 32x1 of 300 steps, 2,000 boxes of certification: under two minutes.
"""

from __future__ import annotations

import time
import warnings

from .common import load_note, machine_info

__all__ = ["run"]


def _fine(name: str, mesh, quick: bool, seed: int, model_path):
    from ..fit.sdf import fit_sdf, load_sdf

    if model_path:
        return load_sdf(model_path), 0.0
    if quick:
        fit = fit_sdf(mesh, preset="64x1", minutes=20 / 60, seed=seed, polish_evals=0, progress=False)
    else:
        fit = fit_sdf(mesh, preset="128x2", seed=seed, progress=False)
    return fit, fit.seconds


def _level_rows(mesh_name: str, seq, levels) -> list[dict]:
    rows = []
    for i, (w, d) in enumerate(levels):
        info = seq.levels_info[i]
        cert, est = info.get("sup_certified"), info["sup_estimated"]
        rows.append({"mesh": mesh_name, "level": f"{w}x{d}", "method": "distilled", "seconds": info["seconds"],
                     "steps": info["steps"], "sup_estimated": est, "estimate_s": info["estimate_seconds"],
                     "sup_certified": cert, "certify_s": (info.get("certify") or {}).get("seconds"),
                     "certified_over_estimated": cert / est if cert is not None and est > 0 else None,
                     "delta": info["delta"], "delta_source": info["delta_source"]})
    return rows


def run(quick: bool = False, *, meshes=None, model_path=None, levels=None, steps: int | None = None,
        seed: int = 0, certify_max_boxes: int | None = None) -> dict:
    """Run the benchmark (module docstring); returns the result dict of :mod:`neural_bake.bench.common`.

    Args:
        quick: the shrunken run (< 2 minutes).
        meshes: names among bumpy_sphere, torus, jack, sphere, spot, bunny (default: see the scope); with
            ``model_path``, the first is the mesh the model was fitted to (for the direct-fit baseline).
        model_path: a fine SDF file to use instead of fitting one (then only the first mesh is run).
        levels: coarse levels as (W, D), coarse to fine (default: see the scope).
        steps: Adam steps per level.
        seed: seed of every fit. certify_max_boxes: the certification's box budget.
    """
    from ..errors import NeuralBakeWarning
    from ..fit.nested import estimate_sup_norm, fit_nested
    from ..fit.sdf import fit_sdf
    from .fit import _meshes

    t0 = time.perf_counter()
    levels = [tuple(lv) for lv in (levels or ([(16, 1), (32, 1)] if quick else [(64, 1), (256, 1)]))]
    steps = int(steps or (300 if quick else 2000))
    boxes = int(certify_max_boxes or (2000 if quick else 20_000))
    names = meshes or (["bumpy_sphere"] if quick else ["bumpy_sphere", "spot"])
    mesh_list, notes = _meshes(quick, names[:1] if model_path else names)
    common = dict(steps=steps, seed=seed, progress=False, max_boxes=boxes)
    if quick:
        common.update(pool=50_000, n_estimate=20_000, eval_samples=5_000, stability_samples=(1_000, 10_000))
    rows, stability = [], []
    for name, mesh in mesh_list:
        fine, fine_s = _fine(name, mesh, quick, seed, model_path)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", NeuralBakeWarning)
            base = fit_nested(fine, mesh=mesh, levels=levels, **common)
        notes += [f"{name}: {w.message}" for w in caught if issubclass(w.category, NeuralBakeWarning)]
        dist_rows = _level_rows(name, base, levels)
        for i, (w, d) in enumerate(levels):
            stability += [{"mesh": name, "level": f"{w}x{d}", **r} for r in base.stability[i]]
        # the baseline: each level fitted to the mesh directly, in the time its distilled version took
        n_est = common.get("n_estimate", 100_000)
        for i, (w, d) in enumerate(levels):
            budget = max(base.levels_info[i]["seconds"], 1.0) / 60
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NeuralBakeWarning)
                direct = fit_sdf(mesh, width=w, depth=d, minutes=budget, steps=10**7, seed=seed, progress=False,
                                 compile="off")
            finer = base.levels[i + 1]
            sup = estimate_sup_norm(direct.model, finer, band=base.band, n=n_est, seed=seed + 17 * i)
            dist_rows[i]["sup_vs_direct"] = dist_rows[i]["sup_estimated"] / sup if sup > 0 else None
            rows += [dist_rows[i], {"mesh": name, "level": f"{w}x{d}", "method": "direct fit (baseline)",
                                    "seconds": round(direct.seconds, 3), "steps": direct.steps, "sup_estimated": sup,
                                    "estimate_s": None, "sup_certified": None, "certify_s": None,
                                    "certified_over_estimated": None, "delta": None, "delta_source": None}]
        notes.append(f"{name}: fine SDF {fine.model.width}x{fine.model.depth}"
                     + (f" fitted in {fine_s:.0f} s" if fine_s else f" loaded from {model_path}"))
    notes += [
        load_note(),
        "sup_estimated: |h - g| sampled on the band {|h| < Δ or |g| < Δ}, g the next finer level (f for the "
        "finest); sup_certified: range analysis over boxes covering the band (a guaranteed bound when its "
        "search completed); delta: Prop. 1's threshold from the certified sup where certification met its "
        "target, else the estimate",
        "baseline: each coarse level fitted to the mesh directly (fit_sdf, same W and D, the time its distilled "
        "version took), its sampled sup-norm against the same finer level; sup_vs_direct = distilled / direct",
        f"levels {', '.join(f'{w}x{d}' for w, d in levels)}; {steps} Adam steps per level",
        f"total bench time {time.perf_counter() - t0:.0f} s",
    ]
    return {"name": "nested", "title": "Nested sequences: each level's sup-norm |h - g| and δ against time",
            "machine": machine_info(), "quick": quick,
            "tables": {"levels": rows, "estimate stability (distilled)": stability}, "notes": notes}
