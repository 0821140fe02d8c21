"""Fit a fine SIREN SDF to a mesh (Novello et al. 2022 losses; paper Appendix A.2).

The network f: R³ → R (unit frame) is trained on points drawn each step from precomputed pools:

- surface samples p with outward normals n: ``f(p)²`` (the surface is a zero level set) and
  ``1 − <∇f(p)/|∇f(p)|, n>`` (the gradient points along the normal; the paper's ``1 − <∇f, n>`` is
  unbounded below when |∇f| > 1 and fought the eikonal term in our runs, so we use the cosine);
- near-surface samples (Gaussian offsets, several σ) and uniform samples in [-1, 1]³ with their ground-truth
  signed distance d: ``(f(x) − d)²``;
- every point: the eikonal term ``(1 − |∇f|)²``.

∇f is computed in the loss by :func:`~neural_bake.nets.gemm.gemm_gradient` with ``differentiable=True``
(the closed-form GEMM gradient as one autograd node with a hand-written backward): the values and
gradients of all the step's points come from ONE pass, and the loss needs ONE ordinary ``backward()`` — no
double-backward. On
a CPU the step runs in cache-sized micro-batches (``SdfFitConfig.micro_batches``), each forward and backward
on its own, whose gradients add up to the whole batch's.
After Adam, an optional L-BFGS polish (``SdfFitConfig.polish_evals``; the 64x1 preset's) minimises the same loss
plus a smooth maximum of the first-order distance f/|∇f| over the surface samples on one large fixed batch.
Pools are drawn from the mesh once per ``refresh_every`` steps (seeded by ``(seed, refresh index)`` so a
resumed run rebuilds exactly the same pools); the loop (:mod:`neural_bake.fit.training`) gives budgets,
progress, checkpoints/resume, seeds and divergence recovery.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import time
from dataclasses import asdict, dataclass, field, fields, replace
from functools import partial
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from .. import __version__
from ..constants import POOL_REFRESH_MAX_SHARE
from ..errors import FitError, ModelFileError
from ..nets.compiled import CompiledFn, long_run, should_compile
from ..nets.siren import Siren
from ..types import Mesh
from .polish import CHUNK_ITERATIONS, lbfgs_polish
from .record import FitRecord
from .sdf_config import _DTYPES, PRESETS, SdfFitConfig, config_from
from .sdf_loss import (FIRST_ORDER_MIN_SLOPE, FOCUS_CAP, first_order_distance, focused_squares, mixed_gradient,
                       sdf_loss_terms, sdf_step_backward)
from .sdf_pools import (BASE_KEYS, _draw, _error_cdf, _hard_indices, _Pools, _sign_errors, _zero_set_samples,
                        band_pools, near_reach, remine_due)
from .sdf_tuning import TRAIN_CHUNK_ELEMENTS, TUNE_EVERY, MicroBatchTuner, _bf16_pays, micro_batch_count
from .training import train

__all__ = ["SdfFitConfig", "SdfFit", "PRESETS", "fit_sdf", "load_sdf", "config_from", "sdf_loss_terms",
           "sdf_step_backward", "micro_batch_count", "mixed_gradient", "focused_squares", "first_order_distance",
           "MicroBatchTuner", "FIRST_ORDER_MIN_SLOPE", "FOCUS_CAP", "TRAIN_CHUNK_ELEMENTS", "TUNE_EVERY",
           "sampled_distance_error", "DISTANCE_ERROR_SOURCE"]


@dataclass
class SdfFit(FitRecord):
    """A fitted SDF (:class:`~neural_bake.fit.record.FitRecord`): ``model`` is the Siren f: (N, 3) unit-frame
    points → (N, 1) signed distance (unit-frame units; negative inside), ``frame`` the mesh's."""

    config: SdfFitConfig = field(default_factory=SdfFitConfig)
    polish: dict | None = None
    """The L-BFGS polish's record (:class:`~neural_bake.fit.polish.PolishResult` as a dict; None: no polish)."""
    micro_batch_tuning: list[dict] | None = None
    """The micro-batch tunings of a time-budgeted run (:attr:`MicroBatchTuner.history`: step, loss variant,
    count chosen, best seconds per count); None when the count was fixed."""
    budget: dict | None = None
    """A time-budgeted run's account (:func:`neural_bake.fit.budget.fit_budget`): Adam steps made beside the
    steps the preset makes on this machine for this mesh (its sampling counted) in Adam's part of the budget,
    why it stopped, the warning if any; a ``budget="steps"`` run's (:func:`neural_bake.fit.budget.steps_budget`):
    the preset's reference steps and their estimated seconds here."""
    sampling_seconds: float | None = None
    """Seconds (the fit's clock: wall time by default) of this run's Adam part spent building pools,
    re-ranking and mining them and drawing batches (the sampling's share of the step cost); None when not
    recorded (a loaded file)."""

    distance_error: float | None = None
    """Sampled distance error to the mesh (unit frame): max |f| at mesh surface samples
    (:func:`sampled_distance_error`); saved as the file's δ, the band a texture fit uses. None: not measured."""

    @property
    def all_steps(self) -> int:
        """Adam steps of every network the fit trained (a construction's: both levels')."""
        return self.steps

    def save(self, path) -> Path:
        """Write the model file (safetensors + JSON metadata: kind="sdf", frame, δ (the sampled distance
        error; ``delta_source`` says so), config, history summary)."""
        from ..fields import save_model

        delta = {} if self.distance_error is None else {
            "delta": self.distance_error, "delta_source": DISTANCE_ERROR_SOURCE}
        return save_model(
            self.model, path, kind="sdf", frame=self.frame.to_dict(), config=_jsonable(asdict(self.config)),
            training={**self.training(), "polish": self.polish,
                      "micro_batch_tuning": (self.micro_batch_tuning or [])[-20:] or None, "budget": self.budget},
            package_version=__version__, **delta,
        )

    @classmethod
    def load(cls, path, *, device=None) -> "SdfFit":
        """Read a file written by :meth:`save` (ModelFileError if it is not an SDF model file)."""
        return load_sdf(path, device=device)


