"""`neural-bake bench batch`: assets per hour of `neural-bake batch` against the verbs run one after another.

The baseline is what a user would otherwise script: for each asset, ``fit sdf``, ``fit nested``, ``fit
texture`` and ``bake``, each a separate `neural-bake` process, one after another. The batch runs the same
stages with the same settings (fits bounded by steps, not time, so every run does the same work) with 1, 2
and 4 workers, each into a fresh output folder, and once more over a finished folder (every stage cached).
Every row gives the wall time, assets per hour and the ratio to the baseline measured in the same run, and
the median baked normal error against the samples' analytic surfaces (the same models: same seeds and steps).

Assets: full run, each of the four bundled samples twice (SDF seeds 0 and 1: eight assets, so that four
workers have work to share), the ``quick`` preset's networks with step caps; ``quick``: low-resolution copies
of the four samples and tiny fits, with 1, 2 and 4 workers too (a smoke run of the machinery).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from .common import last_error_line, load_note, machine_info, run_command

__all__ = ["run", "COLUMNS", "settings"]

COLUMNS = ["method", "workers", "threads", "assets", "ok", "seconds", "assets/hour", "× verbs", "normal err median °"]


def settings(quick: bool) -> dict:
    """Stage settings of the bench as ``{stage: {field: value}}`` (fits bounded by steps)."""
    if quick:
        return {"sdf": {"preset": "quick", "steps": 60, "minutes": 60.0, "polish_evals": 0, "compile": "off",
                        "micro_batches": 1},
                "nested": {"levels": "16x1", "steps": 30, "certify": False},
                "texture": {"preset": "quick", "steps": 30, "minutes": 60.0},
                "coarse": {"spec": "decimate:300"},
                "bake": {"size": 64, "baseline": False}}
    return {"sdf": {"preset": "quick", "steps": 1500, "minutes": 60.0, "polish_evals": 0, "compile": "off"},
            "nested": {"levels": "32x1", "steps": 300, "certify": False},
            "texture": {"preset": "quick", "steps": 600, "minutes": 60.0},
            "coarse": {"spec": "decimate:1000"},
            "bake": {"size": 512, "baseline": False}}


def _verb_commands(mesh: Path, out: Path, s: dict) -> list[list[str]]:
    """The four verbs with the settings of :func:`settings`."""
    sdf, nested, tex, bake = s["sdf"], s["nested"], s["texture"], s["bake"]
    return [
        ["fit", "sdf", str(mesh), "-o", str(out / "sdf.safetensors"), "--preset", sdf["preset"], "--steps",
         str(sdf["steps"]), "--minutes", str(sdf["minutes"]), "--polish-evals", str(sdf["polish_evals"]),
         "--compile", sdf["compile"], "--seed", str(sdf.get("seed", 0)), *(["--micro-batches", str(sdf["micro_batches"])] if "micro_batches" in sdf
                                        else []), "--no-metrics", "--no-progress"],
        ["fit", "nested", str(out / "sdf.safetensors"), "-o", str(out / "nested.safetensors"), "--levels",
         nested["levels"], "--steps", str(nested["steps"]), "--no-certify", "--no-progress"],
        ["fit", "texture", str(mesh), "--sdf", str(out / "sdf.safetensors"), "-o", str(out / "texture.safetensors"),
         "--preset", tex["preset"], "--steps", str(tex["steps"]), "--minutes", str(tex["minutes"]), "--no-metrics",
         "--no-progress"],
        ["bake", str(mesh), "--sdf", str(out / "sdf.safetensors"), "--texture-model", str(out / "texture.safetensors"),
         "--coarse", s["coarse"]["spec"], "--size", str(bake["size"]), *([] if bake["baseline"] else ["--no-baseline"]),
         "-o", str(out / "bake")],
    ]


def _median(values):
    values = sorted(v for v in values if v is not None)
    return values[len(values) // 2] if values else None


def _run_verbs(meshes: dict[str, Path], root: Path, s: dict) -> tuple[float, int, float | None]:
    t0 = time.perf_counter()
    ok, errors = 0, []
    for name, mesh in meshes.items():
        out = root / name
        out.mkdir(parents=True)
        seed = {"sdf": {**s["sdf"], "seed": int(name.endswith("_b"))}}
        for args in _verb_commands(mesh, out, {**s, **seed}):
            _, proc = run_command(args)
            if proc.returncode != 0:
                raise RuntimeError(f"bench batch: `neural-bake {' '.join(args[:2])}` on {name} failed: "
                                   f"{last_error_line(proc)}")
        ok += 1
        rep = json.loads((out / "bake" / "report.json").read_text())
        errors.append((rep.get("vs_truth_deg") or {}).get("median"))
    return time.perf_counter() - t0, ok, _median(errors)


def _run_batch(manifest: Path, out: Path, s: dict, workers: int) -> tuple[float, dict]:
    from ..pipelines.batch import BatchConfig, run_batch

    t0 = time.perf_counter()
    summary = run_batch(manifest, out, BatchConfig(preset="quick", stages=s, workers=workers, quiet=True),
                        log=lambda m: None)
    return time.perf_counter() - t0, summary


def run(quick: bool = False, workers: tuple[int, ...] | None = None) -> dict:
    """Measure; returns ``{"name", "rows", "notes", "machine", "quick", "settings"}``."""
    from ..samples.generate import sample_path, write_sample
    from ..samples.shapes import SAMPLES, get_sample

    s = settings(quick)
    workers = workers or (1, 2, 4)
    notes = []
    with tempfile.TemporaryDirectory(prefix="nb-bench-batch-") as tmp:
        root = Path(tmp)
        if quick:
            (root / "meshes").mkdir()
            meshes = {n: write_sample(get_sample(n).mesh(resolution=300, texture_size=64), root / "meshes", n)
                      for n in SAMPLES}
        else:  # each bundled sample twice (SDF seeds 0 and 1), so that 4 workers have 8 assets to share
            meshes = {f"{n}_{c}": sample_path(n) for n in SAMPLES for c in ("a", "b")}
        manifest = root / "assets.csv"
        manifest.write_text("mesh,name,sdf.seed\n" + "".join(f"{p},{name},{int(name.endswith('_b'))}\n"
                                                            for name, p in meshes.items()))
        n = len(meshes)
        seconds, ok, err = _run_verbs(meshes, root / "verbs", s)
        base_rate = 3600 * n / seconds
        rows = [{"method": "verbs one after another", "workers": 1, "threads": os.cpu_count(), "assets": n, "ok": ok,
                 "seconds": seconds, "assets/hour": base_rate, "× verbs": 1.0, "normal err median °": err}]
        for w in workers:
            out = root / f"batch-{w}"
            seconds, summary = _run_batch(manifest, out, s, w)
            errs = [((r["metrics"].get("bake") or {}).get("normal_deg_vs_truth") or {}).get("median")
                    for r in summary["assets"].values()]
            rows.append({"method": "batch", "workers": summary["workers"], "threads": summary["threads"], "assets": n,
                         "ok": summary["ok"], "seconds": seconds, "assets/hour": 3600 * n / seconds,
                         "× verbs": (3600 * n / seconds) / base_rate, "normal err median °": _median(errs)})
        seconds, summary = _run_batch(manifest, root / f"batch-{workers[-1]}", s, workers[-1])
        rows.append({"method": "batch, all cached", "workers": summary["workers"], "threads": summary["threads"],
                     "assets": n, "ok": summary["ok"], "seconds": seconds, "assets/hour": 3600 * n / seconds,
                     "× verbs": (3600 * n / seconds) / base_rate, "normal err median °": None})
        shutil.rmtree(root, ignore_errors=True)
    notes.append("same settings in every row: fits bounded by steps (not time), so every run does the same work; "
                 "the batch runs one process per asset, the verbs one per verb")
    if workers and max(workers) > (os.cpu_count() or 1):
        notes.append(f"{max(workers)} workers on {os.cpu_count()} cores: one torch thread each, oversubscribed")
    notes.append(load_note())
    return {"name": "batch", "title": "batch throughput: neural-bake batch against the verbs one after another",
            "quick": quick, "machine": machine_info(), "settings": s, "rows": rows, "notes": notes}
