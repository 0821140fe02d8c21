"""Shared training-loop machinery for every fitter (SDF, nested levels, texture).

One function, :func:`train`, runs an optimiser over a ``torch.nn.Module`` with:

- a step budget and/or a wall-clock budget (``minutes``), whichever ends first;
- a per-step random generator derived from ``(seed, step)``, so a run is reproducible and a resumed run
  draws exactly the samples an uninterrupted run would have drawn;
- progress (tqdm) showing the losses, and a history (one dict per logged step: step, seconds, lr, losses);
- checkpoints (one safetensors file: model weights, optimiser state, JSON metadata; no pickle) written
  atomically every ``checkpoint_every`` steps and at the end, and ``resume`` from such a file;
- its CPU thread count chosen from its own steps and followed as the machine's load changes
  (:class:`~neural_bake.nets.threads.ThreadTuner`; ``LoopResult.threads`` says what ran);
- divergence detection: a non-finite loss, gradient or weight, a loss above ``blowup`` times the first
  loss, or a collapse (the median loss of the last steps ``collapse`` times its best: a network that after
  a spike fell back to about its first loss, a constant, say, which the first-loss test misses) restores
  the last good in-memory snapshot (snapshots are taken only while the loss is near that best), halves the
  learning rate and says so
  (:class:`~neural_bake.errors.NeuralBakeWarning`); after ``max_restarts`` tries it raises
  :class:`~neural_bake.errors.FitError`. The returned model never holds NaN weights;
- optional "keep the best": an ``evaluate()`` callback run every ``eval_every`` steps whose smallest value
  selects the weights returned (the nested fitter keeps the step with the smallest sup-norm |h − f|).

A fitter supplies ``step_fn(step, generator) -> dict`` returning loss tensors; the key ``"loss"`` is the one
back-propagated, the others are logged (as floats); a ``step_fn`` that back-propagates itself returns them
detached. Example::

    def step_fn(step, gen):
        idx = torch.randint(0, n, (batch,), generator=gen)
        pred = model(points[idx])
        mse = ((pred - target[idx]) ** 2).mean()
        return {"loss": mse, "mse": mse}

    result = train(model, step_fn, LoopConfig(steps=1000, lr=1e-4, seed=0))
"""

from __future__ import annotations

import collections
import copy
import json
import math
import statistics
import time
import warnings
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Callable

import torch

from ..constants import BLOWUP_LOSS_FLOOR
from ..errors import FitError, NeuralBakeWarning, TrainingDivergedError
from ..io.atomic import atomic_path
from ..nets.cpu_gemm import gemm_route, model_width, reroute
from ..nets.threads import ThreadTuner
from ..nets.heap import keep_freed_memory

__all__ = ["LoopSettings", "CheckpointSettings", "PresetLoopSettings", "LoopConfig", "LoopResult", "train", "step_generator", "load_checkpoint", "CHECKPOINT_FORMAT",
           "adam_options", "FUSED_ADAM_PARAMETERS"]

#: The ``format`` entry of a checkpoint's metadata.
CHECKPOINT_FORMAT = "neural_bake.checkpoint.v1"


@dataclass
class LoopSettings:
    """The training loop's settings as every fitter's config holds them (its config class derives from this
    one, with its own defaults); :meth:`loop_config` makes the loop's :class:`LoopConfig` of them."""

    steps: int = 1000
    """Maximum number of optimiser steps (the run also stops at ``minutes``)."""
    minutes: float | None = None
    """Wall-clock budget in minutes (None: no budget). Resumed runs count the time already spent."""
    lr: float = 1e-4
    """Initial Adam learning rate (halved on each divergence recovery)."""
    lr_schedule: str = "cosine"
    """"constant" or "cosine" (decay to ``lr_min_factor`` × lr over the steps or the time budget)."""
    lr_min_factor: float = 0.05
    """Final learning rate of the cosine schedule as a fraction of ``lr`` (0 < factor ≤ 1)."""
    seed: int = 0
    """Seeds the initial weights, the samples and the per-step draws: the same seed gives the same model."""
    progress: bool = True
    """Show a progress bar with the losses."""
    log_every: int = 50
    """Steps between history entries (and progress updates)."""

    def loop_config(self, desc: str = "fit", **changes) -> "LoopConfig":
        """The :class:`LoopConfig` of this config's loop settings (checkpoint settings included where the
        config has them), labelled ``desc``; ``changes``: other :class:`LoopConfig` fields."""
        names = {f.name for f in fields(CheckpointSettings)}
        own = {f.name: getattr(self, f.name) for f in fields(self) if f.name in names}
        return LoopConfig(**{**own, "desc": desc, **changes})