def load_sdf(path, *, device=None) -> SdfFit:
    """Read an SDF model file written by :meth:`SdfFit.save` into an :class:`SdfFit` (through
    :func:`neural_bake.fields.load_field`, which checks the header)."""
    from ..fields import SdfField, load_field

    field = load_field(path, device=device)
    if not isinstance(field, SdfField):
        raise ModelFileError(f"{path}: not an SDF model file (a {type(field).__name__} file)")
    if field.frame is None:
        raise ModelFileError(f"{path}: SDF model file without a frame")
    meta = field.metadata
    names = {f.name for f in fields(SdfFitConfig)}
    cfg = meta.get("config") if isinstance(meta.get("config"), dict) else {}
    cfg_dict = {k: v for k, v in cfg.items() if k in names}
    if "sigmas" in cfg_dict:
        cfg_dict["sigmas"] = tuple(cfg_dict["sigmas"])
    training = meta.get("training") if isinstance(meta.get("training"), dict) else {}
    try:
        return SdfFit(model=field.model, frame=field.frame, **FitRecord.training_fields(training),
                      config=SdfFitConfig(**cfg_dict), polish=training.get("polish"),
                      micro_batch_tuning=training.get("micro_batch_tuning"), budget=training.get("budget"),
                      distance_error=field.delta)
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f"{path}: unreadable training record ({exc})") from None


#: How an SDF fit's δ was obtained (stored as ``delta_source`` in its file).
DISTANCE_ERROR_SOURCE = "sampled distance error: max |f| at mesh surface samples"


@torch.no_grad()
def sampled_distance_error(model: Siren, mesh: Mesh, n: int = 20_000, seed: int = 0) -> float:
    """max |f| (unit frame) at ``n`` area-uniform surface samples of ``mesh`` (seeded): a sampled estimate
    of how far the mesh strays from f's zero set in f's units, i.e. the band |f| ≤ δ that holds the mesh."""
    from .sampling import sample_surface

    p = next(model.parameters())
    pts = torch.as_tensor(sample_surface(mesh, int(n), seed=seed).points, dtype=p.dtype, device=p.device)
    values = torch.cat([model(pts[s:s + 65536])[:, 0] for s in range(0, pts.shape[0], 65536)])
    return float(values.abs().max())


def _jsonable(d):
    return json.loads(json.dumps(d, default=str))


