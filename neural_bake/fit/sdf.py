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

import hashlib
import json
import math
import time
from dataclasses import asdict, dataclass, field, fields, replace
from functools import partial
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..errors import FitError, ModelFileError
from ..nets.compiled import COMPILE_MODES, CompiledFn, long_run, should_compile
from ..nets.gemm import gemm_gradient, sin_cos
from ..nets.siren import Siren
from ..types import Frame, Mesh
from .polish import CHUNK_ITERATIONS, lbfgs_polish
from .training import LoopConfig, train

__all__ = ["SdfFitConfig", "SdfFit", "PRESETS", "fit_sdf", "load_sdf", "sdf_loss_terms", "sdf_step_backward",
           "micro_batch_count", "mixed_gradient", "focused_squares", "first_order_distance",
           "sampled_distance_error", "DISTANCE_ERROR_SOURCE"]

_DTYPES = {"float32": torch.float32, "float64": torch.float64}


@dataclass
class SdfFitConfig:
    """Settings of :func:`fit_sdf`. Presets: :data:`PRESETS`."""

    width: int = 256
    """Hidden width W of the Siren (papers' (W, D) notation)."""
    depth: int = 3
    """Number D of hidden W×W matrices (D + 1 hidden layers)."""
    omega_0: float = 30.0
    """ω0 of the first layer (hidden layers use 30); stored in the model file."""
    steps: int = 5000
    """Maximum number of optimiser steps (the run also stops at ``minutes``)."""
    minutes: float | None = None
    """Wall-clock budget in minutes (None: no budget)."""
    batch: int = 4096
    """Surface points per step."""
    batch_near: int = 4096
    """Near-surface points (with ground-truth SDF) per step."""
    batch_uniform: int = 1024
    """Uniform points in [-1, 1]³ (with ground-truth SDF) per step."""
    lr: float = 1e-4
    """Initial Adam learning rate (cosine decay to ``lr_min_factor`` of it over the steps or the time budget)."""
    lr_schedule: str = "cosine"
    """"cosine" or "constant"."""
    lr_min_factor: float = 0.05
    """Final learning rate of the cosine schedule as a fraction of ``lr`` (0 < factor ≤ 1)."""
    w_surface: float = 3000.0
    """Weight of mean f² on surface samples."""
    w_normal: float = 100.0
    """Weight of mean (1 − <∇f/|∇f|, n>) on surface samples (cosine form: bounded, |∇f| is left to eikonal)."""
    w_eikonal: float = 50.0
    """Weight of mean (1 − |∇f|)² on every point of the step."""
    w_sdf: float = 3000.0
    """Weight of mean (f − d)² on near and uniform samples (d: ground-truth signed distance)."""
    focus_tau: float = 0.0
    """Worst-point focus τ (unit frame; 0: off). Each surface residual f and off-surface residual f − d is
    weighted by 1 + min((r / τ)², 16) (:func:`focused_squares`; the weight is a constant of the step), so
    residuals above τ pull like their fourth power instead of their square: the loss leans from the mean
    towards the maximum error, which is what the Hausdorff distance measures."""
    pool_surface: int = 200_000
    """Surface samples per pool."""
    pool_near: int = 200_000
    """Near-surface samples per pool."""
    pool_uniform: int = 50_000
    """Uniform samples per pool."""
    sigmas: tuple[float, ...] = (0.003, 0.01, 0.05)
    """Standard deviations (unit frame) of the near-surface offsets, mixed in equal parts."""
    refresh_every: int = 2000
    """Steps between pool refreshes (0: never refresh)."""
    seed: int = 0
    """Seeds the initial weights, the pools and the per-step draws: the same seed gives the same model."""
    checkpoint: str | None = None
    """Checkpoint file written during training (None: no checkpoint)."""
    checkpoint_every: int = 500
    """Steps between checkpoints."""
    resume: bool = False
    """Continue from ``checkpoint`` if it exists (same mesh and settings)."""
    progress: bool = True
    """Show a progress bar with the losses."""
    log_every: int = 100
    """Steps between history entries."""
    hard_fraction: float = 0.25
    """Part of each step's surface batch drawn from the pool's hardest samples (largest |f|, hard-example
    mining; 0: off), and likewise of the near-surface batch (largest |f − d|). The worst-fitted places set
    the Hausdorff distance; this spends steps on them: on Spot, (64, 1) in 2 minutes, Hausdorff 0.017 →
    0.0074 for Chamfer-L1 0.00092 → 0.00102."""
    hard_every: int = 100
    """Steps between re-ranking the surface and near pools (with ``hard_fraction`` > 0)."""
    zero_fraction: float = 0.0
    """Part of each step's near batch drawn from mined points of the network's own zero level set (0: off):
    every ``hard_every`` steps, ``zero_candidates`` near-pool points are projected onto f = 0 (two Newton
    steps), their true signed distance d is computed, and the ``hard_pool`` part with the largest |d| —
    where the network's surface is furthest from the mesh — is trained towards f = d. It aims at the
    network → mesh half of the Hausdorff distance, which surface samples do not see."""
    zero_candidates: int = 16384
    """Near-pool points projected onto f = 0 at each mining (with ``zero_fraction`` > 0)."""
    hard_pool: float = 0.02
    """Part of each pool that counts as hard (the top of the ranking)."""
    gemm_dtype: str = "auto"
    """"float32", "bfloat16" for the hidden W×W GEMMs of the loss (forward and gradient streams; first and
    last layers, sin/cos and accumulation stay float32), or "auto": bfloat16 when the network has hidden
    W×W matrices with W ≥ 128 and a bf16 GEMM measured on the device at the start is ≥ 1.5× faster than a
    float32 one (CPUs with AMX/AVX512-BF16: 2.5× faster (256, 3) steps here), else float32. bf16 values
    carry ~1e-3 noise, so only the first ``bf16_fraction`` of the run uses it. On Spot, (256, 3), 10 min:
    5,881 steps instead of 3,837, median normal error 2.67° instead of 2.86°, the same Hausdorff."""
    bf16_fraction: float = 0.75
    """With ``gemm_dtype="bfloat16"``: the part of the run (of the steps, or of the time budget) in bf16;
    the rest trains in float32 so the final weights are tuned at full precision."""
    compile: str = "auto"
    """"on", "off" or "auto": run the loss (forward, GEMM gradients, loss terms and their backward) through
    ``torch.compile`` (:mod:`neural_bake.nets.compiled`), which fuses its element-wise work: on the AVX2
    EPYC (``bench fit``'s step timing, best of 5) a (64, 1) step 21.8 → 18.1 ms, a (256, 3) step 376 →
    340 ms, for a one-off 3–20 s of compiling (less when TorchInductor's on-disk cache holds the kernels).
    "auto" compiles runs with a budget of at least five minutes (or, without one, 5,000 steps or more)
    where a compiler is available; a failed compile warns and trains eagerly. Not part of the fingerprint:
    a checkpoint resumes with either setting."""
    micro_batches: int = 0
    """Split each step's points into this many micro-batches, each run forward and backward on its own
    (the gradients add up to the whole batch's: the loss terms are sums over the batch divided by its sizes);
    0: auto — on a CPU the power of two nearest to points × width / 2¹⁸ (about 2¹⁸ hidden activations per
    micro-batch, so a layer's working set stays in the L2 cache: (256, 3) 8 micro-batches of 1,152 points,
    (64, 1) 2), elsewhere 1. On the AVX2 EPYC a (256, 3) step 281 → 234 ms compiled, 402 → 226 ms eager
    (:data:`TRAIN_CHUNK_ELEMENTS`). A run with a time budget on a CPU starts from that rule but times the
    powers of two up to it on its own steps and keeps the fastest (:class:`MicroBatchTuner`): the best count
    depends on the machine. Not part of the fingerprint (the same trajectory up to rounding)."""
    polish_evals: int = 0
    """L-BFGS polish after the Adam run (0: off): this many loss evaluations (forward and backward of the
    whole polish batch, line-search evaluations included) of full-batch L-BFGS with a strong-Wolfe line
    search on one fixed batch of ``polish_points`` pool points
    (:func:`~neural_bake.fit.polish.lbfgs_polish`), minimising the training loss plus the worst-distance
    term (``polish_max_weight``). Adam's noisy mini-batch steps stall short of what a small network can
    reach, and its mean-square loss leaves the worst place to chance. With a time budget the polish's time
    is taken from the Adam part of the budget: ``polish_share`` of it, or (share 0) its measured cost (at
    most half of it). Kept only if the loss on
    a second, disjoint held-out batch went down. Not part of the fingerprint: a checkpointed Adam run can be
    polished with any setting."""
    polish_share: float = 0.0
    """With a time budget and ``polish_evals``: the part of the budget set aside for the polish, which then
    runs until ``polish_evals`` evaluations or the budget's end, whichever comes first (0: set aside the
    polish's cost estimated from one timed evaluation, which read 0.07–0.15 s against 0.09–0.11 s in the
    polish on one machine, leaving up to 17 s of a 2-minute budget unused or cutting the polish short). A
    share scales the evaluations with the machine's speed. Not part of the fingerprint."""
    polish_points: int = 65536
    """Points of the polish batch (and of its held-out check batch), drawn like a step's: surface, near and
    uniform points in the step's proportions."""
    polish_max_weight: float = 100.0
    """Weight λ of the polish's worst-distance term λ·(mean |r|^p)^(1/p) over the polish batch's surface
    points, r = f / max(|∇f|, 0.1) the first-order distance from a sample of the mesh to the network's zero
    set: a smooth maximum of the mesh → network half of the Hausdorff distance, which the mean-square
    training loss leaves to chance (0: polish the training loss alone). Spot, (64, 1), ten seeds at equal
    time: Hausdorff 0.0083–0.0151 → 0.0053–0.0063, Chamfer-L1 −25 %; the polish without this term lowered
    Chamfer-L1 as much but not the Hausdorff; λ 300 matched 100 with slightly worse Chamfer-L1 and normals
    (BENCHMARKS.md)."""
    polish_max_p: float = 8.0
    """Exponent p of the worst-distance term (larger: closer to the maximum, less smooth)."""
    device: str | None = None
    """torch device ("cpu", "cuda", …); None: CPU."""
    dtype: str = "float32"
    """"float32" or "float64"."""

    def loop_config(self, desc: str = "fit sdf") -> LoopConfig:
        """The training-loop part of this config."""
        return LoopConfig(steps=self.steps, minutes=self.minutes, lr=self.lr, lr_schedule=self.lr_schedule,
                          lr_min_factor=self.lr_min_factor, seed=self.seed, checkpoint=self.checkpoint,
                          checkpoint_every=self.checkpoint_every, resume=self.resume, progress=self.progress,
                          log_every=self.log_every, desc=desc)

    def fingerprint_dict(self) -> dict:
        """The settings that define the training trajectory (not budgets, paths or display)."""
        skip = {"steps", "minutes", "checkpoint", "checkpoint_every", "resume", "progress", "log_every", "compile",
                "micro_batches", "polish_evals", "polish_share", "polish_points", "polish_max_weight", "polish_max_p"}
        return {k: v for k, v in asdict(self).items() if k not in skip}


