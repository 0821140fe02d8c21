"""Batch runs: many assets through the stages of :mod:`.stages`, on a local process pool or a Ray cluster.

``run_batch(manifest, out, config)`` reads the manifest (:mod:`.manifest`), merges for each asset the preset,
the batch's stage options and the asset's own overrides, checks them all before any work (a bad option fails
that asset alone), runs the assets and writes OUT/batch.json: every asset with its status, the time of each
stage, its headline metrics and, for a failure, the one-line reason. The summary is rewritten after each
asset, so a batch that dies keeps the record of what it finished; a re-run skips every unchanged stage.

One batch per folder: a batch holds OUT's :class:`~neural_bake.io.outdir.OutputLock` from the manifest's
check to the index page, so a second batch (or any other verb) writing OUT fails at once naming the first.
The summary is merged: the assets an earlier batch recorded in OUT/batch.json and this manifest does not name
stay in it, each record's ``run`` says which batch produced it (``runs`` lists them, numbered from 1), and
the counts ``ok``, ``failed`` and ``pending`` are this batch's (``earlier``: the assets kept from before).

Execution. ``executor="local"`` (default): each asset runs in its own fresh process (spawned), at most
``workers`` at a time, each limited to ``threads`` torch threads with workers × threads ≤ the cores this
process may use. A worker that dies (killed, out of memory) fails its asset only; the others go on.
Ctrl-C stops the workers, records the unfinished assets as interrupted and re-raises KeyboardInterrupt.
``executor="ray"``: one Ray task per asset (``ray.init(address)``; a local instance when no address), one CPU
per torch thread and one GPU per task when the device is CUDA; OUT must be on storage every node shares.
"""

from __future__ import annotations

import copy
import dataclasses
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

from neural_bake.errors import NeuralBakeError

from .bake_asset import PRESETS as BAKE_PRESETS
from .manifest import STAGE_NAMES, AssetSpec, read_manifest

__all__ = ["BatchConfig", "PRESETS", "run_batch", "run_preset_batches", "parse_presets", "COMPARE_DIR", "plan_workers", "SUMMARY_NAME", "EXECUTORS", "usable_cores",
           "OutputNotWritable", "summary_lines",
           "batch_config", "resolved_config"]

#: The summary of a batch, in OUT.
SUMMARY_NAME = "batch.json"
SUMMARY_FORMAT = "neural_bake.batch.v1"
EXECUTORS = ("local", "ray")

#: Stage options of the batch presets; the names are the fits' own (:mod:`neural_bake.fit.presets`).
#: quick: about a minute per asset on a 2-core CPU (smoke runs: the quick fits at shorter budgets, the SDF
#: the small 64x1 network, which a 24-second budget trains further than the quick preset's);
#: default: the fits' default presets; high: the largest networks and longest budgets.
PRESETS: dict[str, dict[str, dict]] = {
    "quick": {
        "sdf": {"preset": "64x1", "minutes": 0.4},
        "nested": {"preset": "quick"},
        "texture": {"preset": "quick", "minutes": 0.2},
        "coarse": {"spec": BAKE_PRESETS["quick"]["coarse"]},
        "bake": {"preset": "quick"},
    },
    "default": {
        "sdf": {"preset": "default"},
        "nested": {"preset": "default"},
        "texture": {"preset": "default"},
        "coarse": {"spec": BAKE_PRESETS["default"]["coarse"]},
        "bake": {"preset": "default"},
    },
    "high": {
        "sdf": {"preset": "high"},
        "nested": {"preset": "high"},
        "texture": {"preset": "high"},
        "coarse": {"spec": BAKE_PRESETS["high"]["coarse"]},
        "bake": {"preset": "high"},
    },
}


@dataclass
class BatchConfig:
    """Settings of :func:`run_batch`; one line per field."""

    preset: str = "default"
    """Stage settings preset: quick (about a minute per asset), default or high (:data:`PRESETS`)."""
    stages: dict[str, dict] = field(default_factory=dict)
    """Stage options over the preset's, ``{stage: {field: value}}`` (a manifest row's override these)."""
    workers: int = 0
    """Assets run at once (0: the usable cores // 2, at least 1)."""
    threads: int = 0
    """Torch threads per worker (0: usable cores // workers, at least 1)."""
    executor: str = "local"
    """"local" (a process pool on this machine) or "ray"."""
    address: str | None = None
    """Ray cluster address (executor "ray"; None: start a local Ray instance)."""
    seed: int | None = None
    """Seed of every fit (None: each stage's own default)."""
    device: str | None = None
    """Torch device of the fits ("cpu", "cuda", …; None: each stage's default, the CPU)."""
    quiet: bool = False
    """Print only the summary (no per-stage lines)."""
    verbose: bool = False
    """Also print the bake's own lines."""