@dataclass
class CheckpointSettings(LoopSettings):
    """:class:`LoopSettings` with checkpoints and resume (fitters whose runs can be resumed)."""

    checkpoint: str | None = None
    """Checkpoint file (safetensors: weights, optimiser state) written every ``checkpoint_every`` steps and at
    the end; None: none."""
    checkpoint_every: int = 500
    """Steps between checkpoints."""
    resume: bool = False
    """Continue from ``checkpoint`` if that file exists (same run fingerprint required: mesh, network and
    settings)."""


@dataclass
class PresetLoopSettings(CheckpointSettings):
    """:class:`CheckpointSettings` of a fitter with presets whose time budgets are accounted
    (:mod:`neural_bake.fit.budget`)."""

    budget: str = "time"
    """"time": run the preset's time budget (``minutes``: the steps made follow the machine and its load), or
    "steps": run the steps the preset makes in its budget on the quiet reference machine
    (neural_bake.fit.presets.REFERENCE_STEPS; they replace ``steps`` and ``minutes``), so the
    result does not depend on the load and the time is the estimate (needs a preset, its network and batch)."""


@dataclass
class LoopConfig(CheckpointSettings):
    """How :func:`train` runs: the loop settings of a fitter's config (:meth:`LoopSettings.loop_config`) and
    the loop's own."""

    snapshot_every: int = 100
    """Steps between in-memory snapshots that divergence recovery restores."""
    max_restarts: int = 4
    """Divergence recoveries (each halves the learning rate) before giving up with FitError."""
    blowup: float = 1e3
    """A loss above ``blowup`` × the first finite loss counts as divergence."""
    collapse: float = 100.0
    """The median loss of the last ``collapse_window`` steps above ``collapse`` × the smallest such median of
    the run counts as divergence (a spike shorter than half the window does not move a median); 0 turns the
    test off. Snapshots are taken only while both the median and the step's loss are within √``collapse`` ×
    that best. A resumed run starts its window afresh."""
    collapse_window: int = 50
    """Steps whose median loss the collapse test watches."""
    eval_every: int = 0
    """Steps between ``evaluate()`` calls when keeping the best weights (0: only at the end)."""
    desc: str = "fit"
    """Label of the progress bar and of messages."""


@dataclass
class LoopResult:
    """What :func:`train` returns; the model passed in holds the final (or best) weights."""

    history: list[dict] = field(default_factory=list)
    """One dict per logged step: ``step``, ``seconds``, ``lr`` and every loss as a float."""
    steps: int = 0
    """Optimiser steps done (including those of a resumed run)."""
    seconds: float = 0.0
    """Training wall time in seconds (including a resumed run's)."""
    stopped_reason: str = "steps"
    """"steps", "time budget" or "resumed finished run"."""
    lr: float = 0.0
    """The base learning rate at the end (halved once per divergence recovery)."""
    restarts: int = 0
    """Divergence recoveries done."""
    best_step: int | None = None
    """Step of the weights kept by ``evaluate`` (None without an evaluate callback)."""
    best_value: float | None = None
    """``evaluate()`` at ``best_step``."""
    evaluations: list[dict] = field(default_factory=list)
    """Every ``evaluate()`` call: ``{"step", "value"}``."""
    threads: dict = field(default_factory=dict)
    """The CPU threads the steps ran with: :meth:`~neural_bake.nets.threads.ThreadTuner.summary`."""


def step_generator(seed: int, step: int, device: torch.device | str = "cpu") -> torch.Generator:
    """The generator of one step: a function of ``(seed, step)`` only, so runs and resumes agree."""
    g = torch.Generator(device=device)
    g.manual_seed((int(seed) * 1_000_003 + int(step) * 7_919 + 12_345) % (2**63 - 1))
    return g


def cosine_lr(base_lr: float, lr_min_factor: float, step: int, steps: int, elapsed: float = 0.0,
              minutes: float | None = None) -> float:
    """The cosine learning rate from ``base_lr`` down to ``lr_min_factor`` × it, at the fraction of the run done:
    of its ``steps``, or of its time budget ``minutes`` (``elapsed`` seconds) when that is further along."""
    frac = step / max(steps, 1)
    if minutes:
        frac = max(frac, elapsed / (60.0 * minutes))
    frac = min(max(frac, 0.0), 1.0)
    return base_lr * (lr_min_factor + (1 - lr_min_factor) * 0.5 * (1 + math.cos(math.pi * frac)))