#: The training settings of the multi-layer presets. Measured on (256, 3), Spot, 10 min, AVX2 EPYC, compiled,
#: micro-batched (~1,850-2,200 steps), three seeds each (BENCHMARKS.md):
#: lr 3e-4 (was 2e-4; 1e-4 before): Hausdorff 0.0049 / 0.0053 / 0.0048 against 0.0061 / 0.0053 / 0.0060.
#: hard_pool 0.05 (default 0.02): seed 0 read 0.0044 against 0.0060 at lr 2e-4, but seeds 1-3 with 0.05
#: then read 0.0053-0.0061: no worse than 0.02, kept.
#: lr_min_factor 0.01 (default 0.05): the low-lr end of the run settles the worst places (creases, ear and
#: snout tips): Hausdorff 0.0041 / 0.0043 / 0.0042 against 0.0049 / 0.0053 / 0.0048, median normal error
#: 2.50° / 2.65° / 2.56° against 2.66° / 2.69° / 2.63°, Chamfer-L1 -20 to -30 %; 0.002 read 0.0045 (seed 1)
_MULTI_LAYER = {"lr": 3e-4, "lr_min_factor": 0.01, "hard_pool": 0.05, "steps": 100_000}

#: Architecture presets ``"WxD"`` with their time budgets (minutes; the step cap is only a safety net).
#: Measured cost of one training step at the default batch (4096 surface + 4096 near + 1024 uniform points,
#: ∇f on all 9216) on the project's 2-core AVX2 EPYC (``neural-bake bench fit``, 2026-11-30, quiet): (64, 1)
#: 17 ms (eager, 2 micro-batches), (256, 3) 277 ms (compiled, 8 micro-batches), against 39 ms and 477 ms for
#: double-backward autograd. So a 2-minute (64, 1) budget gives about 4,500–5,400 steps and a 10-minute
#: (256, 3) budget about 1,950–2,150. Accuracy at these budgets (Spot, bumpy sphere, three seeds): BENCHMARKS.md.
PRESETS: dict[str, dict] = {
    # lr 1e-3 (was 5e-4): three seeds on Spot, 2 min, compiled loss, AVX2 EPYC: Hausdorff 0.0101/0.0103/0.0122
    # against 0.0109/0.0106/0.0138; bumpy sphere (two seeds) 0.0022/0.0029 against 0.0028/0.0025.
    # lr_min_factor 0.01 did not help here (Spot seeds 0/1/2: 0.0100/0.0117/0.0104 against 0.0094/0.0090/0.0118)
    # Not step-bound: 6 minutes (15,790 steps) read 0.0117 on Spot seed 2. w_sdf 300 (3,000) read 0.0093 / 0.0095 /
    # 0.0094 / 0.0087 / 0.0086 on Spot seeds 0-4 (default 0.0094 / 0.0090 / 0.0118 / 0.0114 / 0.0086), but the bunny
    # 0.0190 / 0.0160 (default 0.0133 / 0.0142) and the bumpy sphere 0.0030 (0.0026): a trade, not in the preset.
    # w_eikonal 10 (default 50), 5,200 fixed steps (what 2 minutes reach), Spot seeds 0-9: Chamfer-L1
    # 0.00093-0.00108 against 0.00104-0.00125 and median normal error 3.58-3.66 against 3.67-3.85 deg on every
    # seed; Hausdorff mean 0.0110 against 0.0108 (<= 0.01 on 5 seeds against 3: a wider spread, no gain on the
    # mean). Bunny seeds 0/1: Hausdorff 0.0152 / 0.0120 against 0.0169 / 0.0183, Chamfer -22 %, normals 5.2
    # against 5.8 deg; bumpy sphere 0.0026 (0.0024). w_eikonal 3: Spot 0.0078 / 0.0098 / 0.0117 (seeds 0/2/3),
    # bunny 0.0161 (BENCHMARKS.md, sixth session)
    # polish_evals 150 (L-BFGS with the worst-distance term after Adam; ~20-35 s of the 2 minutes): 4,400 fixed
    # Adam steps + the polish against 5,200 steps, Spot seeds 0-9: Hausdorff 0.0053-0.0063 against 0.0083-0.0151,
    # Chamfer-L1 -25 %; bunny seeds 0/1 0.0106 / 0.0108 against 0.0152 / 0.0120 (BENCHMARKS.md, seventh session)
    # polish_share 0.25 with up to 400 evaluations (was 150 evaluations at an estimated cost): the polish's 30 s
    # are what the 150 took on the AVX2 EPYC (22-31 s); on the faster AVX-512 EPYC 150 took ~10-17 s and left
    # the bunny at Hausdorff 0.0110 (seed 0), 250-400 reached 0.0093-0.0094 (BENCHMARKS.md, ninth session)
    "64x1": {"width": 64, "depth": 1, "lr": 1e-3, "minutes": 2.0, "steps": 100_000, "w_eikonal": 10.0,
             "pool_surface": 100_000, "pool_near": 100_000, "pool_uniform": 25_000, "polish_evals": 400,
             "polish_share": 0.25},
    # (128, 2) and (256, 2): the (256, 3) settings, _MULTI_LAYER (were lr 2e-4 and 1e-4, lr_min_factor 0.05, hard_pool
    # 0.02), seed 0 (BENCHMARKS.md, fifth session). 128x2, 5 min: Spot Hausdorff 0.0083 -> 0.0069, Chamfer-L1
    # 0.00081 -> 0.00062; Stanford bunny 0.0095 -> 0.0062, 0.00103 -> 0.00068. 256x2, 8 min: Spot 0.0063 -> 0.0049,
    # 0.00078 -> 0.00055, median normal error 3.41 -> 2.91 deg; bunny 0.0104 -> 0.0080, 0.00088 -> 0.00057,
    # 3.99 -> 3.58 deg; bumpy sphere 0.0025 -> 0.0020
    "128x2": {"width": 128, "depth": 2, "minutes": 5.0, **_MULTI_LAYER},
    "256x2": {"width": 256, "depth": 2, "minutes": 8.0, **_MULTI_LAYER},
    "256x3": {"width": 256, "depth": 3, "minutes": 10.0, **_MULTI_LAYER},
}