def _fingerprint(mesh: Mesh, cfg: SdfFitConfig, *, networks: tuple = (), arrays: tuple = (),
                 values: tuple = ()) -> str:
    """The run's fingerprint (a checkpoint resumes only the run it belongs to): the mesh, the settings that
    define the trajectory, and what a level of a construction starts from or trains on (``networks``: the
    frozen coarse level or the warm start's weights; ``arrays``: tensors such as the band audit's points;
    ``values``: numbers such as the band)."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    h.update(json.dumps(_jsonable(cfg.fingerprint_dict()), sort_keys=True).encode())
    tensors = [t for net in networks for _, t in sorted(net.state_dict().items())] + list(arrays)
    for t in tensors:
        h.update(t.detach().to("cpu", torch.float64).contiguous().numpy().tobytes())
    h.update(json.dumps([float(v) for v in values]).encode())
    return h.hexdigest()[:32]



# ----------------------------------------------------------------------------------------------- fitting
def fit_sdf(mesh: Mesh, config: SdfFitConfig | None = None, *, preset: str | None = None,
            clock: Callable[[], float] | None = None, base: Siren | None = None, band: float | None = None,
            init: Siren | None = None, pool_cache: dict | None = None, budget_key: str | None = None,
            audit: tuple | None = None, **overrides) -> SdfFit:
    """Train a Siren SDF of ``mesh`` (unit frame) and return an :class:`SdfFit`.

    Args:
        mesh: a :class:`~neural_bake.types.Mesh` (unit frame; e.g. from ``load_mesh``). Open meshes are
            signed by the generalised winding number, and the field is the union of the mesh's shells: faces
            buried inside another shell are not its surface (see :mod:`neural_bake.fit.sampling`).
        config: the settings (default :class:`SdfFitConfig`).
        preset: ``"64x1"``, ``"128x2"``, ``"256x2"`` or ``"256x3"`` (:data:`PRESETS`), or the shared names
            ``"quick"`` (192x3 for 2 minutes), ``"default"`` (192x3 for 5), ``"high"`` (256x4 for 10 minutes),
            applied before ``overrides``.
        clock: the seconds every budget decision of the run measures — Adam's budget, the share of bf16
            steps, the polish's reserve and deadline, the budget account's split of a step into sampling and
            its own work (default ``time.perf_counter``; tests simulate a slow or loaded machine with their own).
        base: a frozen network h (unit frame): the model r is then trained as a residual level on it, every
            loss term on the sum h + r, on the pool points inside h's band |h| < ``band`` only
            (:func:`~neural_bake.fit.sdf_pools.band_pools`); r starts with a zero output layer (h + r = h).
            Without hard examples, mined zero-set points, error sampling or polish (they would rank r alone); a
            checkpoint keeps r and resumes only on the same h, band and audit (the run's fingerprint holds
            them); the result's ``model`` is r and its ``distance_error`` None (the sum's is the caller's).
        band: the band's half-width δ (unit frame; with ``base``).
        audit: (points, true distances) of the coarse level's band audit
            (:func:`~neural_bake.fit.sdf_pools.band_audit`; with ``base``), added to every pool's uniform points.
        init: a Siren of the config's width and depth to start from instead of a random one (warm start).
        pool_cache: a dict shared by fits of this mesh with the same sampling settings: each sample pool is
            drawn from the mesh once and taken from it by the next fit (e.g. the levels of one construction).
        budget_key: the :data:`~neural_bake.fit.budget.STEP_COST` key the run's budget is accounted against
            and whose reference steps a ``budget="steps"`` run makes (default: the preset's, when the run kept
            its network and batches; a construction's levels have keys of their own).
        **overrides: any :class:`SdfFitConfig` field, e.g. ``width=64, depth=1, steps=500, seed=3``.

    Returns:
        An :class:`SdfFit` whose ``model`` is in eval mode on ``config.device``.

    Raises:
        FitError: invalid settings, a mesh with nothing to sample, a checkpoint of another run, or
            divergence that learning-rate halvings did not cure (weights are never left non-finite).
    """
    if not isinstance(mesh, Mesh):
        raise FitError(f"fit_sdf: expected a neural_bake Mesh, got {type(mesh).__name__}")
    if mesh.n_faces == 0 or mesh.n_vertices == 0:
        raise FitError(f"{mesh.name}: the mesh has no faces to fit")
    if not np.isfinite(mesh.vertices).all():
        raise FitError(f"{mesh.name}: the mesh has non-finite vertex coordinates")
    cfg = config_from(config, preset=preset, **overrides)
    if budget_key is None:
        budget_key = _preset_key(preset, cfg)
    if cfg.construction != "plain" and base is None and init is None:  # a construction of several levels
        from .residual import fit_levels

        return fit_levels(mesh, cfg, budget_key, clock=clock, pool_cache=pool_cache)
    budget_minutes = cfg.minutes  # the time budget the run is sized by (a budget="steps" run's preset's)
    if cfg.budget == "steps":  # the preset's steps on the quiet reference machine, no time stop
        from .budget import reference_steps

        n_steps = reference_steps(budget_key)
        if n_steps is None:
            raise FitError("fit_sdf: budget='steps' needs preset (one of "
                           f"{', '.join(PRESETS)}) with the preset's width, depth and batches, got preset {preset!r}")
        cfg = replace(cfg, steps=n_steps, minutes=None)
    _check_residual(cfg, base, band, init)
    if audit is not None and base is None:
        raise FitError("fit_sdf: audit points belong to a residual level's band: they need base")
    device = torch.device(cfg.device or "cpu")
    dtype = _DTYPES[cfg.dtype]
    gen = torch.Generator().manual_seed(int(cfg.seed))
    model = Siren(cfg.width, cfg.depth, omega_0=cfg.omega_0, generator=gen).to(device=device, dtype=dtype)
    if init is not None:
        model.load_state_dict(init.state_dict())
    prepare: Callable[[dict], dict] | None = None
    extra: tuple[str, ...] = ()
    if base is not None:
        with torch.no_grad():  # the residual starts at zero: h + r = h
            model.layers[-1].weight.zero_()
            model.layers[-1].bias.zero_()
        base = copy.deepcopy(base).to(device=device, dtype=dtype).eval()  # the caller's network untouched
        prepare, extra = band_pools(base, float(band or 0.0), audit=audit), BASE_KEYS
    n_base = len(extra)
    if near_reach(cfg):  # the near points' gradient targets, drawn beside them
        extra = (*extra, "vol_n")
    model.train()
    # a budgeted run keeps its pools longer where rebuilding them would eat its steps (POOL_REFRESH_MAX_SHARE)
    pools = _Pools(mesh, cfg, device, dtype, max_share=POOL_REFRESH_MAX_SHARE if cfg.minutes else None,
                   prepare=prepare, cache=pool_cache)

    # of the settings as asked ("auto" included) and, for a construction's level, of what it is built on
    fingerprint = _fingerprint(mesh, cfg, networks=tuple(n for n in (base, init) if n is not None),
                               arrays=() if audit is None else audit, values=() if band is None else (band,))
    if cfg.gemm_dtype == "auto":
        cfg = replace(cfg, gemm_dtype="bfloat16" if _bf16_pays(cfg, device, dtype) else "float32")
    use_bf16 = cfg.gemm_dtype == "bfloat16" and cfg.bf16_fraction > 0
    compiled = should_compile(cfg.compile, device, long_run=long_run(cfg.steps, budget_minutes))
    cfg = replace(cfg, compile="on" if compiled else "off")
    loss_terms = CompiledFn(sdf_loss_terms, enabled=compiled, desc=f"fit sdf {cfg.width}x{cfg.depth}")
    now = clock or time.perf_counter
    t_start = now()

    def low_precision(step: int) -> bool:
        if not use_bf16:
            return False
        frac = step / max(cfg.steps, 1)
        if cfg.minutes:  # resumed runs restart this clock: the switch may come later than in one run
            frac = max(frac, (now() - t_start) / (60.0 * cfg.minutes))
        return frac < cfg.bf16_fraction

    hard = {"pool": None, "idx": None}  # idx: {"surf", "near"} index tensors

    def hard_set(step: int, data: dict) -> dict | None:
        # re-ranked when remine_due says (a new pool, every hard_every steps, each checkpoint step)
        if cfg.hard_fraction <= 0 and cfg.zero_fraction <= 0 and cfg.error_sampling <= 0 and cfg.sign_fraction <= 0:
            return None
        if remine_due(cfg, step, hard["idx"] is None or hard["pool"] is not data):
            idx, n_near = {}, data["n_near"]
            if cfg.hard_fraction > 0:
                idx["surf"] = _hard_indices(model, data["surf_p"], cfg)
                if cfg.batch_near and n_near:
                    idx["near"] = _hard_indices(model, data["vol_p"][:n_near], cfg, data["vol_d"][:n_near])
            if cfg.sign_fraction > 0 and cfg.batch_uniform:
                idx["sign"] = _sign_errors(model, data)
            if cfg.error_sampling > 0:
                idx["error"] = _error_cdf(model, data["surf_p"], data["surf_n"])
            if cfg.zero_fraction > 0 and cfg.batch_near and n_near:
                idx["zero"] = _zero_set_samples(model, mesh, data["vol_p"][:n_near], cfg,
                                                int(cfg.seed) * 1_000_003 + step)
            hard.update(pool=data, idx=idx)
        return hard["idx"]

    micro = micro_batch_count(cfg, cfg.batch + cfg.batch_near + cfg.batch_uniform, device)
    tuner = (MicroBatchTuner(micro) if cfg.micro_batches == 0 and cfg.minutes and device.type == "cpu"
             else None)

    # the clock's seconds of pools, re-rankings, mining and draws (the asset's own work in a step) and the steps
    sampling = {"seconds": 0.0, "steps": 0}

    def step_fn(step: int, g: torch.Generator) -> dict:
        t_sample = now()
        data = pools.get(step)
        sp, sn, vp, vd, *more = _draw(data, cfg, g, hard_set(step, data), extra=extra)
        sampling["seconds"] += now() - t_sample
        sampling["steps"] += 1
        low = low_precision(step)
        # keyed by the loss variant and the CPU threads in force (nets.threads may change them): a tuning
        # never compares counts timed with different threads
        key = ("bf16" if low else "float32", torch.get_num_threads())
        k, timed = tuner.next(step, key) if tuner else (micro, False)
        t0 = time.perf_counter()  # the tuner measures the machine's real speed, whatever the budget's clock
        # back-propagated here, part by part (the loop sees a detached loss and skips its own backward)
        terms = sdf_step_backward(loss_terms, model, sp, sn, vp, vd, cfg, micro_batches=k, low_precision=low,
                                  base=tuple(more[:n_base]) if n_base else None,
                                  vol_n=more[n_base] if len(more) > n_base else None)
        if timed:
            tuner.record(k, time.perf_counter() - t0)
        return terms

    loop_cfg = cfg.loop_config(f"fit sdf {cfg.width}x{cfg.depth}")
    polish_loss = partial(_polish_loss, model=model, cfg=cfg,
                          micro=micro_batch_count(cfg, cfg.polish_points, device))
    reserve = 0.0  # seconds of the budget set aside for the polish: they come out of Adam's part
    if cfg.polish_evals and cfg.minutes:
        if cfg.polish_share > 0:
            reserve = cfg.polish_share * 60.0 * cfg.minutes
        else:  # its cost, measured on a throw-away batch (+ its held-out checks), at most half the budget
            per_eval = _seconds_per_eval(polish_loss, cfg, device, dtype, now)
            reserve = min(0.5 * 60.0 * cfg.minutes, (cfg.polish_evals + 3) * per_eval)
        loop_cfg = replace(loop_cfg, minutes=cfg.minutes - reserve / 60.0)
    t_adam = now()  # this run's Adam seconds, on the clock the sampling is timed by
    res = train(model, step_fn, loop_cfg, fingerprint=fingerprint, metadata={"mesh": mesh.name}, clock=now)
    budget = _budget(budget_key, cfg, res, 60.0 * cfg.minutes - reserve if cfg.minutes else None,
                     sampling, now() - t_adam)
    if budget is not None:  # a budgeted run may have skipped pool refreshes (sdf_pools): the account says so
        budget["pool_refreshes"] = pools.record()
    polish = None
    seconds = res.seconds
    if cfg.polish_evals:
        left = 60.0 * cfg.minutes - res.seconds if cfg.minutes else 0.0
        fit_batch, check_batch = _polish_batches(pools.get(max(res.steps - 1, 0)), cfg)
        # what is left of the budget, but at least the time set aside (Adam's last step or the pools may
        # have run over its part)
        deadline = now() + max(left, reserve) if cfg.minutes else None
        result = lbfgs_polish(model, polish_loss, fit_batch, check_batch, evals=int(cfg.polish_evals),
                              deadline=deadline, clock=now, progress=cfg.progress,
                              desc=f"fit sdf {cfg.width}x{cfg.depth}: L-BFGS polish")
        polish, seconds = result.to_dict(), seconds + result.seconds
    model.eval()
    return SdfFit(model=model, frame=mesh.frame, history=res.history, steps=res.steps, seconds=seconds,
                  config=cfg, stopped_reason=res.stopped_reason, restarts=res.restarts, polish=polish,
                  micro_batch_tuning=tuner.history if tuner else None, budget=budget, threads=res.threads,
                  sampling_seconds=sampling["seconds"],
                  distance_error=None if base is not None else sampled_distance_error(model, mesh, seed=int(cfg.seed)))


def _check_residual(cfg: SdfFitConfig, base, band, init) -> None:
    """FitError for a residual level (``base``) or warm start (``init``) fit_sdf cannot run."""
    if init is not None and (not isinstance(init, Siren) or (init.width, init.depth, init.omega_0) != (
            cfg.width, cfg.depth, cfg.omega_0)):
        raise FitError(f"fit_sdf: init must be a Siren of width {cfg.width}, depth {cfg.depth} and omega_0 "
                       f"{cfg.omega_0:g} (the config's)")
    if base is None:
        if band is not None:
            raise FitError("fit_sdf: band is the residual level's band: it needs base")
        return
    if not isinstance(base, Siren) or base.in_dim != 3 or base.out_dim != 1:
        raise FitError("fit_sdf: base must be a Siren R³ → R")
    if band is None or not (math.isfinite(band) and band > 0):
        raise FitError(f"fit_sdf: a residual level needs a positive band, got {band!r}")
    used = [k for k in ("hard_fraction", "zero_fraction", "error_sampling", "polish_evals") if getattr(cfg, k)]
    if used:
        raise FitError(f"fit_sdf: a residual level (base) does not support {', '.join(used)}; set them to 0/None")


def _preset_key(preset: str | None, cfg: SdfFitConfig) -> str | None:
    """The :data:`PRESETS` key whose step cost the run has: ``preset``'s, when the run kept its network and
    batch (else its step cost is another); None otherwise."""
    from .presets import SDF_ALIASES, resolve_preset

    key = None if preset is None else resolve_preset(preset, SDF_ALIASES, PRESETS)
    if key is not None:
        ref = replace(SdfFitConfig(), **PRESETS[key])
        if (cfg.width, cfg.depth, cfg.batch, cfg.batch_near, cfg.batch_uniform) != (
                ref.width, ref.depth, ref.batch, ref.batch_near, ref.batch_uniform):
            key = None
    return key


def _budget(key: str | None, cfg: SdfFitConfig, res, adam_seconds: float | None, sampling: dict,
            run_seconds: float) -> dict | None:
    """The budget account of Adam's part of a run (its steps against the preset's, ``key``, on this machine for
    this mesh): ``sampling`` holds the clock's seconds of this run's sampling and its step count, ``run_seconds``
    this run's Adam seconds; their split gives the mesh's own seconds a step, counted in the expected steps,
    and the steps' own work, which says whether the machine was slowed. A ``budget="steps"`` run's account
    is :func:`~neural_bake.fit.budget.steps_budget`."""
    from .budget import fit_budget, steps_budget

    n = sampling["steps"]
    asset = sampling["seconds"] / n if n else None
    compute = max(0.0, run_seconds - sampling["seconds"]) / n if n else None
    share = sampling["seconds"] / run_seconds if run_seconds > 0 else None
    if cfg.budget == "steps" and key is not None:
        return steps_budget(key, steps=res.steps, seconds=res.seconds, asset_seconds=asset, sampling_share=share)
    return fit_budget(key, steps=res.steps, seconds=res.seconds, minutes=cfg.minutes, step_cap=int(cfg.steps),
                      stopped_reason=res.stopped_reason, budget_seconds=adam_seconds,
                      sampling_share=share, asset_seconds=asset, compute_seconds=compute)


def _polish_loss(batch, *, model: Siren, cfg: SdfFitConfig, micro: int) -> torch.Tensor:
    """The polish's objective on a whole batch, its gradient left in the parameters' ``.grad``: the training
    loss plus λ·P, P = (mean |r|^p)^(1/p) over the surface points (``polish_max_weight``, ``polish_max_p``).

    P does not split over micro-batches, the mean S of |r / m|^p does (m: the batch's largest |r|, a
    constant that keeps the powers in range; P = m·S^(1/p)): a first pass without a graph gives m and S,
    then each micro-batch back-propagates its share of S with the weight λ·m·S^(1/p − 1)/p — the chain rule
    of λ·m·S^(1/p), so the gradient is exact."""
    sp, sn, vp, vd = batch
    lam, p = cfg.polish_max_weight, cfg.polish_max_p
    weight, m = 0.0, 1.0
    if lam > 0 and sp.shape[0]:
        r = first_order_distance(model, sp, micro).abs()
        m = float(r.max())
        if math.isfinite(m) and m > 0:
            weight = lam * m * float(((r / m) ** p).mean()) ** (1.0 / p - 1.0) / p
    terms = sdf_step_backward(partial(sdf_loss_terms, power_weight=weight, power_scale=m), model, sp, sn, vp, vd,
                              cfg, micro_batches=micro)
    if weight == 0.0:
        return terms["loss"]
    power = terms["power"]
    return terms["loss"] - weight * power + lam * m * power.clamp_min(0) ** (1.0 / p)


def _polish_batches(data: dict, cfg: SdfFitConfig):
    """The polish batch and its held-out check batch, ``polish_points`` pool points each: surface, near and
    uniform points in a step's proportions, seeded by ``cfg.seed``. No hard examples: the worst-distance
    term (``polish_max_weight``) weighs the worst places, and a fixed set of mined points is one the polish
    over-fits (its own loss falls, the held-out batch's barely). The two batches are disjoint where
    the pools hold enough points (the presets' do), else they overlap as little as they can."""
    gen = torch.Generator().manual_seed(int(cfg.seed) * 1_000_033 + 977)
    n_near_pool = data["n_near"]
    n_uni_pool = data["vol_p"].shape[0] - n_near_pool
    total = cfg.batch + cfg.batch_near + cfg.batch_uniform
    k_near = round(cfg.polish_points * cfg.batch_near / total) if n_near_pool else 0
    k_uni = round(cfg.polish_points * cfg.batch_uniform / total) if n_uni_pool else 0
    k_surf = max(1, cfg.polish_points - k_near - k_uni)

    def two(n_pool: int, k: int, offset: int = 0):
        if k == 0:
            return torch.zeros(0, dtype=torch.long), torch.zeros(0, dtype=torch.long)
        perms = [torch.randperm(n_pool, generator=gen) for _ in range(-(-2 * k // n_pool))]
        idx = torch.cat(perms)[: 2 * k] + offset
        return idx[:k], idx[k:]

    surf = two(data["surf_p"].shape[0], k_surf)
    near, uni = two(n_near_pool, k_near), two(n_uni_pool, k_uni, n_near_pool)
    dev, take = data["surf_p"].device, torch.index_select
    batches = []
    for h in (0, 1):
        si, vi = surf[h].to(dev), torch.cat([near[h], uni[h]]).to(dev)
        batches.append((take(data["surf_p"], 0, si), take(data["surf_n"], 0, si), take(data["vol_p"], 0, vi),
                        take(data["vol_d"], 0, vi)))
    return batches[0], batches[1]


def _seconds_per_eval(polish_loss, cfg: SdfFitConfig, device, dtype, clock=time.perf_counter) -> float:
    """Measured time (by ``clock``) of one polish evaluation (the second of two, on random points; the
    gradients it leaves are cleared by the first training step)."""
    gen = torch.Generator().manual_seed(0)
    n_s = cfg.polish_points // 2
    n_v = cfg.polish_points - n_s
    batch = (torch.rand(n_s, 3, generator=gen) * 2 - 1,
             torch.nn.functional.normalize(torch.randn(n_s, 3, generator=gen), dim=1),
             torch.rand(n_v, 3, generator=gen) * 2 - 1, torch.rand(n_v, generator=gen) - 0.5)
    batch = tuple(t.to(device=device, dtype=dtype) for t in batch)
    times = []
    for _ in range(2):
        t0 = clock()
        float(polish_loss(batch))  # float(): waits for an asynchronous device
        times.append(clock() - t0)
    return times[-1] * (1.0 + 1.0 / CHUNK_ITERATIONS)  # each L-BFGS call re-evaluates its starting point