def _lr_at(cfg: LoopConfig, base_lr: float, step: int, elapsed: float) -> float:
    if cfg.lr_schedule == "constant":
        return base_lr
    return cosine_lr(base_lr, cfg.lr_min_factor, step, cfg.steps, elapsed, cfg.minutes)


def _all_finite(tensors) -> bool:
    """Whether every element of the tensors (None skipped) is finite, from one sum a tensor: a NaN or an infinity
    makes its sum non-finite, and one read of the tensor costs a tenth of ``isfinite(t).all()``'s mask (a
    feature grid's millions of entries, checked twice a step). A sum that overflows, of values near 1e38 in
    float32, also reads as non-finite: weights or gradients that large have diverged."""
    finite = [torch.isfinite(t.sum()) for t in tensors if t is not None]  # booleans: one stack whatever the dtypes
    return not finite or bool(torch.stack(finite).all())


def _snapshot(model, opt) -> dict:
    return {"model": copy.deepcopy(model.state_dict()), "opt": copy.deepcopy(opt.state_dict())}


def _validate(cfg: LoopConfig) -> None:
    if not math.isfinite(cfg.steps) or int(cfg.steps) != cfg.steps or cfg.steps < 1:
        raise FitError(f"{cfg.desc}: steps must be a positive integer, got {cfg.steps!r}")
    if cfg.minutes is not None and not (math.isfinite(cfg.minutes) and cfg.minutes > 0):
        raise FitError(f"{cfg.desc}: minutes must be positive, got {cfg.minutes!r}")
    if not (math.isfinite(cfg.lr) and cfg.lr > 0):
        raise FitError(f"{cfg.desc}: learning rate must be positive, got {cfg.lr!r}")
    if cfg.lr_schedule not in ("constant", "cosine"):
        raise FitError(f"{cfg.desc}: lr_schedule must be 'constant' or 'cosine', got {cfg.lr_schedule!r}")
    if not (math.isfinite(cfg.lr_min_factor) and 0 < cfg.lr_min_factor <= 1):
        raise FitError(f"{cfg.desc}: lr_min_factor must be in (0, 1], got {cfg.lr_min_factor!r}")
    if cfg.resume and not cfg.checkpoint:
        raise FitError(f"{cfg.desc}: resume needs a checkpoint path")
    if not (math.isfinite(cfg.collapse) and (cfg.collapse == 0 or cfg.collapse > 1)):
        raise FitError(f"{cfg.desc}: collapse must be 0 (off) or above 1, got {cfg.collapse!r}")
    for name in ("checkpoint_every", "log_every", "snapshot_every", "collapse_window"):
        if int(getattr(cfg, name)) < 1:
            raise FitError(f"{cfg.desc}: {name} must be >= 1, got {getattr(cfg, name)!r}")


# ----------------------------------------------------------------------------------------------- checkpoints
def _save_checkpoint(path, model, opt, meta: dict) -> None:
    from safetensors.torch import save_file

    tensors = {f"model.{k}": v.detach().contiguous().cpu() for k, v in model.state_dict().items()}
    opt_state = opt.state_dict()
    scalars = {}
    for pid, st in opt_state["state"].items():
        for key, val in st.items():
            if torch.is_tensor(val):
                tensors[f"optim.{pid}.{key}"] = val.detach().contiguous().cpu()
            else:
                scalars[f"{pid}.{key}"] = val
    groups = [{k: v for k, v in g.items() if k != "params"} | {"params": list(g["params"])}
              for g in opt_state["param_groups"]]
    meta = dict(meta, format=CHECKPOINT_FORMAT, optim_groups=groups, optim_scalars=scalars)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, suffix=".safetensors") as tmp:
        save_file(tensors, str(tmp), metadata={"neural_bake": json.dumps(meta)})


