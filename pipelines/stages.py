"""The stages of one asset in a batch, each cached by a content hash of its inputs and its settings.

fit sdf -> fit nested -> fit texture -> coarse mesh -> bake, in the asset's folder OUT/NAME:

    sdf.safetensors, nested.safetensors, texture.safetensors   the fitted fields
    coarse.npz                                                 the coarse mesh (unit frame, the fine mesh's frame)
    bake/                                                      asset.glb, maps, report.json (pipelines.bake_asset)
    stages.json                                                per stage: key, seconds, metrics, output digests

The nested sequence (when ``nested.levels`` names levels) is the asset that the texture fit, a marched coarse
mesh and the bake use; without it, the fine SDF. A stage's key is the SHA-256 of its name, its resolved
settings (budgets included; display and checkpoint paths excluded) and the digests of its inputs (the loaded
mesh's arrays, the upstream stages' output files).
A stage whose key and output digests match ``stages.json`` is skipped, so an interrupted batch resumes
where it stopped and changing only a bake setting re-bakes without refitting. Fits checkpoint beside their
output under a name holding the key, so even a fit cut short resumes from its last checkpoint.

:func:`run_asset` runs in a worker process (local pool or Ray task): it never raises; it returns the
asset's record with its status and, for a failure, the one-line reason.
"""

from __future__ import annotations

import dataclasses
import os
import time
import typing
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

from neural_bake.errors import NeuralBakeError, NeuralBakeWarning
from neural_bake.fit.nested import NestedFitConfig

from .manifest import STAGE_NAMES

__all__ = ["NestedStageConfig", "CoarseStageConfig", "resolve_stages", "unknown_setting", "stage_key_config", "run_asset", "cached_record",
           "STAGE_FILES", "RECORD_NAME", "RECORD_FORMAT", "set_threads"]

#: The per-asset record of done stages (JSON), in the asset's folder.
RECORD_NAME = "stages.json"
RECORD_FORMAT = "neural_bake.batch_stages.v1"

#: What each stage writes in the asset's folder (the bake writes a folder; its report.json is its digest).
STAGE_FILES = {"sdf": "sdf.safetensors", "nested": "nested.safetensors", "texture": "texture.safetensors",
               "coarse": "coarse.npz", "bake": "bake/report.json"}

#: Settings that change no result: left out of the stage keys.
_NOT_IN_KEY = {"progress", "checkpoint", "checkpoint_every", "resume", "log_every"}


#: The nested stage's settings are the nested fit's own.
NestedStageConfig = NestedFitConfig


@dataclass
class CoarseStageConfig:
    """Settings of the coarse-mesh stage; one line per field."""

    spec: str = "decimate:2000"
    """Coarse mesh: decimate:FACES, decimate:RATIO, march:RESOLUTION (of the fine SDF), level:I:RESOLUTION (of
    level I of the nested sequence) or keep."""


def _stage_classes():
    from neural_bake.fit.sdf import SdfFitConfig
    from neural_bake.fit.texture import TextureFitConfig

    from .bake_asset import BakeAssetConfig

    return {"sdf": SdfFitConfig, "nested": NestedStageConfig, "texture": TextureFitConfig,
            "coarse": CoarseStageConfig, "bake": BakeAssetConfig}


def _coerce(value, hint, what: str):
    """A manifest value as the field's type: text (CSV, a text file) converted, a JSON value as it is."""
    from neural_bake.configs import convert

    return convert(value, hint, what) if isinstance(value, str) else value