class OutputNotWritable(NeuralBakeError):
    """The output folder cannot be created or written (permissions, read-only file system): exit code 1."""

    exit_code = 1


def batch_config(table: dict | None = None, *, where: str = "config", **overrides) -> BatchConfig:
    """A BatchConfig from a settings table (a TOML file's: batch fields at the top, one table per stage) with
    ``overrides`` (the command line's) applied last; NeuralBakeError naming ``where`` and the key otherwise."""
    table = dict(table or {})
    names = {f.name for f in dataclasses.fields(BatchConfig)} - {"stages"}
    stages: dict[str, dict] = {}
    values = {}
    for k, v in table.items():
        if k in STAGE_NAMES:
            if not isinstance(v, dict):
                raise NeuralBakeError(f"{where}: [{k}] must be a table of {k} settings")
            stages[k] = dict(v)
        elif k in names:
            values[k] = None if v == "none" else v
        else:
            raise NeuralBakeError(f"{where}: unknown key {k!r} (batch settings: {', '.join(sorted(names))}; "
                                  f"stage tables: {', '.join(STAGE_NAMES)})")
    for stage, opts in (overrides.pop("stages", None) or {}).items():
        stages.setdefault(stage, {}).update(opts)
    cfg = BatchConfig(**{**values, **overrides, "stages": stages})
    from neural_bake.constants import MAX_BATCH_THREADS, MAX_BATCH_WORKERS
    from neural_bake.limits import check_count

    check_count(cfg.workers, "workers", MAX_BATCH_WORKERS, minimum=0, what="0: auto")
    check_count(cfg.threads, "threads", MAX_BATCH_THREADS, minimum=0, what="0: auto")
    return cfg


def resolved_config(cfg: BatchConfig) -> tuple[dict, dict]:
    """(table, comments) of ``cfg`` with every stage's settings resolved (preset, config, command line), as
    ``--print-config`` writes it: a TOML file that gives the same run."""
    from neural_bake.configs import field_docs

    from .stages import _stage_classes, resolve_stages, stage_key_config

    if cfg.preset not in PRESETS:
        raise NeuralBakeError(f"preset {cfg.preset!r}: unknown (choose from {', '.join(PRESETS)})")
    resolved = resolve_stages(_batch_options(cfg))
    table = {k: v for k, v in asdict(cfg).items() if k != "stages"}
    comments = {k: field_docs(BatchConfig).get(k, "") for k in table}
    classes = _stage_classes()
    for stage in STAGE_NAMES:
        table[stage] = {k: v for k, v in stage_key_config(resolved[stage]).items()
                        if not (stage == "bake" and k in ("coarse", "texture"))}  # coarse.spec; per asset
        comments[stage] = {k: field_docs(classes[stage]).get(k, "").split(". ")[0] for k in table[stage]}
    return table, comments