_NONE_IS_A_VALUE = ("minutes", "checkpoint", "device")


def config_from(config: SdfFitConfig | None = None, *, preset: str | None = None, **overrides) -> SdfFitConfig:
    """A config from a preset name and/or overrides; FitError for an unknown preset or field.

    An override of None is ignored (the preset's or config's value stays), except for ``minutes``,
    ``checkpoint`` and ``device`` where None is a value: ``preset="64x1", minutes=None`` removes the budget.
    """
    cfg = config or SdfFitConfig()
    if preset is not None:
        if preset not in PRESETS:
            raise FitError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
        cfg = replace(cfg, **PRESETS[preset])
    names = {f.name for f in fields(SdfFitConfig)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise FitError(f"fit_sdf: unknown setting(s) {', '.join(unknown)}")
    # None leaves a setting as it is, except where None is a value of its own (no budget, no checkpoint)
    cfg = replace(cfg, **{k: v for k, v in overrides.items() if v is not None or k in _NONE_IS_A_VALUE})
    if isinstance(cfg.sigmas, (int, float)):
        cfg = replace(cfg, sigmas=(float(cfg.sigmas),))
    cfg = replace(cfg, sigmas=tuple(float(s) for s in cfg.sigmas))
    _check_config(cfg)
    return cfg


def _check_config(cfg: SdfFitConfig) -> None:
    for name in ("width", "batch", "pool_surface"):
        v = getattr(cfg, name)
        if int(v) != v or v < 1:
            raise FitError(f"fit_sdf: {name} must be a positive integer, got {v!r}")
    for name in ("depth", "batch_near", "batch_uniform", "pool_near", "pool_uniform", "refresh_every"):
        v = getattr(cfg, name)
        if int(v) != v or v < 0:
            raise FitError(f"fit_sdf: {name} must be a non-negative integer, got {v!r}")
    if (cfg.batch_near and not cfg.pool_near) or (cfg.batch_uniform and not cfg.pool_uniform):
        raise FitError("fit_sdf: a non-empty batch needs a non-empty pool (pool_near / pool_uniform)")
    if not (math.isfinite(cfg.omega_0) and cfg.omega_0 > 0):
        raise FitError(f"fit_sdf: omega_0 must be positive, got {cfg.omega_0!r}")
    for name in ("w_surface", "w_normal", "w_eikonal", "w_sdf", "focus_tau"):
        v = getattr(cfg, name)
        if not (math.isfinite(v) and v >= 0):
            raise FitError(f"fit_sdf: {name} must be a non-negative number, got {v!r}")
    if not cfg.sigmas or not all(math.isfinite(s) and s > 0 for s in cfg.sigmas):
        raise FitError(f"fit_sdf: sigmas must be positive numbers, got {cfg.sigmas!r}")
    if not (0.0 <= cfg.hard_fraction <= 1.0) or not (0.0 < cfg.hard_pool <= 1.0):
        raise FitError(f"fit_sdf: hard_fraction must be in [0, 1] and hard_pool in (0, 1], got "
                       f"{cfg.hard_fraction!r}, {cfg.hard_pool!r}")
    if not (0.0 <= cfg.zero_fraction <= 1.0 - cfg.hard_fraction):
        raise FitError(f"fit_sdf: zero_fraction must be in [0, 1 - hard_fraction], got {cfg.zero_fraction!r} "
                       f"(hard_fraction {cfg.hard_fraction!r})")
    if int(cfg.zero_candidates) != cfg.zero_candidates or cfg.zero_candidates < 1:
        raise FitError(f"fit_sdf: zero_candidates must be a positive integer, got {cfg.zero_candidates!r}")
    if int(cfg.hard_every) != cfg.hard_every or cfg.hard_every < 1:
        raise FitError(f"fit_sdf: hard_every must be a positive integer, got {cfg.hard_every!r}")
    if not (0.0 <= cfg.polish_share <= 0.5):
        raise FitError(f"fit_sdf: polish_share must be in [0, 0.5], got {cfg.polish_share!r}")
    if int(cfg.polish_evals) != cfg.polish_evals or cfg.polish_evals < 0:
        raise FitError(f"fit_sdf: polish_evals must be a non-negative integer (0: no polish), got {cfg.polish_evals!r}")
    if int(cfg.polish_points) != cfg.polish_points or cfg.polish_points < 2:
        raise FitError(f"fit_sdf: polish_points must be an integer of at least 2, got {cfg.polish_points!r}")
    if not (math.isfinite(cfg.polish_max_weight) and cfg.polish_max_weight >= 0):
        raise FitError(f"fit_sdf: polish_max_weight must be a non-negative number, got {cfg.polish_max_weight!r}")
    if not (math.isfinite(cfg.polish_max_p) and 1.0 <= cfg.polish_max_p <= 64.0):
        raise FitError(f"fit_sdf: polish_max_p must be a number in [1, 64], got {cfg.polish_max_p!r}")
    if int(cfg.micro_batches) != cfg.micro_batches or cfg.micro_batches < 0:
        raise FitError(f"fit_sdf: micro_batches must be a non-negative integer (0: auto), got {cfg.micro_batches!r}")
    if cfg.compile not in COMPILE_MODES:
        raise FitError(f"fit_sdf: compile must be one of {', '.join(COMPILE_MODES)}, got {cfg.compile!r}")
    if cfg.gemm_dtype not in ("auto", "float32", "bfloat16"):
        raise FitError(f"fit_sdf: gemm_dtype must be 'auto', 'float32' or 'bfloat16', got {cfg.gemm_dtype!r}")
    if not (0.0 <= cfg.bf16_fraction <= 1.0):
        raise FitError(f"fit_sdf: bf16_fraction must be in [0, 1], got {cfg.bf16_fraction!r}")
    if cfg.dtype not in _DTYPES:
        raise FitError(f"fit_sdf: dtype must be one of {', '.join(_DTYPES)}, got {cfg.dtype!r}")


@dataclass
class SdfFit:
    """A fitted SDF: the network, the frame it lives in, and how it was trained."""

    model: Siren
    """The Siren f: (N, 3) unit-frame points → (N, 1) signed distance (unit-frame units; negative inside)."""
    frame: Frame
    """Source ↔ unit frame transform of the mesh it was fitted to."""
    history: list[dict] = field(default_factory=list)
    """Logged steps: ``step``, ``seconds``, ``lr``, ``loss`` and each loss term."""
    steps: int = 0
    """Optimiser steps done."""
    seconds: float = 0.0
    """Training wall time (pool sampling included)."""
    config: SdfFitConfig = field(default_factory=SdfFitConfig)
    """The settings used."""
    stopped_reason: str = "steps"
    """"steps", "time budget" or "resumed finished run"."""
    restarts: int = 0
    """Divergence recoveries (learning-rate halvings)."""
    polish: dict | None = None
    """The L-BFGS polish's record (:class:`~neural_bake.fit.polish.PolishResult` as a dict; None: no polish)."""
    micro_batch_tuning: list[dict] | None = None
    """The micro-batch tunings of a time-budgeted run (:attr:`MicroBatchTuner.history`: step, loss variant,
    count chosen, best seconds per count); None when the count was fixed."""
    distance_error: float | None = None
    """Sampled distance error to the mesh (unit frame): max |f| at mesh surface samples
    (:func:`sampled_distance_error`); saved as the file's δ, the band a texture fit uses. None: not measured."""

    def save(self, path) -> Path:
        """Write the model file (safetensors + JSON metadata: kind="sdf", frame, δ (the sampled distance
        error, ``delta_source`` says so), config, history summary)."""
        from ..fields import save_model

        summary = self.history[-1] if self.history else {}
        delta = {} if self.distance_error is None else {
            "delta": self.distance_error, "delta_source": DISTANCE_ERROR_SOURCE}
        return save_model(
            self.model, path, kind="sdf", frame=self.frame.to_dict(), config=_jsonable(asdict(self.config)), **delta,
            training={"steps": self.steps, "seconds": round(self.seconds, 3), "stopped_reason": self.stopped_reason,
                      "restarts": self.restarts, "final": summary, "history": self.history[-200:],
                      "polish": self.polish, "micro_batch_tuning": (self.micro_batch_tuning or [])[-20:] or None},
            package_version=__version__,
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
    model, meta = field.model, field.metadata
    names = {f.name for f in fields(SdfFitConfig)}
    cfg = meta.get("config") if isinstance(meta.get("config"), dict) else {}
    cfg_dict = {k: v for k, v in cfg.items() if k in names}
    if "sigmas" in cfg_dict:
        cfg_dict["sigmas"] = tuple(cfg_dict["sigmas"])
    training = meta.get("training") if isinstance(meta.get("training"), dict) else {}
    try:
        config = SdfFitConfig(**cfg_dict)
        return SdfFit(model=model, frame=field.frame, history=list(training.get("history", [])),
                      steps=int(training.get("steps", 0)), seconds=float(training.get("seconds", 0.0)),
                      config=config, stopped_reason=str(training.get("stopped_reason", "")),
                      restarts=int(training.get("restarts", 0)), polish=training.get("polish"),
                      micro_batch_tuning=training.get("micro_batch_tuning"), distance_error=field.delta)
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


# ----------------------------------------------------------------------------------------------- losses
def mixed_gradient(model: Siren, points: torch.Tensor, gemm_dtype: torch.dtype = torch.bfloat16):
    """Values (N, 1) and gradients (N, 3) of ``model`` on the autograd graph, hidden GEMMs in ``gemm_dtype``.

    The reverse-mode GEMM gradient of :func:`~neural_bake.nets.gemm.gemm_gradient` (``differentiable=True``),
    with the D hidden W×W products of the forward pass and of the gradient stream computed on
    ``gemm_dtype`` operands (results converted back to the points' dtype); the first layer (3 → W), the
    output layer, sin/cos and the element-wise products stay in the points' dtype. Used by the training loss
    when ``SdfFitConfig.gemm_dtype == "bfloat16"``; checked against ``gemm_gradient`` in the tests.
    """
    layers = model.affine_layers()
    dtype = points.dtype
    w0, b0 = layers[0]
    h, c = sin_cos(torch.addmm(b0.to(dtype), points, w0.to(dtype).t()))
    derivs = [c]
    low = [(w.to(gemm_dtype), b.to(dtype)) for w, b in layers[1:-1]]
    for wl, b in low:
        h, c = sin_cos(torch.mm(h.to(gemm_dtype), wl.t()).to(dtype) + b)
        derivs.append(c)
    wn, bn = layers[-1]
    values = torch.addmm(bn.to(dtype), h, wn.to(dtype).t())
    g = derivs[-1] * wn.to(dtype)
    for i in range(len(derivs) - 1, 0, -1):
        g = torch.mm(g.to(gemm_dtype), low[i - 1][0]).to(dtype) * derivs[i - 1]
    return values, g @ w0.to(dtype)


def sdf_loss_terms(model: Siren, surf_p, surf_n, vol_p, vol_d, cfg: SdfFitConfig, *, low_precision: bool = False,
                   totals: tuple[int, int] | None = None, power_weight: float = 0.0,
                   power_scale: float = 1.0) -> dict:
    """The loss terms of one step (scalar tensors) and their weighted sum ``"loss"``.

    Args:
        model: the Siren being trained.
        surf_p, surf_n: (S, 3) surface points and unit outward normals (unit frame).
        vol_p, vol_d: (V, 3) off-surface points and (V,) their ground-truth signed distances.
        cfg: weights ``w_surface``, ``w_normal``, ``w_eikonal``, ``w_sdf`` and the focus ``focus_tau``.
        low_precision: hidden GEMMs in bfloat16 (:func:`mixed_gradient`) instead of float32.
        totals: (S, V) of the whole step when these points are one micro-batch of it: each term is a sum
            over these points divided by the step's sizes, so the micro-batches' terms add up to the step's
            means (default: these points' own sizes, i.e. means).
        power_weight: if > 0, the term ``"power"`` = mean over the surface points of |r / power_scale|^p,
            r the first-order distance (:func:`first_order_distance`, p = ``cfg.polish_max_p``), is added to
            the loss with this weight (the polish's worst-distance term, linearised: :func:`_polish_loss`;
            the scale, e.g. the batch's largest |r|, keeps the p-th powers in float32's range).

    ∇f of all S + V points comes from one differentiable GEMM pass (no double-backward).
    """
    s = surf_p.shape[0]
    n_s, n_v = totals if totals is not None else (s, vol_p.shape[0])
    pts = torch.cat([surf_p, vol_p], dim=0) if vol_p.shape[0] else surf_p
    if low_precision and model.depth > 0:
        values, grads = mixed_gradient(model, pts, torch.bfloat16)
    else:
        values, grads = gemm_gradient(model, pts, "reverse", differentiable=True)
    f = values[:, 0]
    gnorm = torch.linalg.vector_norm(grads, dim=1)
    sq_surf = focused_squares(f[:s] ** 2, cfg.focus_tau)
    sq_vol = focused_squares((f[s:] - vol_d) ** 2, cfg.focus_tau)
    terms = {
        "surface": sq_surf.sum() / max(n_s, 1),
        "normal": (1.0 - (grads[:s] * surf_n).sum(dim=1) / gnorm[:s].clamp_min(1e-6)).sum() / max(n_s, 1),
        "eikonal": ((1.0 - gnorm) ** 2).sum() / max(n_s + n_v, 1),
    }
    terms["sdf"] = sq_vol.sum() / max(n_v, 1) if vol_p.shape[0] else f.new_zeros(())
    terms["loss"] = (cfg.w_surface * terms["surface"] + cfg.w_normal * terms["normal"]
                     + cfg.w_eikonal * terms["eikonal"] + cfg.w_sdf * terms["sdf"])
    if power_weight > 0:
        r = f[:s] / (gnorm[:s].clamp_min(FIRST_ORDER_MIN_SLOPE) * power_scale)
        terms["power"] = r.abs().pow(cfg.polish_max_p).sum() / max(n_s, 1)
        terms["loss"] = terms["loss"] + power_weight * terms["power"]
    return terms


#: The slope below which :func:`first_order_distance` stops dividing (|∇f| of a trained SDF is ~1 on its
#: surface; where it sags to 0 the first-order distance would blow up).
FIRST_ORDER_MIN_SLOPE = 0.1


def first_order_distance(model: Siren, points: torch.Tensor, chunks: int = 1) -> torch.Tensor:
    """f / max(|∇f|, 0.1) at ``points`` (N,), no graph: Taubin's first-order estimate of the distance from
    each point to the zero set of f (GEMM gradients, in ``chunks`` parts)."""
    out = []
    with torch.no_grad():
        for part in torch.tensor_split(points, max(1, min(int(chunks), points.shape[0]))):
            values, grads = gemm_gradient(model, part, "reverse")
            out.append(values[:, 0] / torch.linalg.vector_norm(grads, dim=1).clamp_min(FIRST_ORDER_MIN_SLOPE))
    return torch.cat(out) if out else points.new_zeros(0)


#: Cap of the focus weight's (r / τ)² (see ``SdfFitConfig.focus_tau``): early in a run, when residuals are
#: many τ, the worst points would otherwise swamp the step.
FOCUS_CAP = 16.0


def focused_squares(sq: torch.Tensor, tau: float) -> torch.Tensor:
    """Squared residuals ``sq`` weighted by 1 + min(sq / τ², :data:`FOCUS_CAP`), the weights constants of the
    step (no gradient flows through them); ``sq`` itself when τ ≤ 0 (the focus off)."""
    if tau <= 0:
        return sq
    return sq * (1.0 + (sq.detach() / (tau * tau)).clamp_max(FOCUS_CAP))


#: Hidden activations (points × width) per training micro-batch that ``micro_batches=0`` aims at: a
#: (256, 3) step's working set per layer then stays in a core's 1 MB L2. Step timings on the AVX2 EPYC,
#: 9,216 points, best of interleaved rounds, 1 part against the auto choice: (256, 3) 8 parts, compiled
#: 281 → 234 ms, eager 402 → 226 ms; (128, 2) 4 parts, compiled 84 → 64 ms, eager 107 → 74 ms; (64, 1) 2 parts,
#: eager 21.9 → 17.4 ms, compiled 13.9 → 14.2 ms (no gain: its activations nearly fit).
TRAIN_CHUNK_ELEMENTS = 1 << 18


def micro_batch_count(cfg: SdfFitConfig, n_points: int, device) -> int:
    """How many micro-batches a step of ``n_points`` points runs in (``cfg.micro_batches``; 0: auto)."""
    if cfg.micro_batches:
        return int(cfg.micro_batches)
    if torch.device(device).type != "cpu" or n_points * cfg.width <= TRAIN_CHUNK_ELEMENTS:
        return 1
    return 2 ** max(0, round(math.log2(n_points * cfg.width / TRAIN_CHUNK_ELEMENTS)))


#: Steps between two re-tunings of the micro-batch count of a time-budgeted run (:class:`MicroBatchTuner`).
TUNE_EVERY = 200


class MicroBatchTuner:
    """The micro-batch count of a time-budgeted CPU run (``micro_batches=0``), chosen by timing real steps.

    Which count is fastest depends on the machine and on its moment: on the AVX2 EPYC a (256, 3) step in one
    part took 1.3–1.8x as long as in 8; on the AVX-512 EPYC that replaced it (2026-11-30) one part was the
    fastest compiled step while the VM's memory traffic was slow (150 against 174 ms in 8) and 2–4 parts
    otherwise (136–145 ms). So the tuner runs the powers of two from 1 up to the rule's count
    (:func:`micro_batch_count`), at most four of them, in interleaved rounds on the run's own steps (``rounds``
    steps each; the first tuning of a loss variant runs one more round, untimed, which pays any compile of its
    shapes), keeps the fastest, and tunes again every ``every`` steps and whenever ``key`` (the loss variant:
    bf16 or float32 GEMMs) changes. The steps it times are training steps like the others: the parts'
    gradients add up to the whole batch's for any count, so tuning costs only the few steps run at a slower
    count. Only for time-budgeted runs, which depend on the machine's speed anyway; a run with a step count
    keeps the rule's count so that a seed reproduces bit for bit."""

    def __init__(self, rule: int, *, rounds: int = 2, every: int = TUNE_EVERY):
        top = max(1, int(rule))
        self.candidates = [1 << i for i in range(top.bit_length()) if (1 << i) <= top][-4:]
        self.rounds, self.every = int(rounds), int(every)
        self.choice = top
        self.history: list[dict] = []  # one per tuning: the step it began at, the variant, seconds per count
        self._queue: list[tuple[int, bool]] = []  # (count, timed) of the tuning under way
        self._times: dict[int, float] = {}
        self._seen: set = set()
        self._key = None
        self._last = None

    def next(self, step: int, key=None) -> tuple[int, bool]:
        """The count for this step and whether to time it (then report with :meth:`record`)."""
        if len(self.candidates) == 1:
            return self.choice, False
        if not self._queue and (key != self._key or self._last is None or step - self._last >= self.every):
            self._key, self._last, self._times = key, step, {}
            warm = key not in self._seen
            self._seen.add(key)
            # (count, timed): the warm-up round of a new variant is not timed
            self._queue = [(k, r >= warm) for r in range(self.rounds + warm) for k in self.candidates]
        return self._queue.pop(0) if self._queue else (self.choice, False)

    def record(self, k: int, seconds: float) -> None:
        """A timed step's seconds; after the tuning's last step, the fastest count becomes the choice."""
        self._times[k] = min(self._times.get(k, math.inf), float(seconds))
        if not self._queue:
            self.choice = min(self._times, key=self._times.get)
            self.history.append({"step": int(self._last), "variant": str(self._key), "choice": self.choice,
                                 "seconds": {int(c): round(t, 5) for c, t in sorted(self._times.items())}})


def sdf_step_backward(loss_fn, model: Siren, surf_p, surf_n, vol_p, vol_d, cfg: SdfFitConfig, *,
                      micro_batches: int = 1, low_precision: bool = False) -> dict:
    """Forward and backward of one training step in ``micro_batches`` parts; the detached loss terms.

    Each part (a slice of the surface points and one of the off-surface points) runs ``loss_fn``
    (:func:`sdf_loss_terms` or its compiled form) with the step's totals and is back-propagated at once,
    so its graph is freed before the next part is built; the parameters' ``.grad`` add up to the whole
    step's. Returns the terms summed over the parts (the whole step's, detached).
    """
    totals = (surf_p.shape[0], vol_p.shape[0])
    k = max(1, min(int(micro_batches), totals[0] + totals[1]))
    out: dict = {}
    parts = zip(*(torch.tensor_split(t, k) for t in (surf_p, surf_n, vol_p, vol_d)))
    for sp, sn, vp, vd in parts:
        if sp.shape[0] + vp.shape[0] == 0:
            continue
        terms = loss_fn(model, sp, sn, vp, vd, cfg, low_precision=low_precision, totals=totals)
        terms["loss"].backward()
        for key, val in terms.items():
            out[key] = out[key] + val.detach() if key in out else val.detach()
    return out


# ----------------------------------------------------------------------------------------------- pools
class _Pools:
    """Sample pools drawn from the mesh, rebuilt for every refresh index (deterministic in (seed, index))."""

    def __init__(self, mesh: Mesh, cfg: SdfFitConfig, device, dtype):
        self.mesh, self.cfg, self.device, self.dtype = mesh, cfg, device, dtype
        self.index = None

    def get(self, step: int):
        idx = step // self.cfg.refresh_every if self.cfg.refresh_every else 0
        if idx != self.index:
            self._build(idx)
        return self.data

    def _build(self, idx: int) -> None:
        from .sampling import sample_near, sample_surface, sample_uniform

        cfg, mesh = self.cfg, self.mesh
        seed = int(cfg.seed) * 10_007 + idx
        try:
            surf = sample_surface(mesh, cfg.pool_surface, seed=seed)
            near = sample_near(mesh, cfg.pool_near, sigma=cfg.sigmas, seed=seed + 1) if cfg.pool_near else None
            uni = sample_uniform(mesh, cfg.pool_uniform, seed=seed + 2) if cfg.pool_uniform else None
        except (ValueError, RuntimeError) as exc:
            raise FitError(f"{mesh.name}: cannot sample the mesh for fitting ({exc})") from None

        def t(a):
            return torch.as_tensor(np.ascontiguousarray(a), dtype=self.dtype, device=self.device)

        vol_p = [v.points for v in (near, uni) if v is not None]
        vol_d = [v.sdf for v in (near, uni) if v is not None]
        if surf.points.shape[0] == 0:
            raise FitError(f"{mesh.name}: no surface samples (every face is degenerate)")
        vp = np.concatenate(vol_p) if vol_p else np.zeros((0, 3), np.float32)
        vd = np.concatenate(vol_d) if vol_d else np.zeros(0, np.float32)
        finite = np.isfinite(vd) & np.isfinite(vp).all(axis=1)
        n_near = int(finite[: near.points.shape[0]].sum()) if near is not None else 0
        self.data = {"surf_p": t(surf.points), "surf_n": t(surf.normals), "vol_p": t(vp[finite]),
                     "vol_d": t(vd[finite]), "n_near": n_near}
        self.index = idx


def _hard_indices(model: Siren, points: torch.Tensor, cfg: SdfFitConfig, target: torch.Tensor | None = None):
    """Indices of the ``hard_pool`` part of ``points`` with the largest |f − target| (target 0: |f|; at
    least one)."""
    with torch.no_grad():
        err = model(points)[:, 0]
        err = (err if target is None else err - target).abs()
    return _top_part(err, cfg.hard_pool)


def _top_part(err: torch.Tensor, part: float) -> torch.Tensor:
    """Indices of the ``part`` of ``err`` (n,) with the largest values (at least one; 0 < part ≤ 1)."""
    return torch.topk(err, max(1, int(round(part * err.shape[0]))), sorted=False).indices


def _zero_set_samples(model: Siren, mesh: Mesh, near_p: torch.Tensor, cfg: SdfFitConfig, seed: int):
    """Mined points of the network's zero level set and their true signed distances: ``(points (k, 3),
    d (k,))`` (see ``SdfFitConfig.zero_fraction``), or None when no candidate reached f ≈ 0."""
    from .metrics import project_to_zero_set
    from .sampling import signed_distance

    gen = torch.Generator().manual_seed(seed)
    pick = torch.randint(0, near_p.shape[0], (int(cfg.zero_candidates),), generator=gen).to(near_p.device)
    x = project_to_zero_set(model, torch.index_select(near_p, 0, pick), 2)
    with torch.no_grad():
        f = model(x)[:, 0]
    ok = torch.isfinite(x).all(dim=1) & (f.abs() <= 1e-3)
    x = x[ok]
    if x.shape[0] == 0:
        return None
    d = torch.as_tensor(signed_distance(mesh, x.double().cpu().numpy()), dtype=x.dtype, device=x.device)
    top = _top_part(d.abs(), cfg.hard_pool)
    return x[top].contiguous(), d[top].contiguous()


def _bf16_pays(cfg: SdfFitConfig, device, dtype) -> bool:
    """gemm_dtype="auto": does a bf16 W×W GEMM beat a float32 one by 1.5× on this device (measured)?"""
    if cfg.depth < 1 or cfg.width < 128 or dtype != torch.float32:
        return False
    a = torch.rand(4096, cfg.width, device=device)
    w = torch.rand(cfg.width, cfg.width, device=device)
    best = {}
    for name, (x, y) in {"f32": (a, w), "bf16": (a.bfloat16(), w.bfloat16())}.items():
        times = []
        for _ in range(6):
            t0 = time.perf_counter()
            torch.mm(x, y).sum().item()  # .item(): waits for an asynchronous device
            times.append(time.perf_counter() - t0)
        best[name] = min(times[1:])
    return best["f32"] >= 1.5 * best["bf16"]


def _with_hard(idx: torch.Tensor, hard: torch.Tensor | None, fraction: float, gen: torch.Generator):
    """``idx`` (n,) with its last ``fraction`` · n entries drawn from ``hard`` instead (unchanged if None)."""
    n_hard = int(idx.shape[0] * fraction) if hard is not None else 0
    if n_hard:
        pick = torch.randint(0, hard.shape[0], (n_hard,), generator=gen)
        idx[idx.shape[0] - n_hard:] = hard.to(idx.device)[pick.to(hard.device)]
    return idx


def _draw(pools: dict, cfg: SdfFitConfig, gen: torch.Generator, hard: dict | None = None):
    """A step's batch; with ``hard`` ({"surf", "near"} index tensors) the tail of the surface and near
    batches (``hard_fraction`` of each) comes from the hard sets."""
    dev = pools["surf_p"].device
    hard = hard or {}
    si = torch.randint(0, pools["surf_p"].shape[0], (cfg.batch,), generator=gen).to(dev)
    si = _with_hard(si, hard.get("surf"), cfg.hard_fraction, gen)
    n_near, n_vol = pools["n_near"], pools["vol_p"].shape[0]
    parts = []
    if cfg.batch_near and n_near:  # hard near indices point into the near part of the volume pool
        ni = torch.randint(0, n_near, (cfg.batch_near,), generator=gen)
        parts.append(_with_hard(ni, hard.get("near"), cfg.hard_fraction, gen))
    if cfg.batch_uniform and n_vol > n_near:
        parts.append(torch.randint(n_near, n_vol, (cfg.batch_uniform,), generator=gen))
    vi = torch.cat(parts).to(dev) if parts else torch.zeros(0, dtype=torch.long, device=dev)
    # index_select, not x[idx]: advanced indexing of these small rows cost 0.43 ms per gather on the EPYC
    # (1.7 ms of a 24 ms (64, 1) step), index_select a quarter of that
    take = torch.index_select
    vp, vd = take(pools["vol_p"], 0, vi), take(pools["vol_d"], 0, vi)
    zero = hard.get("zero")
    n_zero = int(cfg.batch_near * cfg.zero_fraction) if zero is not None and cfg.batch_near and n_near else 0
    if n_zero:  # the head of the near batch: mined zero-set points with their true distances
        pick = torch.randint(0, zero[0].shape[0], (n_zero,), generator=gen).to(dev)
        vp[:n_zero] = take(zero[0], 0, pick)
        vd[:n_zero] = take(zero[1], 0, pick)
    return take(pools["surf_p"], 0, si), take(pools["surf_n"], 0, si), vp, vd


def _fingerprint(mesh: Mesh, cfg: SdfFitConfig) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    h.update(json.dumps(_jsonable(cfg.fingerprint_dict()), sort_keys=True).encode())
    return h.hexdigest()[:32]


# ----------------------------------------------------------------------------------------------- fitting
def fit_sdf(mesh: Mesh, config: SdfFitConfig | None = None, *, preset: str | None = None, **overrides) -> SdfFit:
    """Train a Siren SDF of ``mesh`` (unit frame) and return an :class:`SdfFit`.

    Args:
        mesh: a :class:`~neural_bake.types.Mesh` (unit frame; e.g. from ``load_mesh``). Open meshes are
            signed by the generalised winding number (see :mod:`neural_bake.fit.sampling`).
        config: the settings (default :class:`SdfFitConfig`).
        preset: ``"64x1"``, ``"128x2"``, ``"256x2"`` or ``"256x3"`` (:data:`PRESETS`), applied before
            ``overrides``.
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
    device = torch.device(cfg.device or "cpu")
    dtype = _DTYPES[cfg.dtype]
    gen = torch.Generator().manual_seed(int(cfg.seed))
    model = Siren(cfg.width, cfg.depth, omega_0=cfg.omega_0, generator=gen).to(device=device, dtype=dtype)
    model.train()
    pools = _Pools(mesh, cfg, device, dtype)

    fingerprint = _fingerprint(mesh, cfg)  # of the settings as asked ("auto" included)
    if cfg.gemm_dtype == "auto":
        cfg = replace(cfg, gemm_dtype="bfloat16" if _bf16_pays(cfg, device, dtype) else "float32")
    use_bf16 = cfg.gemm_dtype == "bfloat16" and cfg.bf16_fraction > 0
    compiled = should_compile(cfg.compile, device, long_run=long_run(cfg.steps, cfg.minutes))
    cfg = replace(cfg, compile="on" if compiled else "off")
    loss_terms = CompiledFn(sdf_loss_terms, enabled=compiled, desc=f"fit sdf {cfg.width}x{cfg.depth}")
    t_start = time.perf_counter()

    def low_precision(step: int) -> bool:
        if not use_bf16:
            return False
        frac = step / max(cfg.steps, 1)
        if cfg.minutes:  # resumed runs restart this clock: the switch may come later than in one run
            frac = max(frac, (time.perf_counter() - t_start) / (60.0 * cfg.minutes))
        return frac < cfg.bf16_fraction

    hard = {"pool": None, "idx": None}  # idx: {"surf", "near"} index tensors

    def hard_set(step: int, data: dict) -> dict | None:
        # re-ranked every hard_every steps, at each pool refresh and at each checkpoint step, so that a run
        # resumed from a periodic checkpoint re-ranks exactly where the uninterrupted run did
        if cfg.hard_fraction <= 0 and cfg.zero_fraction <= 0:
            return None
        at_checkpoint = bool(cfg.checkpoint) and step % cfg.checkpoint_every == 0
        if hard["idx"] is None or hard["pool"] is not data or step % cfg.hard_every == 0 or at_checkpoint:
            idx, n_near = {}, data["n_near"]
            if cfg.hard_fraction > 0:
                idx["surf"] = _hard_indices(model, data["surf_p"], cfg)
                if cfg.batch_near and n_near:
                    idx["near"] = _hard_indices(model, data["vol_p"][:n_near], cfg, data["vol_d"][:n_near])
            if cfg.zero_fraction > 0 and cfg.batch_near and n_near:
                idx["zero"] = _zero_set_samples(model, mesh, data["vol_p"][:n_near], cfg,
                                                int(cfg.seed) * 1_000_003 + step)
            hard.update(pool=data, idx=idx)
        return hard["idx"]

    micro = micro_batch_count(cfg, cfg.batch + cfg.batch_near + cfg.batch_uniform, device)
    tuner = (MicroBatchTuner(micro) if cfg.micro_batches == 0 and cfg.minutes and device.type == "cpu"
             else None)

    def step_fn(step: int, g: torch.Generator) -> dict:
        data = pools.get(step)
        sp, sn, vp, vd = _draw(data, cfg, g, hard_set(step, data))
        low = low_precision(step)
        k, timed = tuner.next(step, "bf16" if low else "float32") if tuner else (micro, False)
        t0 = time.perf_counter()
        # back-propagated here, part by part (the loop sees a detached loss and skips its own backward)
        terms = sdf_step_backward(loss_terms, model, sp, sn, vp, vd, cfg, micro_batches=k, low_precision=low)
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
            per_eval = _seconds_per_eval(polish_loss, cfg, device, dtype)
            reserve = min(0.5 * 60.0 * cfg.minutes, (cfg.polish_evals + 3) * per_eval)
        loop_cfg = replace(loop_cfg, minutes=cfg.minutes - reserve / 60.0)
    res = train(model, step_fn, loop_cfg, fingerprint=fingerprint, metadata={"mesh": mesh.name})
    polish = None
    seconds = res.seconds
    if cfg.polish_evals:
        left = 60.0 * cfg.minutes - res.seconds if cfg.minutes else 0.0
        fit_batch, check_batch = _polish_batches(pools.get(max(res.steps - 1, 0)), cfg)
        # what is left of the budget, but at least the time set aside (Adam's last step or the pools may
        # have run over its part)
        deadline = time.perf_counter() + max(left, reserve) if cfg.minutes else None
        result = lbfgs_polish(model, polish_loss, fit_batch, check_batch, evals=int(cfg.polish_evals),
                              deadline=deadline, progress=cfg.progress,
                              desc=f"fit sdf {cfg.width}x{cfg.depth}: L-BFGS polish")
        polish, seconds = result.to_dict(), seconds + result.seconds
    model.eval()
    return SdfFit(model=model, frame=mesh.frame, history=res.history, steps=res.steps, seconds=seconds,
                  config=cfg, stopped_reason=res.stopped_reason, restarts=res.restarts, polish=polish,
                  micro_batch_tuning=tuner.history if tuner else None,
                  distance_error=sampled_distance_error(model, mesh, seed=int(cfg.seed)))


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
    over-fits (Spot, (64, 1): its loss −12 %, the held-out batch's −2 %). The two batches are disjoint where
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


def _seconds_per_eval(polish_loss, cfg: SdfFitConfig, device, dtype) -> float:
    """Measured wall time of one polish evaluation (the second of two, on random points; the
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
        t0 = time.perf_counter()
        float(polish_loss(batch))  # float(): waits for an asynchronous device
        times.append(time.perf_counter() - t0)
    return times[-1] * (1.0 + 1.0 / CHUNK_ITERATIONS)  # each L-BFGS call re-evaluates its starting point