def resolve_stages(options: dict[str, dict], *, where: str = "") -> dict:
    """``{stage: config object}`` from ``{stage: {field: value}}`` (text values converted to the field types).

    ``sdf``, ``nested``, ``texture`` and ``bake`` take a ``preset`` key (their presets), applied before the
    other fields.
    Raises NeuralBakeError naming ``STAGE.FIELD`` (and ``where``) for an unknown field or a bad value.
    """
    from neural_bake.fit.nested import nested_config
    from neural_bake.fit.sdf import config_from
    from neural_bake.fit.texture import _resolve_config

    from .bake_asset import bake_config

    prefix = f"{where}: " if where else ""
    classes = _stage_classes()
    out = {}
    for stage in STAGE_NAMES:
        cls = classes[stage]
        hints = typing.get_type_hints(cls)
        given = dict(options.get(stage, {}))
        values = {}
        for k in given:
            problem = unknown_setting(stage, k)
            if problem:
                raise NeuralBakeError(f"{prefix}{stage}.{k}: {problem}")
        preset = given.pop("preset", None)
        for k, v in given.items():
            values[k] = _coerce(v, hints[k], f"{prefix}{stage}.{k}")
        try:
            if stage == "sdf":
                out[stage] = config_from(preset=preset, **values)
            elif stage == "texture":
                out[stage] = _resolve_config(None, {**values, **({"preset": preset} if preset else {})})
            elif stage == "nested":
                out[stage] = nested_config(preset, **values)
            elif stage == "bake":
                out[stage] = bake_config(preset, **values)
            else:
                out[stage] = cls(**values)
        except NeuralBakeError as exc:
            raise NeuralBakeError(f"{prefix}{stage}: {exc}") from None
        except TypeError as exc:
            raise NeuralBakeError(f"{prefix}{stage}: {exc}") from None
    _check_values(out, prefix)
    return out


def unknown_setting(stage: str, name: str) -> str | None:
    """Why ``STAGE.NAME`` is not a stage setting, as one phrase naming the close match if there is one
    ("unknown setting (did you mean sdf.steps?)"); None when it is one (``preset`` is one of every stage
    but the coarse mesh's)."""
    import difflib

    classes = _stage_classes()
    if stage not in classes:
        close = difflib.get_close_matches(stage, STAGE_NAMES, n=1)
        return (f"unknown stage {stage!r}" + (f" (did you mean {close[0]}?)" if close else "")
                + f"; stages: {', '.join(STAGE_NAMES)}")
    if stage == "coarse" and name == "preset":
        return "the coarse stage has no presets (the bake's set it)"
    if stage == "bake" and name == "coarse":
        return "unknown setting (the coarse mesh is set by coarse.spec)"
    names = [f.name for f in dataclasses.fields(classes[stage])] + ([] if stage == "coarse" else ["preset"])
    if name in names:
        return None
    close = difflib.get_close_matches(name, [n for n in names if not (stage == "bake" and n == "coarse")], n=1)
    return "unknown setting" + (f" (did you mean {stage}.{close[0]}?)" if close else "")


def _check_values(cfg: dict, prefix: str) -> None:
    """Checks of the settings that the stage functions would only make when they run."""
    from neural_bake.mesh.coarse import parse_coarse
    from neural_bake.fit.nested import parse_levels

    n = cfg["nested"]
    if _nested_levels(n):
        try:
            parse_levels(n.levels)
        except NeuralBakeError as exc:
            raise NeuralBakeError(f"{prefix}nested.levels: {exc}") from None
    try:
        parse_coarse(cfg["coarse"].spec)
    except NeuralBakeError as exc:
        raise NeuralBakeError(f"{prefix}coarse.spec: {exc}") from None
    b = cfg["bake"]
    if not isinstance(b.size, int) or isinstance(b.size, bool) or not 1 <= b.size <= 16384:
        raise NeuralBakeError(f"{prefix}bake.size {b.size!r}: must be an integer between 1 and 16384")


def _nested_levels(n: NestedStageConfig) -> str:
    return "" if str(n.levels).strip().lower() in ("", "none") else str(n.levels)


def stage_key_config(config) -> dict:
    """The settings of a stage that enter its key (display, checkpoint and resume settings left out)."""
    return {k: v for k, v in asdict(config).items() if k not in _NOT_IN_KEY}