def load_checkpoint(path) -> tuple[dict, dict, dict]:
    """Read a checkpoint: ``(model_state, optimizer_state, metadata)``; FitError if it is not one."""
    from safetensors import safe_open

    p = Path(path)
    if not p.is_file():
        raise FitError(f"{p}: checkpoint not found")
    try:
        with safe_open(str(p), framework="pt") as fh:
            meta = json.loads((fh.metadata() or {}).get("neural_bake", "{}"))
            tensors = {k: fh.get_tensor(k) for k in fh.keys()}
    except FitError:
        raise
    except Exception as exc:  # corrupt / truncated / not safetensors
        raise FitError(f"{p}: not a readable checkpoint ({type(exc).__name__}: {exc})") from None
    if meta.get("format") != CHECKPOINT_FORMAT:
        raise FitError(f"{p}: not a neural_bake checkpoint (format {meta.get('format')!r})")
    model_state = {k[len("model."):]: v for k, v in tensors.items() if k.startswith("model.")}
    state: dict = {}
    for k, v in tensors.items():
        if k.startswith("optim."):
            _, pid, key = k.split(".", 2)
            state.setdefault(int(pid), {})[key] = v
    for k, v in meta.get("optim_scalars", {}).items():
        pid, key = k.split(".", 1)
        state.setdefault(int(pid), {})[key] = v
    opt_state = {"state": state, "param_groups": meta.get("optim_groups", [])}
    return model_state, opt_state, meta


# ----------------------------------------------------------------------------------------------- the loop
def train(
    model: torch.nn.Module,
    step_fn: Callable[[int, torch.Generator], dict],
    config: LoopConfig | None = None,
    *,
    evaluate: Callable[[], float] | None = None,
    fingerprint: str = "",
    metadata: dict | None = None,
    on_log: Callable[[dict], None] | None = None,
    clock: Callable[[], float] = time.perf_counter,
) -> LoopResult:
    """Optimise ``model`` with Adam, calling ``step_fn(step, generator)`` for the losses of each step.

    ``step_fn`` returns a dict of scalar tensors; ``"loss"`` is back-propagated (ONE ``backward()`` per
    step), the others are logged. A ``step_fn`` may back-propagate itself (e.g. in micro-batches, as the
    SDF fitter does on CPUs) and return the loss detached: the loop then only checks the gradients. The
    generator is :func:`step_generator` ``(seed, step)`` on the model's device. ``evaluate()`` (no grad),
    if given, runs every ``eval_every`` steps and at the end; the weights with its smallest value are the
    ones left in ``model``. ``fingerprint`` identifies the run in the
    checkpoint: resuming a checkpoint with another fingerprint raises FitError. ``metadata`` is stored in
    the checkpoint as is (JSON-able). ``on_log(entry)`` is called with every history entry. ``clock()``
    gives the seconds the time budget and the history measure (default ``time.perf_counter``; tests pass
    their own to simulate a slow machine).

    Returns a :class:`LoopResult`; the model holds the final (or best) weights, never non-finite ones.
    Raises FitError when divergence persists after ``max_restarts`` learning-rate halvings.
    """
    first = next(iter(model.parameters()), None)
    device = first.device if first is not None else torch.device("cpu")
    with gemm_route(model_width(model), device):  # float32 CPU GEMMs where they run fastest (nets.cpu_gemm)
        return _train(model, step_fn, config, evaluate=evaluate, fingerprint=fingerprint, metadata=metadata,
                      on_log=on_log, clock=clock)


def _forward_slice(model, device):
    """A small slice of the loop's work for the thread count of its first steps: a no-grad forward pass of
    ``model`` on 4,096 points (None when its input width is unknown)."""
    dim = getattr(model, "in_dim", None)
    if dim is None:
        first = next((m for m in model.modules() if isinstance(m, torch.nn.Linear)), None)
        dim = None if first is None else first.in_features
    if dim is None:
        return None
    p = next(iter(model.parameters()))
    x = torch.rand(4096, int(dim), generator=torch.Generator().manual_seed(0)).to(device=device, dtype=p.dtype)

    def work():
        with torch.no_grad():
            model(x)

    return work


#: Parameters from which the fused Adam update is taken (a feature grid's table: 1.8M at the texture presets).
FUSED_ADAM_PARAMETERS = 1 << 18


def adam_options(params) -> dict:
    """Adam's implementation: the fused update (one pass over each parameter) where the parameters are many and
    torch has it for their device and dtype; there the update's memory traffic is what a step pays for (a
    feature grid's 1.8M: 26 against 40–49 ms a step, BENCHMARKS.md); torch's default elsewhere (a SIREN's step
    is its products)."""
    fusable = all(p.device.type in ("cpu", "cuda") and p.dtype in (torch.float32, torch.float64) for p in params)
    return {"fused": True} if fusable and sum(p.numel() for p in params) >= FUSED_ADAM_PARAMETERS else {}


