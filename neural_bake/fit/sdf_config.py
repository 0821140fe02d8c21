"""Settings of :func:`~neural_bake.fit.sdf.fit_sdf`: :class:`SdfFitConfig`, the :data:`PRESETS` and their checks."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

import torch

from ..errors import FitError
from ..nets.compiled import COMPILE_MODES
from .training import LoopConfig

__all__ = ["SdfFitConfig", "PRESETS", "config_from"]

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
        from .presets import SDF_ALIASES, resolve_preset

        key = resolve_preset(preset, SDF_ALIASES, PRESETS)
        if key is None:
            raise FitError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)} or "
                           f"{', '.join(f'{a} ({k})' for a, k in SDF_ALIASES.items())}")
        cfg = replace(cfg, **PRESETS[key])
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