def set_threads(threads: int) -> None:
    """Limit this process's torch (and BLAS/OpenMP) threads; called first in each worker. The fits and bakes
    of the worker then choose their count by measurement up to this cap (:mod:`neural_bake.nets.threads`)."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NEURAL_BAKE_MAX_THREADS"):
        os.environ[var] = str(threads)
    import torch

    torch.set_num_threads(max(1, int(threads)))
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:  # already set in this process (a Ray worker reused for a second task)
        pass


# ----------------------------------------------------------------------------------------------------------
# the worker


def run_asset(task: dict) -> dict:
    """Run (or skip) the stages of one asset; return its record. Never raises (except KeyboardInterrupt).

    ``task``: ``name``, ``mesh``, ``texture`` (or None), ``folder`` (the asset's output folder, absolute),
    ``options`` (``{stage: {field: value}}``, already merged), ``threads``, ``quiet``.
    Returns ``{"name", "mesh", "status": "ok" | "failed", "reason", "stages": {stage: {"status", "seconds"}},
    "metrics": {...}, "warnings": [...], "budget": {...}, "seconds"}``; a stage's status is "done", "cached",
    "skipped", "failed" or "not run"; ``warnings`` holds the toolkit's one-line warnings (each also logged);
    ``budget`` has per time-budgeted fit stage the steps made, the ``expected_steps`` this machine makes in
    the budget (None: no reference) and the ``warning`` when fewer than half were made (also in its metrics
    and in the model file).
    """
    t_start = time.perf_counter()
    if task.get("threads"):
        set_threads(int(task["threads"]))
    name = task["name"]
    quiet = bool(task.get("quiet"))

    def log(msg: str) -> None:
        if not quiet:
            print(f"[{name}] {msg}", flush=True)

    result: dict = {"name": name, "mesh": task["mesh"], "status": "ok", "reason": None, "stages": {}, "metrics": {},
                    "warnings": []}
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", NeuralBakeWarning)
            try:
                _run_stages(task, result, log)
            finally:
                for w in caught:
                    text = str(w.message)
                    if issubclass(w.category, NeuralBakeWarning) and text not in result["warnings"]:
                        result["warnings"].append(text)
                        log(f"warning: {text}")
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # isolated: one line for the summary, the batch goes on
        result["status"] = "failed"
        result["reason"] = _one_line(exc)
        for st in STAGE_NAMES:
            result["stages"].setdefault(st, {"status": "not run", "seconds": 0.0})
        running = [s for s, r in result["stages"].items() if r.get("status") == "running"]
        for s in running:
            result["stages"][s]["status"] = "failed"
        log(f"failed: {result['reason']}")
    result["seconds"] = time.perf_counter() - t_start
    return result


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, NeuralBakeError):
        return str(exc)
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename else ""
        return f"{where}{exc.strerror or exc}"
    if isinstance(exc, MemoryError):
        return "out of memory"
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _load_record(folder: Path) -> dict:
    import json

    try:
        rec = json.loads((folder / RECORD_NAME).read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(rec, dict) or rec.get("format") != RECORD_FORMAT or not isinstance(rec.get("stages"), dict):
        return {}
    return rec


class _WouldRun(Exception):
    """A stage of a :func:`cached_record` check is not cached."""


def cached_record(task: dict) -> dict | None:
    """The asset's record, made in this process without running anything, when ``stages.json`` shows every
    stage done with its present key and unchanged outputs (an all-cached asset needs no worker); None when a
    stage would run or the check cannot tell (the worker then runs the asset and reports any failure)."""
    rec = _load_record(Path(task["folder"]))
    if not {"sdf", "coarse", "bake"} <= set(rec.get("stages", {})):
        return None
    t_start = time.perf_counter()
    result: dict = {"name": task["name"], "mesh": task["mesh"], "status": "ok", "reason": None, "stages": {},
                    "metrics": {}, "warnings": []}
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", NeuralBakeWarning)
            _run_stages(task, result, lambda msg: None, dry=True)
    except KeyboardInterrupt:
        raise
    except BaseException:  # _WouldRun, or anything the worker is to report
        return None
    for w in caught:
        if issubclass(w.category, NeuralBakeWarning) and str(w.message) not in result["warnings"]:
            result["warnings"].append(str(w.message))
    result["seconds"] = time.perf_counter() - t_start
    return result


def _run_stages(task: dict, result: dict, log: Callable[[str], None], dry: bool = False) -> None:
    """Run (or skip) the stages of one asset into ``result``; ``dry``: raise _WouldRun instead of running a
    stage, and write nothing."""
    from neural_bake.io.atomic import atomic_write_text
    from neural_bake.io.digest import arrays_digest, file_digest, json_digest
    from neural_bake.io.jsonio import dumps
    from neural_bake.io.mesh_io import load_mesh

    folder = Path(task["folder"])
    cfg = resolve_stages(task.get("options") or {})
    mesh_path, texture = task["mesh"], task.get("texture")
    t0 = time.perf_counter()
    mesh = load_mesh(mesh_path, texture)
    mesh_digest = arrays_digest(mesh.vertices, mesh.faces, mesh.uv, mesh.texture,
                                [*mesh.frame.center, mesh.frame.scale], [mesh.uv_policy == "wrap"])
    result["metrics"]["faces"] = mesh.n_faces
    log(f"loaded {Path(mesh_path).name}: {mesh.n_faces} faces in {time.perf_counter() - t0:.1f} s")
    folder.mkdir(parents=True, exist_ok=True)
    if not dry:
        _remove_stale(folder)
    record = _load_record(folder)
    stages = record.get("stages", {})
    record = {"format": RECORD_FORMAT, "name": task["name"], "mesh": mesh_path, "texture": texture, "stages": stages}
    digests: dict[str, str | None] = {"mesh": mesh_digest}

    def save_record():
        atomic_write_text(folder / RECORD_NAME, dumps(record))

    def stage(name: str, inputs: list[str], key_config: dict, run: Callable[[Path, str], dict] | None) -> None:
        """Run ``run(output_path) -> metrics`` unless the stage's key and output match the record."""
        out = folder / STAGE_FILES[name]
        key = json_digest({"stage": name, "config": key_config, "inputs": {i: digests[i] for i in inputs}})
        prev = stages.get(name)
        if run is None:  # not part of this asset (no nested levels, no texture)
            stages.pop(name, None)
            digests[name] = None
            result["stages"][name] = {"status": "skipped", "seconds": 0.0}
            return
        if prev and prev.get("key") == key and out.is_file() and prev.get("digest") == file_digest(out):
            digests[name] = prev["digest"]
            result["stages"][name] = {"status": "cached", "seconds": 0.0}
            result["metrics"][name] = prev.get("metrics", {})
            log(f"{name}: unchanged, skipped")
            return
        if dry:
            raise _WouldRun(name)
        result["stages"][name] = {"status": "running", "seconds": 0.0}
        t = time.perf_counter()
        metrics = run(out, key)
        seconds = time.perf_counter() - t
        digests[name] = file_digest(out)
        stages[name] = {"key": key, "digest": digests[name], "seconds": round(seconds, 3), "metrics": metrics}
        save_record()
        result["stages"][name] = {"status": "done", "seconds": seconds}
        result["metrics"][name] = metrics
        log(f"{name}: done in {seconds:.1f} s {_short_metrics(metrics)}")

    sdf_cfg = cfg["sdf"]
    presets = {s: (task.get("options") or {}).get(s, {}).get("preset") for s in ("sdf", "texture")}

    def run_sdf(out: Path, key: str) -> dict:
        from neural_bake.fit.residual import coarse_checkpoint
        from neural_bake.fit.sdf import fit_sdf

        ckpt = folder / f".sdf-{key[:16]}.ckpt"
        levels = (ckpt, Path(coarse_checkpoint(str(ckpt)) or ckpt))  # a construction's coarse level beside it
        _remove_stale(folder, ".sdf-*.ckpt", keep=levels)
        # the preset again, as `fit sdf` does: the time budget is accounted against its step cost
        fit = fit_sdf(mesh, preset=presets["sdf"], **dataclasses.asdict(dataclasses.replace(
            sdf_cfg, progress=False, checkpoint=str(ckpt), resume=True)))
        fit.save(out)
        for p in levels:
            p.unlink(missing_ok=True)
        last = fit.history[-1] if fit.history else {}
        return {"steps": fit.all_steps, "fit_seconds": round(fit.seconds, 3), "loss": last.get("loss"),
                "stopped": fit.stopped_reason, **_budget_metrics([fit.budget])}

    stage("sdf", ["mesh"], stage_key_config(sdf_cfg), run_sdf)
    sdf_path = folder / STAGE_FILES["sdf"]

    nested_cfg = cfg["nested"]

    def run_nested(out: Path, key: str) -> dict:
        from neural_bake.fit.nested import fit_nested
        from neural_bake.fit.sdf import load_sdf

        n = nested_cfg
        seq = fit_nested(load_sdf(sdf_path, device=n.device), dataclasses.replace(n, progress=False, stability_samples=()))
        seq.save(out)
        return {"deltas": [round(d, 6) for d in seq.deltas], "steps": sum(seq.iterations[:-1]),
                **_budget_metrics([info.get("budget") for info in seq.levels_info[:-1]])}

    stage("nested", ["sdf"], stage_key_config(nested_cfg), run_nested if _nested_levels(nested_cfg) else None)

    tex_cfg = cfg["texture"]

    def run_texture(out: Path, key: str) -> dict:
        from neural_bake.fit.texture import fit_texture

        ckpt = folder / f".texture-{key[:16]}.ckpt"
        _remove_stale(folder, ".texture-*.ckpt", keep=(ckpt,))
        fit = fit_texture(mesh, str(field_path), None, preset=presets["texture"], **dataclasses.asdict(
            dataclasses.replace(tex_cfg, progress=False, checkpoint=str(ckpt), resume=True)))
        fit.save(out)
        ckpt.unlink(missing_ok=True)
        last = fit.history[-1] if fit.history else {}
        return {"steps": fit.steps, "fit_seconds": round(fit.seconds, 3), "colour_mse": last.get("colour"),
                "delta": fit.delta, **_budget_metrics([fit.budget])}

    # the nested sequence, when there is one, is the asset the texture fit and the bake use (its δ is the band)
    field_key = "nested" if digests["nested"] else "sdf"
    field_path = folder / STAGE_FILES[field_key]
    stage("texture", ["mesh", field_key], stage_key_config(tex_cfg),
          run_texture if mesh.texture is not None else None)
    tex_path = folder / STAGE_FILES["texture"] if digests["texture"] else None

    coarse_spec = cfg["coarse"].spec
    if coarse_spec.startswith("level") and field_key != "nested":
        raise NeuralBakeError(f"coarse.spec {coarse_spec!r}: a level of the nested sequence needs nested.levels")

    def run_coarse(out: Path, key: str) -> dict:
        from neural_bake.mesh.coarse import coarse_mesh
        from neural_bake.fields import load_field

        coarse_m, info = coarse_mesh(mesh, coarse_spec, load_field(field_path) if marched else None)
        save_coarse(coarse_m, info, out)
        return {"faces": info["faces"], "vertices": info["vertices"]}

    marched = coarse_spec.startswith(("march", "level"))
    coarse_inputs = ["mesh", field_key] if marched else ["mesh"]
    stage("coarse", coarse_inputs, stage_key_config(cfg["coarse"]), run_coarse)

    bake_cfg = dataclasses.replace(cfg["bake"], coarse=coarse_spec, texture=texture)

    def run_bake(out: Path, key: str) -> dict:
        from .bake_asset import bake_asset

        coarse = load_coarse(folder / STAGE_FILES["coarse"])
        report = bake_asset(mesh_path, str(field_path), out.parent, bake_cfg,
                            texture_model=str(tex_path) if tex_path else None, coarse_mesh=coarse,
                            log=lambda m: log("  " + m) if task.get("verbose") else None)
        return _bake_metrics(report)

    stage("bake", ["mesh", field_key, "texture", "coarse"], stage_key_config(bake_cfg), run_bake)
    result["budget"] = {s: {"steps": m.get("steps"), "expected_steps": m["expected_steps"],
                            "warning": m.get("budget_warning")}
                        for s, m in result["metrics"].items() if isinstance(m, dict) and "expected_steps" in m}
    if not dry:
        save_record()


def _budget_metrics(budgets: list[dict | None]) -> dict:
    """A fit stage's budget metrics from its time-budgeted fits' accounts (:func:`neural_bake.fit.budget.fit_budget`;
    one per nested level): ``expected_steps`` (their sum; None when one has no reference), ``budget_seconds``
    and ``budget_warning`` (their warnings, joined); {} for a stage without a time budget."""
    budgets = [b for b in budgets if b]
    if not budgets:
        return {}
    expected = [b.get("expected_steps") for b in budgets]
    warned = [b["warning"] for b in budgets if b.get("warning")]
    return {"expected_steps": None if None in expected else sum(expected),
            "budget_seconds": sum(float(b.get("budget_seconds") or 0.0) for b in budgets),
            "budget_warning": "; ".join(warned) or None}


def _remove_stale(folder: Path, pattern: str = ".*.tmp*", keep: tuple[Path, ...] = ()) -> None:
    """Leftovers in the asset's folder: atomic temporaries of a killed worker (default), or the checkpoints
    of a fit whose settings changed (``pattern`` ".sdf-*.ckpt", ``keep`` the current run's)."""
    for p in folder.glob(pattern):
        if p not in keep:
            p.unlink(missing_ok=True)


def _bake_metrics(report: dict) -> dict:
    out = {}
    for key, label in (("vs_truth_deg", "normal_deg_vs_truth"), ("vs_gradient_deg", "normal_deg_vs_gradient")):
        s = report.get(key) or {}
        if s.get("median") is not None:
            out[label] = {"median": s["median"], "p95": s.get("p95")}
    base = (report.get("baseline") or {}).get("vs_truth_deg") or {}
    if base.get("median") is not None:
        out["baseline_normal_deg_vs_truth"] = {"median": base["median"], "p95": base.get("p95")}
    for key in ("color_psnr_db", "coverage", "seconds_total"):
        if report.get(key) is not None:
            out[key] = report[key]
    return out


def _short_metrics(m: dict) -> str:
    parts = []
    for k, v in m.items():
        if isinstance(v, dict) and "median" in v:
            parts.append(f"{k} median {v['median']:.2f}")
        elif isinstance(v, float):
            parts.append(f"{k} {v:.4g}")
        elif isinstance(v, (int, str)):
            parts.append(f"{k} {v}")
    return f"({', '.join(parts)})" if parts else ""


# ----------------------------------------------------------------------------------------------------------
# the coarse mesh between its stage and the bake


def save_coarse(mesh, info: dict, path: Path) -> None:
    """Write a coarse :class:`~neural_bake.types.Mesh` (every field, unit frame) and its info to ``path``."""
    import json

    from neural_bake.io.jsonio import dumps
    from neural_bake.io.mesh_npz import save_mesh_npz

    save_mesh_npz(mesh, path, json.loads(dumps(info)))


def load_coarse(path: Path):
    """(Mesh, info) written by :func:`save_coarse`."""
    from neural_bake.io.mesh_npz import load_mesh_npz

    return load_mesh_npz(path)