def _train(model, step_fn, config, *, evaluate, fingerprint, metadata, on_log, clock) -> LoopResult:
    cfg = config or LoopConfig()
    _validate(cfg)
    keep_freed_memory()  # a step's tensors reuse the last step's memory instead of page-faulting (nets.heap)
    params = [p for p in model.parameters() if p.requires_grad]
    if not params:
        raise FitError(f"{cfg.desc}: the model has no trainable parameters")
    device = params[0].device
    opt = torch.optim.Adam(params, lr=cfg.lr, **adam_options(params))
    result = LoopResult(lr=cfg.lr)
    base_lr = cfg.lr
    step, spent = 0, 0.0
    first_loss: float | None = None

    if cfg.resume and cfg.checkpoint and Path(cfg.checkpoint).is_file():
        model_state, opt_state, meta = load_checkpoint(cfg.checkpoint)
        if meta.get("fingerprint", "") != fingerprint:
            raise FitError(f"{cfg.checkpoint}: checkpoint belongs to another run (different network, mesh or "
                           f"settings); remove it or choose another checkpoint file")
        try:
            model.load_state_dict(model_state)
            opt.load_state_dict(opt_state)
        except (RuntimeError, KeyError, ValueError) as exc:
            raise FitError(f"{cfg.checkpoint}: checkpoint does not match the model ({exc})".splitlines()[0]) from None
        step, spent = int(meta["step"]), float(meta["seconds"])
        base_lr = float(meta["base_lr"])
        first_loss = meta.get("first_loss")
        result.history = list(meta.get("history", []))
        result.restarts = int(meta.get("restarts", 0))
        result.evaluations = list(meta.get("evaluations", []))
        if step >= cfg.steps:
            result.stopped_reason = "resumed finished run"

    best = {"value": math.inf, "state": None, "step": None}
    # A resumed run keeps the evaluations' history but only the checkpoint's weights: the best is chosen
    # among the weights evaluated from here on (the checkpoint's included, evaluated at the first eval).
    def run_eval(at_step: int) -> None:
        if evaluate is None:
            return
        with torch.no_grad():
            v = float(evaluate())
        result.evaluations.append({"step": at_step, "value": v})
        if math.isfinite(v) and v < best["value"]:
            best.update(value=v, state=copy.deepcopy(model.state_dict()), step=at_step)

    def checkpoint_meta() -> dict:
        return {
            "fingerprint": fingerprint, "step": step, "seconds": spent, "base_lr": base_lr,
            "first_loss": first_loss, "history": result.history, "restarts": result.restarts,
            "evaluations": result.evaluations, "config": asdict(cfg), "user": metadata or {},
        }

    bar = None
    if cfg.progress:
        from tqdm.auto import tqdm

        if cfg.minutes is not None:  # a time budget: the bar is seconds against it (the step cap is a safety net)
            bar = tqdm(total=round(60.0 * cfg.minutes, 1), initial=round(min(spent, 60.0 * cfg.minutes), 1),
                       desc=cfg.desc, leave=False, dynamic_ncols=True, unit="s",
                       bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s of the budget{postfix}")
        else:
            bar = tqdm(total=cfg.steps, initial=step, desc=cfg.desc, leave=False, dynamic_ncols=True)

    snapshot = _snapshot(model, opt)
    snapshot_step = step
    recent: collections.deque = collections.deque(maxlen=int(cfg.collapse_window))  # the collapse test's losses
    best_median = math.inf
    width = model_width(model)
    tuner = ThreadTuner(device=device, clock=clock, on_change=lambda n: reroute(width, device),
                        initial=_forward_slice(model, device))
    t_start = clock() - spent
    try:
        while step < cfg.steps:
            elapsed = clock() - t_start
            if cfg.minutes is not None and elapsed >= 60.0 * cfg.minutes:
                result.stopped_reason = "time budget"
                break
            lr = _lr_at(cfg, base_lr, step, elapsed)
            for g in opt.param_groups:
                g["lr"] = lr
            gen = step_generator(cfg.seed, step, device if device.type != "mps" else "cpu")
            tuner.before_step()
            opt.zero_grad(set_to_none=True)
            losses = step_fn(step, gen)
            loss = losses["loss"]
            loss_value = float(loss.detach())
            problem = None
            if not math.isfinite(loss_value):
                problem = "non-finite loss"
            elif first_loss is not None and loss_value > cfg.blowup * max(first_loss, BLOWUP_LOSS_FLOOR):
                problem = f"loss {loss_value:.3g} exploded (first loss {first_loss:.3g})"
            else:
                recent.append(loss_value)
                median = statistics.median(recent)
                best_median = min(best_median, median)
                if cfg.collapse and median > cfg.collapse * max(best_median, BLOWUP_LOSS_FLOOR):
                    problem = (f"loss collapsed: its median over {len(recent)} steps {median:.3g} is "
                               f"{median / max(best_median, BLOWUP_LOSS_FLOOR):.0f}× its best {best_median:.3g}")
            if problem is None:
                if loss.requires_grad:
                    loss.backward()
                elif all(p.grad is None for p in params):
                    raise FitError(f"{cfg.desc}: the step returned a loss without a graph and back-propagated "
                                   "nothing itself")
                if not _all_finite(p.grad for p in params):
                    problem = "non-finite gradient"
            if problem is None:
                opt.step()
                if not _all_finite(params):
                    problem = "non-finite weights"
            if problem is not None:
                result.restarts += 1
                if result.restarts > cfg.max_restarts:
                    model.load_state_dict(snapshot["model"])
                    raise TrainingDivergedError(f"{cfg.desc}: training diverged at step {step} ({problem}) after "
                                   f"{cfg.max_restarts} learning-rate halvings (lr now {base_lr:.3g}); "
                                   f"try a smaller learning rate or check the input")
                base_lr *= 0.5
                model.load_state_dict(snapshot["model"])
                opt.load_state_dict(snapshot["opt"])
                warnings.warn(f"{cfg.desc}: training diverged at step {step} ({problem}); restored step "
                              f"{snapshot_step} and halved the learning rate to {base_lr:.3g}",
                              NeuralBakeWarning, stacklevel=2)
                step = snapshot_step
                recent.clear()
                if bar is not None and cfg.minutes is None:
                    bar.n = step
                    bar.refresh()
                continue
            if first_loss is None:
                first_loss = loss_value
            step += 1
            spent = clock() - t_start
            tuner.after_step(spent - elapsed)  # the step's seconds, from the two reads the loop makes anyway
            if step % cfg.snapshot_every == 0 and (  # never a snapshot of a collapsing run
                    not cfg.collapse
                    or max(median, loss_value) <= math.sqrt(cfg.collapse) * max(best_median, BLOWUP_LOSS_FLOOR)):
                snapshot, snapshot_step = _snapshot(model, opt), step
            if step % cfg.log_every == 0 or step == cfg.steps or step == 1:
                entry = {"step": step, "seconds": round(spent, 3), "lr": lr}
                entry.update({k: float(v.detach()) if torch.is_tensor(v) else float(v) for k, v in losses.items()})
                result.history.append(entry)
                if on_log is not None:
                    on_log(entry)
                if bar is not None:
                    post = {"step": step} if cfg.minutes is not None else {}
                    post.update({k: f"{v:.3g}" for k, v in entry.items() if k not in ("step", "seconds")})
                    bar.set_postfix(post, refresh=False)
            if bar is not None:  # one step, or the seconds since the last one (tqdm throttles the redraws)
                bar.update(1 if cfg.minutes is None else max(0.0, round(min(spent, bar.total) - bar.n, 3)))
            if evaluate is not None and cfg.eval_every and step % cfg.eval_every == 0:
                run_eval(step)
            if cfg.checkpoint and step % cfg.checkpoint_every == 0:
                _save_checkpoint(cfg.checkpoint, model, opt, checkpoint_meta())
    finally:
        if bar is not None:
            bar.close()

    spent = clock() - t_start
    if evaluate is not None:
        if not result.evaluations or result.evaluations[-1]["step"] != step:
            run_eval(step)
        if best["state"] is not None:
            model.load_state_dict(best["state"])
            result.best_step, result.best_value = best["step"], best["value"]
    if cfg.checkpoint and result.stopped_reason != "resumed finished run":
        _save_checkpoint(cfg.checkpoint, model, opt, checkpoint_meta())
    result.steps, result.seconds, result.lr = step, spent, base_lr
    result.threads = tuner.summary()
    return result