def usable_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def plan_workers(workers: int, threads: int, n_assets: int, cores: int | None = None,
                 busy: float | None = None) -> tuple[int, int]:
    """(workers, threads per worker): workers ≤ assets; 0 means auto; threads = cores // workers when auto.

    Auto plans for the machine as it is: ``busy`` cores (default: the 1-minute load average, taken before
    any worker starts, so it counts other programs) are left out of the cores the workers share. Each
    worker's fits and bakes then choose their threads by measurement up to its share
    (:mod:`neural_bake.nets.threads`)."""
    cores = cores or usable_cores()
    if workers < 0 or threads < 0:
        raise NeuralBakeError(f"workers {workers} / threads {threads}: must be >= 0 (0: auto)")
    if busy is None:
        try:
            busy = os.getloadavg()[0]
        except OSError:  # no load average on this platform
            busy = 0.0
    free = max(1, cores - int(round(max(0.0, float(busy))))) if not workers else cores
    w = workers or max(1, free // 2)
    w = max(1, min(w, n_assets))
    t = threads or max(1, (free if not workers else cores) // w)
    return w, t


def _merge(*layers: dict) -> dict:
    out: dict[str, dict] = {}
    for layer in layers:
        for stage, opts in (layer or {}).items():
            out.setdefault(stage, {}).update(opts)
    return out


def _batch_options(cfg: BatchConfig) -> dict[str, dict]:
    """The stage options of every asset before its manifest row's: preset, seed and device, ``cfg.stages``."""
    common: dict[str, dict] = {}
    if cfg.seed is not None:
        common = {"sdf": {"seed": cfg.seed}, "nested": {"seed": cfg.seed}, "texture": {"seed": cfg.seed}}
    if cfg.device is not None:
        common = _merge(common, {stage: {"device": cfg.device} for stage in ("sdf", "nested", "texture", "bake")})
    return _merge(copy.deepcopy(PRESETS[cfg.preset]), common, cfg.stages)


def _tasks(assets: list[AssetSpec], out: Path, cfg: BatchConfig, threads: int) -> tuple[list[dict], list[dict]]:
    """(tasks to run, records of assets refused before running: bad options or output paths)."""
    from neural_bake.io.paths import inside

    from .stages import resolve_stages

    batch_options = _batch_options(cfg)
    tasks, refused = [], []
    for a in assets:
        options = _merge(batch_options, a.options)
        try:
            if not Path(a.mesh).is_file():
                raise NeuralBakeError(f"{a.mesh}: no such mesh file" if not Path(a.mesh).exists()
                                      else f"{a.mesh}: not a file")
            folder = inside(out, a.name, what="name")
            resolve_stages(options)
        except NeuralBakeError as exc:
            refused.append({"name": a.name, "mesh": a.mesh, "status": "failed", "reason": f"{a.where}: {exc}",
                            "stages": {s: {"status": "not run", "seconds": 0.0} for s in STAGE_NAMES},
                            "metrics": {}, "seconds": 0.0})
            continue
        tasks.append({"name": a.name, "mesh": a.mesh, "texture": a.texture, "folder": str(folder.resolve()),
                      "options": options, "threads": threads, "quiet": cfg.quiet, "verbose": cfg.verbose,
                      "where": a.where})
    return tasks, refused


def _check_out(out: Path) -> None:
    """OUT is (or can be made) a folder this process can write; one line otherwise."""
    if out.exists() and not out.is_dir():
        raise NeuralBakeError(f"-o {out}: exists and is not a folder")
    from neural_bake.io.atomic import link_target

    try:
        link_target(out).mkdir(parents=True, exist_ok=True)  # a dangling symlink: its folder made where it points
        probe = out / f".batch-probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise OutputNotWritable(f"{out}: cannot write the output folder ({exc.strerror or exc})") from None


def run_batch(manifest, out, config: BatchConfig | None = None, *, log: Callable[[str], None] = print,
              on_event: Callable[..., None] | None = None) -> dict:
    """Run every asset of ``manifest`` into folder ``out``; return the summary also written to OUT/batch.json.

    ``on_event(kind, name, **info)`` is called in this process: ``("start", name, pid=…)`` when a worker
    starts an asset (pid: the local worker's process id, None under Ray) and ``("end", name, record=…)``.
    Raises NeuralBakeError (nothing run, nothing written) for a manifest that cannot run (:mod:`.manifest`), a
    bad preset, executor, worker count or stage option of ``config`` (a manifest row's bad value fails that
    asset alone), and an output folder that cannot be written (or another batch writing it: OutputBusyError);
    returns normally when assets failed (see the summary's ``failed`` count).
    """
    cfg = config or BatchConfig()
    if cfg.preset not in PRESETS:
        raise NeuralBakeError(f"preset {cfg.preset!r}: unknown (choose from {', '.join(PRESETS)})")
    if cfg.executor not in EXECUTORS:
        raise NeuralBakeError(f"executor {cfg.executor!r}: unknown (choose from {', '.join(EXECUTORS)})")
    bad = sorted(set(cfg.stages) - set(STAGE_NAMES))
    if bad:
        raise NeuralBakeError(f"stage {bad[0]!r}: unknown (stages: {', '.join(STAGE_NAMES)})")
    assets = read_manifest(manifest)
    from .stages import resolve_stages

    resolve_stages(_batch_options(cfg))  # the batch's own stage options, before any work: bad ones fail every asset
    out = Path(out)
    _check_out(out)
    from neural_bake.io.outdir import OutputLock

    with OutputLock(out):  # one batch per folder; the summary below merges what earlier batches left
        return _run_locked(manifest, out, cfg, assets, log, on_event)


def _run_locked(manifest, out: Path, cfg: BatchConfig, assets: list[AssetSpec], log: Callable[[str], None],
                on_event: Callable[..., None] | None) -> dict:
    """:func:`run_batch`'s work, under OUT's lock."""
    workers, threads = plan_workers(cfg.workers, cfg.threads, len(assets))
    tasks, refused = _tasks(assets, out, cfg, threads)
    t0 = time.perf_counter()
    earlier = _earlier_summary(out)
    runs = list(earlier.get("runs") or [])
    run = max((int(r.get("run", 0)) for r in runs), default=0) + 1
    runs.append({"run": run, "manifest": os.fspath(manifest), "preset": cfg.preset, "assets": len(assets)})
    mine = [a.name for a in assets]
    merged: dict[str, dict | None] = {}
    for name, rec in (earlier.get("assets") or {}).items():  # earlier batches' assets, this manifest's replaced
        merged[name] = None if name in mine else {**(rec or _not_finished(name, "interrupted")), "run": _rec_run(rec)}
    merged.update({name: None for name in mine if name not in merged})
    summary = {"format": SUMMARY_FORMAT, "manifest": os.fspath(manifest), "out": str(out.resolve()),
               "config": asdict(cfg), "executor": cfg.executor, "workers": workers, "threads": threads,
               "run": run, "runs": runs, "assets": merged}
    for r in refused:
        summary["assets"][r["name"]] = {**r, "run": run}
        log(f"[{r['name']}] failed: {r['reason']}")

    def record(rec: dict) -> None:
        summary["assets"][rec["name"]] = {**rec, "run": run}
        _write_summary(out, summary, time.perf_counter() - t0)
        if on_event:
            on_event("end", rec["name"], record=rec)

    kept = len(merged) - len(mine)
    log(f"batch: {len(assets)} assets ({len(refused)} refused), preset {cfg.preset}, {cfg.executor} executor, "
        f"{workers} worker(s) x {threads} thread(s)"
        + (f"; the summary keeps {kept} asset(s) of earlier batches in {out}" if kept else ""))
    try:
        tasks = _skip_cached(tasks, record, log if not cfg.quiet else lambda m: None)
        if cfg.executor == "local":
            _run_local(tasks, workers, record, on_event)
        else:
            _run_ray(tasks, cfg, workers, threads, record, on_event)
    except KeyboardInterrupt:
        for name in mine:
            if summary["assets"][name] is None:
                summary["assets"][name] = {**_not_finished(name, "interrupted"), "run": run}
        _write_summary(out, summary, time.perf_counter() - t0)
        raise
    summary = _write_summary(out, summary, time.perf_counter() - t0)
    for line in summary_lines(summary):
        log(line)
    _write_index(out, summary, log)
    return summary


#: Where a batch over several presets writes its per-asset comparison pages, in OUT.
COMPARE_DIR = "compare"


def parse_presets(text: str) -> list[str]:
    """The preset names of ``text`` ("quick", or comma-separated "quick,default,high"), each once, in order;
    NeuralBakeError naming the unknown one."""
    names = list(dict.fromkeys(p.strip() for p in str(text).split(",") if p.strip()))
    if not names:
        raise NeuralBakeError(f"preset {text!r}: give a preset name (choose from {', '.join(PRESETS)})",
                              parameter="preset")
    for name in names:
        if name not in PRESETS:
            raise NeuralBakeError(f"preset {name!r}: unknown (choose from {', '.join(PRESETS)})", parameter="preset")
    return names


def run_preset_batches(manifest, out, config: BatchConfig | None = None, presets=("quick", "default", "high"), *,
                       log: Callable[[str], None] = print, on_event: Callable[..., None] | None = None,
                       compare_views: int = 8) -> dict:
    """Run the batch of ``manifest`` once per preset and compare the presets asset by asset.

    Layout of ``out``: ``out/PRESET/`` is each preset's batch folder (as :func:`run_batch` writes it: one
    folder per asset, batch.json, index.html); ``out/compare/ASSET/index.html`` compares the presets' bakes
    of each asset that at least two presets baked (:func:`neural_bake.view.comparison.write_comparison`);
    ``out/index.html`` lists every asset under every preset with a link to its comparison. A preset's
    ``config`` is ``config`` with that preset (its stage options, seed, workers … apply to every preset).

    Returns ``{"presets": {preset: its batch summary}, "comparisons": {asset: path}, "failed": count}``.
    """
    from neural_bake.io.outdir import OutputLock
    from neural_bake.view.comparison import CompareConfig, write_comparison

    cfg = config or BatchConfig()
    names = parse_presets(",".join(presets))
    out = Path(out)
    _check_out(out)
    summaries = {}
    for name in names:
        log(f"batch: preset {name} into {out / name}")
        summaries[name] = run_batch(manifest, out / name, dataclasses.replace(cfg, preset=name), log=log,
                                    on_event=on_event)
    comparisons: dict[str, Path] = {}
    with OutputLock(out / COMPARE_DIR):
        assets = list(dict.fromkeys(a for s in summaries.values() for a in s["assets"]))
        for asset in assets:
            done = [p for p in names if (summaries[p]["assets"].get(asset) or {}).get("status") == "ok"]
            if len(done) < 2:
                continue
            (out / COMPARE_DIR).mkdir(exist_ok=True)
            try:
                comparisons[asset] = write_comparison([out / p / asset / "bake" for p in done],
                                                      out / COMPARE_DIR / asset, CompareConfig(views=compare_views),
                                                      names=done, log=lambda m: None)
            except (NeuralBakeError, OSError) as exc:  # a page that cannot be written costs one line
                log(f"[{asset}] no comparison page ({exc})")
                continue
            log(f"[{asset}] presets compared: {comparisons[asset]}")
    _write_preset_index(out, names, summaries, comparisons, log)
    return {"presets": summaries, "comparisons": {k: str(v) for k, v in comparisons.items()},
            "failed": sum(s["failed"] for s in summaries.values())}


def _write_preset_index(out: Path, names: list[str], summaries: dict, comparisons: dict, log) -> None:
    """OUT/index.html: every asset under every preset (rows asset by asset), each linking its comparison."""
    from neural_bake.view.index import write_batch_index

    folders, rows, reasons, extra = [], [], [], []
    assets = list(dict.fromkeys(a for s in summaries.values() for a in s["assets"]))
    for asset in assets:
        for p in names:
            rec = summaries[p]["assets"].get(asset)
            if rec is None and asset not in summaries[p]["assets"]:
                continue
            folders.append(out / p / asset / "bake")
            rows.append(f"{asset} · {p}")
            reasons.append((rec or {}).get("reason") if (rec or {}).get("status") != "ok" else None)
            extra.append({"preset": p, **_index_columns(rec), "comparison": comparisons.get(asset)})
    try:
        page = write_batch_index(folders, out / INDEX_NAME, names=rows, reasons=reasons, extra=extra)
    except (NeuralBakeError, OSError) as exc:
        log(f"batch: no index page ({exc})")
        return
    log(f"batch: index {page}")


def _rec_run(rec: dict | None) -> int:
    """The run that produced an earlier summary's record (1: a summary written before runs were numbered)."""
    run = (rec or {}).get("run")
    return int(run) if isinstance(run, int) and not isinstance(run, bool) else 1


def _earlier_summary(out: Path) -> dict:
    """OUT/batch.json of the batches run into OUT before ({} when there is none or it is not a summary); an
    asset without a record (its batch stopped) comes back as None."""
    import json

    try:
        earlier = json.loads((out / SUMMARY_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(earlier, dict) or earlier.get("format") != SUMMARY_FORMAT:
        return {}
    assets = earlier.get("assets")
    runs = earlier.get("runs")
    if not isinstance(assets, dict):
        return {}
    assets = {str(k): v if isinstance(v, dict) else None for k, v in assets.items()}
    if not isinstance(runs, list) or not all(isinstance(r, dict) for r in runs):
        runs = [{"run": 1, "manifest": earlier.get("manifest")}]
    return {"assets": assets, "runs": runs}


def _skip_cached(tasks: list[dict], record: Callable[[dict], None], log: Callable[[str], None]) -> list[dict]:
    """Record the assets whose every stage is cached here, with no worker process; return the others."""
    from .stages import cached_record

    todo = []
    for task in tasks:
        rec = cached_record(task)
        if rec is None:
            todo.append(task)
            continue
        log(f"[{task['name']}] every stage unchanged, skipped")
        record(rec)
    return todo


#: The batch's HTML index (a row per asset: thumbnail, status, headline metrics, failure), in OUT.
INDEX_NAME = "index.html"


def _write_index(out: Path, summary: dict, log: Callable[[str], None]) -> None:
    """OUT/index.html over every asset's bake folder; a page that cannot be written costs one line, not the batch."""
    from neural_bake.errors import NeuralBakeError
    from neural_bake.view.index import write_batch_index

    names = list(summary["assets"])
    reasons = [(r or {}).get("reason") if (r or {}).get("status") != "ok" else None
               for r in summary["assets"].values()]
    extra = [_index_columns(r) for r in summary["assets"].values()]
    try:
        page = write_batch_index([out / n / "bake" for n in names], out / INDEX_NAME, names=names, reasons=reasons,
                                 extra=extra)
    except (NeuralBakeError, OSError) as exc:
        log(f"batch: no index page ({exc})")
        return
    log(f"batch: index {page}")


def _index_columns(rec: dict | None) -> dict:
    """The index page's batch columns of an asset: the batch run that produced it, and per time-budgeted fit
    stage the steps made of the steps expected in its budget (marked "!" below half)."""
    cells = []
    for stage, b in ((rec or {}).get("budget") or {}).items():
        expected = "?" if b.get("expected_steps") is None else f"~{b['expected_steps']}"
        cells.append(f"{stage} {b.get('steps')} of {expected}" + (" !" if b.get("warning") else ""))
    return {"run": (rec or {}).get("run"), "steps made of expected": ", ".join(cells) or None}


def _not_finished(name: str, status: str) -> dict:
    return {"name": name, "status": status, "reason": f"{status} before the asset finished (a re-run resumes it)",
            "stages": {}, "metrics": {}, "seconds": 0.0}


def _write_summary(out: Path, summary: dict, seconds: float) -> dict:
    from neural_bake.io.atomic import atomic_write_text
    from neural_bake.io.jsonio import dumps

    mine = [r for r in summary["assets"].values() if _this_run(summary, r)]  # the counts are this batch's
    recs = [r for r in mine if r is not None]
    summary["seconds"] = seconds
    summary["ok"] = sum(r["status"] == "ok" for r in recs)
    summary["failed"] = sum(r["status"] == "failed" for r in recs)
    summary["pending"] = len(mine) - summary["ok"] - summary["failed"]
    summary["earlier"] = len(summary["assets"]) - len(mine)
    atomic_write_text(out / SUMMARY_NAME, dumps(summary))
    return summary


def _this_run(summary: dict, rec: dict | None) -> bool:
    """Whether an asset's record (None: not finished yet) belongs to the batch that wrote ``summary``."""
    return rec is None or rec.get("run", summary.get("run")) == summary.get("run")


def summary_lines(summary: dict) -> list[str]:
    """The terminal table: one line per asset of this batch (status, seconds per stage, headline metric or
    reason), then the count of earlier batches' assets the summary keeps."""
    lines = [f"{'asset':<24} {'status':<11} " + " ".join(f"{s:>8}" for s in STAGE_NAMES) + "  result"]
    for name, r in summary["assets"].items():
        if not _this_run(summary, r):
            continue
        r = r or _not_finished(name, "pending")
        cells = []
        for s in STAGE_NAMES:
            st = r["stages"].get(s, {})
            status = st.get("status", "-")
            cells.append(f"{st.get('seconds', 0):>7.1f}s" if status == "done" else f"{status:>8}"[:8])
        if r["status"] == "ok":
            m = r["metrics"].get("bake", {})
            tail = []
            for key, label in (("normal_deg_vs_truth", "normal err"), ("normal_deg_vs_gradient", "vs grad f")):
                if key in m:
                    tail.append(f"{label} median {m[key]['median']:.2f}°")
                    break
            if m.get("color_psnr_db") is not None:
                tail.append(f"albedo {m['color_psnr_db']:.1f} dB")
            result = ", ".join(tail)
        else:
            result = r.get("reason") or ""
        lines.append(f"{name[:24]:<24} {r['status']:<11} " + " ".join(cells) + f"  {result}")
    lines.append(f"batch: {summary['ok']} ok, {summary['failed']} failed"
                 + (f", {summary['pending']} not finished" if summary.get("pending") else "")
                 + f" in {summary['seconds']:.0f} s; summary in {Path(summary['out']) / SUMMARY_NAME}"
                 + (f" (with {summary['earlier']} asset(s) of earlier batches)" if summary.get("earlier") else ""))
    return lines


# ----------------------------------------------------------------------------------------------------------
# executors


def _worker_main(task: dict, conn) -> None:
    """Entry of a local worker process: run the asset, send its record back."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group: the parent stops us
    from .stages import run_asset

    conn.send(run_asset(task))
    conn.close()


def _run_local(tasks: list[dict], workers: int, record: Callable[[dict], None], on_event) -> None:
    import multiprocessing as mp
    from multiprocessing.connection import wait

    ctx = mp.get_context("spawn")
    queue = list(tasks)
    running: dict = {}  # sentinel -> (process, reader, task)
    try:
        while queue or running:
            while queue and len(running) < workers:
                task = queue.pop(0)
                reader, writer = ctx.Pipe(duplex=False)
                proc = ctx.Process(target=_worker_main, args=(task, writer), name=f"neural-bake {task['name']}",
                                   daemon=True)
                proc.start()
                writer.close()
                running[proc.sentinel] = (proc, reader, task)
                if on_event:
                    on_event("start", task["name"], pid=proc.pid)
            ready = wait(list(running) + [r for _, r, _ in running.values()])
            for key in list(running):
                proc, reader, task = running[key]
                if key not in ready and reader not in ready:
                    continue
                rec = None
                try:
                    if reader.poll():
                        rec = reader.recv()
                except (EOFError, OSError):
                    rec = None
                if rec is None and proc.is_alive():
                    continue  # the pipe closed first; the exit comes next
                proc.join()
                reader.close()
                del running[key]
                record(rec if rec is not None else _died(task, proc.exitcode))
    finally:
        for proc, reader, _ in running.values():
            proc.terminate()
        for proc, reader, _ in running.values():
            proc.join(10)
            if proc.is_alive():
                proc.kill()
                proc.join()
            reader.close()


def _died(task: dict, exitcode: int | None) -> dict:
    import signal

    if exitcode is not None and exitcode < 0:
        try:
            how = f"killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            how = f"killed by signal {-exitcode}"
    else:
        how = f"exit code {exitcode}"
    return {"name": task["name"], "mesh": task["mesh"], "status": "failed",
            "reason": f"worker process died ({how}); stages finished before are kept, a re-run resumes",
            "stages": {}, "metrics": {}, "seconds": 0.0}


def _run_ray(tasks: list[dict], cfg: BatchConfig, workers: int, threads: int, record, on_event) -> None:
    try:
        import ray
    except ImportError:
        raise NeuralBakeError("executor ray: Ray is not installed (pip install -e '.[ray]')") from None
    from .stages import run_asset

    started_here = not ray.is_initialized()
    if started_here:
        kwargs = {"include_dashboard": False, "log_to_driver": not cfg.quiet}
        if cfg.address:
            ray.init(address=cfg.address, **kwargs)
        else:
            ray.init(num_cpus=workers * threads, **kwargs)
    gpus = 1 if (cfg.device or "").startswith("cuda") else 0
    remote = ray.remote(num_cpus=threads, num_gpus=gpus, max_retries=0)(run_asset)
    pending = {}
    try:
        for task in tasks:
            pending[remote.remote(task)] = task
            if on_event:
                on_event("start", task["name"], pid=None)
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                task = pending.pop(ref)
                try:
                    rec = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    rec = {"name": task["name"], "mesh": task["mesh"], "status": "failed",
                           "reason": f"ray task failed ({type(exc).__name__}: "
                                     f"{' '.join(str(exc).split())[:200]})",
                           "stages": {}, "metrics": {}, "seconds": 0.0}
                record(rec)
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        if started_here:
            ray.shutdown()
