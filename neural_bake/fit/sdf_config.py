"""Settings of :func:`~neural_bake.fit.sdf.fit_sdf`: :class:`SdfFitConfig`, the :data:`PRESETS` and their checks."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

from ..constants import MAX_TILE_GRID
from ..errors import FitError
from ..nets.compiled import COMPILE_MODES
from .config_checks import DTYPES as _DTYPES, check_counts, check_sigmas, check_weights
from .training import PresetLoopSettings

__all__ = ["SdfFitConfig", "PRESETS", "config_from"]


@dataclass
class SdfFitConfig(PresetLoopSettings):
    """Settings of :func:`fit_sdf` (the loop's first: :class:`~neural_bake.fit.training.PresetLoopSettings`).
    Presets: :data:`PRESETS`."""

    steps: int = 5000  # the loop's settings with this fit's defaults
    log_every: int = 100
    width: int = 256
    """Hidden width W of the Siren (papers' (W, D) notation)."""
    depth: int = 3
    """Number D of hidden W×W matrices (D + 1 hidden layers)."""
    omega_0: float = 30.0
    """ω0 of the first layer (hidden layers use 30); stored in the model file."""
    batch: int = 4096
    """Surface points per step."""
    batch_near: int = 4096
    """Near-surface points (with ground-truth SDF) per step."""
    batch_uniform: int = 1024
    """Uniform points in [-1, 1]³ (with ground-truth SDF) per step."""
    w_surface: float = 3000.0
    """Weight of mean f² on surface samples."""
    w_normal: float = 100.0
    """Weight of the normal term, mean (1 − cos θ) over the surface samples, θ the angle between ∇f and the
    target normal (about θ²/2: large angles, at creases and noise, pull hardest; |∇f| is left to the
    eikonal term)."""
    w_angle: float = 0.0
    """Weight of the angle term, mean (√(2(1 − cos θ) + ε²) − ε) over the surface samples: the chord
    2 sin(θ/2) ≈ θ in radians, smoothed below ε = :data:`~neural_bake.constants.NORMAL_ANGLE_EPS`. Every
    angle pulls alike, so the many small angles that set a map's median get a larger share of each step
    than under the normal term's θ²/2 (docs/findings.md)."""
    w_near_normal: float = 0.0
    """Weight of the angle term at the near-surface samples within ``near_normal_reach`` of the mesh, towards
    the normal (of ``surface_normals``' kind) at each one's closest point, what an exact SDF's gradient is
    there (:func:`~neural_bake.fit.sampling.distance_gradient_targets`), as a mean over the step's off-surface
    points. A bake reads ∇f at the coarse mesh's points, off the surface by up to the coarse mesh's distance
    from it; the surface terms alone leave ∇f there to the distances (docs/findings.md). The SIREN levels'
    term (a tile level does not read it). 0: off (no target computed)."""
    near_normal_reach: float = 0.03
    """Distance from the mesh (unit frame) out to which a near-surface sample gets a normal target."""
    near_normal_gap_share: float = 0.0
    """Share of the gap on a near sample's side of the mesh (from its closest point along the normal to the
    next piece of the mesh) within which it gets a normal target: between sheets closer than the reach (thin
    walls) the exact gradient turns over halfway across. 0: no bound but the reach."""
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
    hard_fraction: float = 0.25
    """Part of each step's surface batch drawn from the pool's hardest samples (largest |f|, hard-example
    mining; 0: off), and likewise of the near-surface batch (largest |f − d|). The worst-fitted places set
    the Hausdorff distance; this spends steps on them, trading a little Chamfer-L1 for a lower Hausdorff
    distance (docs/findings.md)."""
    surface_normals: str = "vertex"
    """Normals the normal term pulls ∇f towards at surface samples: "vertex" (the interpolated vertex normals,
    the file's own where it has them: the shading a renderer and a classical bake show, which the bake report
    scores maps against) or "face" (the sampled face's geometric normal: an unbiased sample of the smooth
    surface the mesh approximates, better when that surface is known and the mesh is only its sampling). The
    trade-off, measured: docs/findings.md."""
    curvature_sampling: float = 0.0
    """Part of the surface and near-surface pools drawn by the mesh's curvature (0: off, all uniform by
    area): faces are drawn with :func:`~neural_bake.fit.sampling.curvature_face_weights` with a uniform share
    of 1 − this, so creases and fine relief get more of each step's points (i3d's curvature-aware sampling)."""
    texel_sampling: float = 0.0
    """Part of the surface and near-surface pools drawn by the mesh's UV area (0: off): faces are drawn as
    densely as a map's texels lie on them (:func:`~neural_bake.fit.sampling.map_texel_weights`: by UV area,
    an overlapped or repeated texel counted once), the rest as ``curvature_sampling`` says; for an asset baked
    onto itself, whose map's texels are where its normals are read (a layout that gives small parts many
    texels gives them as many samples). No UVs: off."""
    edge_sampling: float = 0.0
    """Part of the surface and near-surface pools drawn within ``edge_band`` of the mesh's hard edges, on both
    faces of each (0: off; :func:`~neural_bake.fit.sampling.hard_edge_sides`: where the file's own normals
    split, so a mesh without normals has none and keeps its draws): where the field rounds a board's right
    angle, which area sampling gives a few points of a large face."""
    edge_band: float = 0.01
    """Width of ``edge_sampling``'s strips (unit frame, across the face)."""
    error_sampling: float = 0.0
    """Part of each step's surface batch drawn by the network's current normal error (0: off): every
    ``hard_every`` steps the angle error 1 − cos(∇f, n) is measured at every surface pool point, and this
    part of the batch is drawn with probability proportional to it (importance resampling); the rest stays
    uniform over the pool, the floor that keeps every region trained."""
    hard_every: int = 100
    """Steps between re-ranking the surface and near pools (with ``hard_fraction`` > 0)."""
    zero_fraction: float = 0.0
    """Part of each step's near batch drawn from mined points of the network's own zero level set (0: off):
    every ``hard_every`` steps, ``zero_candidates`` near-pool points are projected onto f = 0 (two Newton
    steps), their true signed distance d is computed, and the ``hard_pool`` part with the largest |d| —
    where the network's surface is furthest from the mesh — is trained towards f = d. It aims at the
    network → mesh half of the Hausdorff distance, which surface samples do not see."""
    sign_fraction: float = 0.0
    """Part of each step's uniform batch drawn from the pool's off-surface points where the network has the
    wrong sign (0: off): every ``hard_every`` steps f is evaluated at the uniform pool points, and those whose
    true distance d is at least :data:`~neural_bake.constants.SIGN_MINING_TOL` from the surface while f and d
    differ in sign — a piece of stray surface, or a hole, away from the mesh — are trained towards f = d.
    Where there are none the batch is unchanged."""
    audit_candidates: int = 0
    """The residual construction's band audit (0: off): after the coarse level h, this many uniform candidates
    are moved onto h's small values, and those inside the fine level's band whose true distance exceeds |h|
    by more than h's own distance error — where h comes close to zero away from the mesh, and the fine level
    could grow a stray piece of surface — join every pool's uniform points with their true distances (so
    ``sign_fraction``'s mining sees them)."""
    zero_candidates: int = 16384
    """Near-pool points projected onto f = 0 at each mining (with ``zero_fraction`` > 0)."""
    hard_pool: float = 0.02
    """Part of each pool that counts as hard (the top of the ranking)."""
    gemm_dtype: str = "auto"
    """"float32", "bfloat16" for the hidden W×W GEMMs of the loss (forward and gradient streams; first and
    last layers, sin/cos and accumulation stay float32), or "auto": bfloat16 when the network has hidden
    W×W matrices with W ≥ 128 and a bf16 GEMM measured on the device at the start is ≥ 1.5× faster than a
    float32 one (CPUs with bf16 matrix instructions), else float32. bf16 values carry ~1e-3 noise, so only
    the first ``bf16_fraction`` of the run uses it."""
    bf16_fraction: float = 0.75
    """With ``gemm_dtype="bfloat16"``: the part of the run (of the steps, or of the time budget) in bf16;
    the rest trains in float32 so the final weights are tuned at full precision."""
    compile: str = "auto"
    """"on", "off" or "auto": run the loss (forward, GEMM gradients, loss terms and their backward) through
    ``torch.compile`` (:mod:`neural_bake.nets.compiled`), which fuses its element-wise work, for a one-off
    cost of compiling (less when TorchInductor's on-disk cache holds the kernels). "auto" compiles runs with a budget of at least five minutes (or, without one, 5,000 steps or more)
    where a compiler is available; a failed compile warns and trains eagerly. Not part of the fingerprint:
    a checkpoint resumes with either setting."""
    micro_batches: int = 0
    """Split each step's points into this many micro-batches, each run forward and backward on its own
    (the gradients add up to the whole batch's: the loss terms are sums over the batch divided by its sizes);
    0: auto — on a CPU the power of two nearest to points × width / 2¹⁸ (about 2¹⁸ hidden activations per
    micro-batch, so a layer's working set stays in the L2 cache: (256, 3) 8 micro-batches of 1,152 points,
    (64, 1) 2; :data:`~neural_bake.fit.sdf_tuning.TRAIN_CHUNK_ELEMENTS`), elsewhere 1. A run with a time budget on a CPU starts from that rule but times the
    powers of two up to it on its own steps and keeps the fastest
    (:class:`~neural_bake.fit.sdf_tuning.MicroBatchTuner`): the best count
    depends on the machine. Not part of the fingerprint (the same trajectory up to rounding)."""
    polish_evals: int = 0
    """L-BFGS polish after the Adam run (0: off): this many loss evaluations (forward and backward of the
    whole polish batch, line-search evaluations included) of full-batch L-BFGS with a strong-Wolfe line
    search on one fixed batch of ``polish_points`` pool points
    (:func:`~neural_bake.fit.polish.lbfgs_polish`), minimising the training loss plus the worst-distance
    term (``polish_max_weight``). Adam's noisy mini-batch steps stall short of what a small network can
    reach, and its mean-square loss leaves the worst place to chance. With a time budget the polish's time
    is taken from the Adam part of the budget: ``polish_share`` of it, or (share 0) its measured cost (at
    most half of it). Kept only if the loss on a second, disjoint held-out batch went down. Not part of the fingerprint: a checkpointed Adam run can be
    polished with any setting."""
    polish_share: float = 0.0
    """With a time budget and ``polish_evals``: the part of the budget set aside for the polish, which then
    runs until ``polish_evals`` evaluations or the budget's end, whichever comes first (0: set aside the
    polish's cost estimated from one timed evaluation, a noisy estimate that can leave part of the budget
    unused or cut the polish short). A share scales the evaluations with the machine's speed. Not part of
    the fingerprint."""
    polish_points: int = 65536
    """Points of the polish batch (and of its held-out check batch), drawn like a step's: surface, near and
    uniform points in the step's proportions."""
    polish_max_weight: float = 100.0
    """Weight λ of the polish's worst-distance term λ·(mean |r|^p)^(1/p) over the polish batch's surface
    points, r = f / max(|∇f|, 0.1) the first-order distance from a sample of the mesh to the network's zero
    set: a smooth maximum of the mesh → network half of the Hausdorff distance, which the mean-square
    training loss leaves to chance (0: polish the training loss alone; docs/findings.md)."""
    polish_max_p: float = 8.0
    """Exponent p of the worst-distance term (larger: closer to the maximum, less smooth)."""
    construction: str = "plain"
    """How the network is built: "plain" (one network), "residual" (a coarse level, then a fine one of the
    rest of ``width`` trained inside its band; the quick, default and high presets') or "residual-warm". In detail
    (:mod:`neural_bake.fit.residual`): "plain", one SIREN of ``width`` fitted to the mesh; "residual", a
    coarse SIREN of ``coarse_width`` (ω0 ``coarse_omega_0``) fitted for ``coarse_share`` of the budget, then
    a fine one of ``width − coarse_width`` fitted for the rest so that their sum fits the mesh, supervised
    only inside the coarse level's band (``band_factor`` × its sampled distance error): the fine level spends
    its capacity on detail (nested-neighbourhoods §3). The file holds the sum as one SIREN of ``width`` (its
    cost to bake is a plain fit's); "residual-warm", the coarse level grown to ``width`` by fresh units and
    fitted plainly for the rest; "tiles", the same coarse level, then small SIRENs over a grid of tiles
    (``tile_grid``³ cells, ``tile_width`` × ``tile_depth`` each, blended across seams of ``tile_margin`` cells)
    fitted as its residual inside its band (:mod:`neural_bake.fit.tiles`): capacity where the surface is; the
    file holds both levels (a :class:`~neural_bake.nets.tiles.TiledSdf`)."""
    coarse_width: int = 64
    """Hidden width of a residual construction's coarse level (part of ``width``)."""
    coarse_share: float = 0.25
    """Part of the budget a residual construction's coarse level is fitted for."""
    coarse_omega_0: float = 15.0
    """ω0 of a residual construction's coarse level (a smooth approximation, as a nested sequence's)."""
    band_factor: float = 4.0
    """A residual level's band δ in multiples of the coarse level's sampled distance error."""
    tile_grid: int = 6
    """The "tiles" construction: cells per axis of the tile grid over the mesh's bounding cube (at most 62: the
    grid has a ring of cells more around it, where the coarse level's stray surface gets tiles)."""
    tile_width: int = 64
    """The "tiles" construction: hidden units of each tile's SIREN."""
    tile_depth: int = 2
    """The "tiles" construction: hidden W×W matrices of each tile's SIREN."""
    tile_margin: float = 0.08
    """The "tiles" construction: half-width of the seams between tiles, in cells (0 < margin ≤ 0.25)."""
    device: str | None = None
    """torch device ("cpu", "cuda", …); None: CPU."""
    dtype: str = "float32"
    """"float32" or "float64"."""

    def fingerprint_dict(self) -> dict:
        """The settings that define the training trajectory (not budgets, paths or display)."""
        skip = {"steps", "minutes", "budget", "checkpoint", "checkpoint_every", "resume", "progress", "log_every", "compile",
                "micro_batches", "polish_evals", "polish_share", "polish_points", "polish_max_weight", "polish_max_p"}
        if self.construction == "plain":  # a plain fit's trajectory does not depend on the residual settings
            skip |= {"construction", "coarse_width", "coarse_share", "coarse_omega_0", "band_factor",
                     "audit_candidates"}
        if self.construction != "tiles":
            skip |= {"tile_grid", "tile_width", "tile_depth", "tile_margin"}
        if not self.texel_sampling:  # off: the trajectory of the settings before it
            skip.add("texel_sampling")
        if not self.edge_sampling:
            skip |= {"edge_sampling", "edge_band"}
        if not self.w_near_normal:
            skip |= {"w_near_normal", "near_normal_reach", "near_normal_gap_share"}
        elif not self.near_normal_gap_share:
            skip.add("near_normal_gap_share")
        return {k: v for k, v in asdict(self).items() if k not in skip}


#: The training settings of the multi-layer presets (how they were chosen: docs/findings.md).
_MULTI_LAYER = {"lr": 3e-4, "lr_min_factor": 0.01, "hard_pool": 0.05, "steps": 100_000}

#: What the 2- and 5-minute presets add for the shading a map shows: no hard-example mining (every sample
#: uniform, so the median normal is fitted everywhere), a stronger normal term, the angle term beside it,
#: the angle term at the near-surface samples (where a bake reads ∇f: off the surface, at the coarse mesh; their
#: targets only within a quarter of the gap to the next sheet) and ω0 = 45 (docs/findings.md).
_SHADING = {"hard_fraction": 0.0, "w_normal": 300.0, "w_angle": 300.0, "w_near_normal": 1000.0,
            "near_normal_gap_share": 0.25, "omega_0": 45.0}

#: What the 10-minute preset takes of them: no mining, the stronger normal term, the angle term and the near
#: one, at half the learning rate (at 3e-4 the (256, 4) network collapsed to a constant near step 1,900 with
#: the stronger normal term; docs/findings.md).
_SHADING_HIGH = {"hard_fraction": 0.0, "w_normal": 300.0, "w_angle": 300.0, "w_near_normal": 1000.0,
                 "near_normal_gap_share": 0.25, "lr": 1.5e-4}

#: Presets with their time budgets (minutes; the step cap is only a safety net): ``"quick"``, ``"default"``
#: and ``"high"`` (the best networks found for 2, 5 and 10 minutes: (192, 3), (192, 3) and (256, 4) Sirens,
#: fewer steps of larger networks) and the architecture presets ``"WxD"`` (the shared names: :mod:`.presets`).
#: ``quick`` is fitted as a residual construction (a 64-wide coarse level for a quarter of its time, then a
#: 128-wide fine level inside its band, saved as one 192x3 SIREN): more detail on scans at equal time; half of
#: its uniform batch comes from the network's sign errors where it has any (the coarse level left a stray
#: solid beyond nefertiti's crown and base that its band kept), and a band audit of a quarter of the others'
#: candidates (without it a stray piece of surface grew under nefertiti's base: Hausdorff 0.080 against 0.0048);
#: its near normal targets stay within a quarter of the gap on their side of the mesh (the tea set's thin walls:
#: ∇f 0.45° against 0.73°).
#: ``default`` and ``high`` are fitted by the same construction (``high``: 64x4 for a tenth of its time, then
#: 192x4: the fine level's extra minute and a half took the ogre's ∇f from 0.63° to 0.58°), with the band audit
#: between their levels (where the coarse level is small away from the mesh, the fine level grew a stray
#: bubble on the rocker arm without it); their near targets stay within a quarter of the gap as
#: ``quick``'s (the tea set's thin walls keep their zero set: Hausdorff 0.057 against 0.99 at ``default``, 0.15
#: against 0.47 at ``high``), and ``high`` draws a quarter of the pools not drawn by texels by curvature (every
#: mesh's ∇f p95 lower, the ogre's 5.1° → 4.5°; the medians within 0.02° but the cabinet's); ``default``'s
#: coarse level also spends a tenth of each near batch on its own zero set where it is furthest from the mesh
#: (plainly fitted, 5 minutes left stray pieces of surface on two of eight meshes without it).
#: The 64x1 preset weighs the eikonal term less and sets a quarter of its budget aside for an L-BFGS polish.
#: What each preset costs and reaches: BENCHMARKS.md; how its settings were chosen: docs/findings.md.
PRESETS: dict[str, dict] = {
    "quick": {"width": 192, "depth": 3, "minutes": 2.0, **_MULTI_LAYER, **_SHADING, "construction": "residual",
              "sign_fraction": 0.5, "audit_candidates": 25_000},
    "default": {"width": 192, "depth": 3, "minutes": 5.0, **_MULTI_LAYER, **_SHADING, "zero_fraction": 0.1,
                "construction": "residual", "sign_fraction": 0.5, "audit_candidates": 100_000},
    "high": {"width": 256, "depth": 4, "minutes": 10.0, **_MULTI_LAYER, **_SHADING_HIGH, "construction": "residual",
             "coarse_share": 0.1, "sign_fraction": 0.5, "audit_candidates": 100_000, "texel_sampling": 0.5,
             "curvature_sampling": 0.25},
    "64x1": {"width": 64, "depth": 1, "lr": 1e-3, "minutes": 2.0, "steps": 100_000, "w_eikonal": 10.0,
             "pool_surface": 100_000, "pool_near": 100_000, "pool_uniform": 25_000, "polish_evals": 400,
             "polish_share": 0.25},
    "128x2": {"width": 128, "depth": 2, "minutes": 5.0, **_MULTI_LAYER},
    "256x2": {"width": 256, "depth": 2, "minutes": 8.0, **_MULTI_LAYER},
    "256x3": {"width": 256, "depth": 3, "minutes": 10.0, **_MULTI_LAYER},
}


_NONE_IS_A_VALUE = ("minutes", "checkpoint", "device")


def config_from(config: SdfFitConfig | None = None, *, preset: str | None = None, **overrides) -> SdfFitConfig:
    """A config from a preset name and/or overrides; FitError for an unknown preset or field.

    An override of None is ignored (the preset's or config's value stays), except for ``minutes``,
    ``checkpoint`` and ``device`` where None is a value: ``preset="64x1", minutes=None`` removes the budget.
    A network set no wider than the construction's coarse level (e.g. ``preset="default", width=32``), with
    neither the construction nor the coarse width set, is fitted plainly: one network of that width.
    """
    cfg = config or SdfFitConfig()
    if preset is not None:
        from .presets import SDF_ALIASES, resolve_preset

        key = resolve_preset(preset, SDF_ALIASES, PRESETS)
        if key is None:
            aliases = "".join(f", {a} ({k})" for a, k in SDF_ALIASES.items())
            raise FitError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}{aliases}")
        cfg = replace(cfg, **PRESETS[key])
    names = {f.name for f in fields(SdfFitConfig)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise FitError(f"fit_sdf: unknown setting(s) {', '.join(unknown)}")
    # None leaves a setting as it is, except where None is a value of its own (no budget, no checkpoint)
    cfg = replace(cfg, **{k: v for k, v in overrides.items() if v is not None or k in _NONE_IS_A_VALUE})
    given = {k for k, v in overrides.items() if v is not None}
    if cfg.construction != "plain" and not given & {"construction", "coarse_width"} and cfg.coarse_width >= cfg.width:
        cfg = replace(cfg, construction="plain")
    if isinstance(cfg.sigmas, (int, float)):
        cfg = replace(cfg, sigmas=(float(cfg.sigmas),))
    cfg = replace(cfg, sigmas=tuple(float(s) for s in cfg.sigmas))
    _check_config(cfg)
    return cfg


def _check_config(cfg: SdfFitConfig) -> None:
    check_counts(cfg, "fit_sdf", ("width", "batch", "pool_surface"), least=1)
    check_counts(cfg, "fit_sdf", ("depth", "batch_near", "batch_uniform", "pool_near", "pool_uniform", "refresh_every",
                                  "audit_candidates"), least=0)
    if (cfg.batch_near and not cfg.pool_near) or (cfg.batch_uniform and not cfg.pool_uniform):
        raise FitError("fit_sdf: a non-empty batch needs a non-empty pool (pool_near / pool_uniform)")
    if not (math.isfinite(cfg.omega_0) and cfg.omega_0 > 0):
        raise FitError(f"fit_sdf: omega_0 must be positive, got {cfg.omega_0!r}")
    check_weights(cfg, "fit_sdf", ("w_surface", "w_normal", "w_angle", "w_near_normal", "w_eikonal", "w_sdf",
                                  "focus_tau"))
    check_sigmas(cfg, "fit_sdf")
    if not (math.isfinite(cfg.near_normal_reach) and cfg.near_normal_reach > 0):
        raise FitError(f"fit_sdf: near_normal_reach must be a positive distance, got {cfg.near_normal_reach!r}")
    if not (math.isfinite(cfg.near_normal_gap_share) and 0.0 <= cfg.near_normal_gap_share <= 1.0):
        raise FitError(f"fit_sdf: near_normal_gap_share must be in [0, 1], got {cfg.near_normal_gap_share!r}")
    if not (0.0 <= cfg.hard_fraction <= 1.0) or not (0.0 < cfg.hard_pool <= 1.0):
        raise FitError(f"fit_sdf: hard_fraction must be in [0, 1] and hard_pool in (0, 1], got "
                       f"{cfg.hard_fraction!r}, {cfg.hard_pool!r}")
    if not (0.0 <= cfg.zero_fraction <= 1.0 - cfg.hard_fraction):
        raise FitError(f"fit_sdf: zero_fraction must be in [0, 1 - hard_fraction], got {cfg.zero_fraction!r} "
                       f"(hard_fraction {cfg.hard_fraction!r})")
    if not (0.0 <= cfg.sign_fraction <= 1.0):
        raise FitError(f"fit_sdf: sign_fraction must be in [0, 1], got {cfg.sign_fraction!r}")
    if cfg.surface_normals not in ("face", "vertex"):
        raise FitError(f"fit_sdf: surface_normals must be 'face' or 'vertex', got {cfg.surface_normals!r}")
    if not (0.0 <= cfg.curvature_sampling <= 1.0):
        raise FitError(f"fit_sdf: curvature_sampling must be in [0, 1], got {cfg.curvature_sampling!r}")
    if not (0.0 <= cfg.texel_sampling <= 1.0):
        raise FitError(f"fit_sdf: texel_sampling must be in [0, 1], got {cfg.texel_sampling!r}")
    if not (0.0 <= cfg.edge_sampling <= 1.0):
        raise FitError(f"fit_sdf: edge_sampling must be in [0, 1], got {cfg.edge_sampling!r}")
    if not (math.isfinite(cfg.edge_band) and cfg.edge_band > 0):
        raise FitError(f"fit_sdf: edge_band must be positive, got {cfg.edge_band!r}")
    if not (0.0 <= cfg.error_sampling <= 1.0 - cfg.hard_fraction):
        raise FitError(f"fit_sdf: error_sampling must be in [0, 1 - hard_fraction], got {cfg.error_sampling!r} "
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
    if cfg.budget not in ("time", "steps"):
        raise FitError(f"fit_sdf: budget must be 'time' or 'steps', got {cfg.budget!r}")
    from .residual import CONSTRUCTIONS

    if cfg.construction not in CONSTRUCTIONS:
        raise FitError(f"fit_sdf: construction must be one of {', '.join(CONSTRUCTIONS)}, got {cfg.construction!r}")
    if cfg.construction != "plain":
        if int(cfg.coarse_width) != cfg.coarse_width or not 0 < cfg.coarse_width < cfg.width:
            raise FitError(f"fit_sdf: coarse_width must be an integer in (0, width {cfg.width}) for the "
                           f"{cfg.construction} construction, got {cfg.coarse_width!r} (set coarse_width below the "
                           "width, or construction 'plain' for one network)")
        if not (0.0 < cfg.coarse_share < 1.0):
            raise FitError(f"fit_sdf: coarse_share must be in (0, 1), got {cfg.coarse_share!r}")
        if not (math.isfinite(cfg.band_factor) and cfg.band_factor > 0):
            raise FitError(f"fit_sdf: band_factor must be positive, got {cfg.band_factor!r}")
        if not (math.isfinite(cfg.coarse_omega_0) and cfg.coarse_omega_0 > 0):
            raise FitError(f"fit_sdf: coarse_omega_0 must be positive, got {cfg.coarse_omega_0!r}")
    if cfg.construction == "tiles":
        for name in ("tile_grid", "tile_width"):
            v = getattr(cfg, name)
            if isinstance(v, bool) or int(v) != v or v < 1:
                raise FitError(f"fit_sdf: {name} must be a positive integer, got {v!r}")
        if cfg.tile_grid > MAX_TILE_GRID - 2:
            raise FitError(f"fit_sdf: tile_grid must be at most {MAX_TILE_GRID - 2} (the grid has a ring of cells "
                           f"more around the mesh's), got {cfg.tile_grid!r}")
        if isinstance(cfg.tile_depth, bool) or int(cfg.tile_depth) != cfg.tile_depth or cfg.tile_depth < 0:
            raise FitError(f"fit_sdf: tile_depth must be a non-negative integer, got {cfg.tile_depth!r}")
        if not (math.isfinite(cfg.tile_margin) and 0 < cfg.tile_margin <= 0.25):
            raise FitError(f"fit_sdf: tile_margin must be in (0, 0.25] cells, got {cfg.tile_margin!r}")
    if cfg.dtype not in _DTYPES:
        raise FitError(f"fit_sdf: dtype must be one of {', '.join(_DTYPES)}, got {cfg.dtype!r}")
