"""Settings of :func:`~neural_bake.fit.spacetime.fit_morph` and :func:`~neural_bake.fit.spacetime.fit_sequence`:
:class:`SpaceTimeFitConfig`, their checks (:func:`config_from`) and the time specs of the verbs
(:func:`parse_times`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from ..errors import FitError
from .config_checks import DTYPES as _DTYPES, check_counts, check_sigmas, check_weights
from .training import LoopSettings

__all__ = ["SpaceTimeFitConfig", "config_from", "parse_times", "MORPH_METHODS", "SEQUENCE_METHODS"]

#: The morph methods of :func:`~neural_bake.fit.spacetime.fit_morph` (see that module's docstring).
MORPH_METHODS = ("lse", "interpolate")

#: The in-between methods of :func:`~neural_bake.fit.spacetime.fit_sequence` (see that module's docstring).
SEQUENCE_METHODS = ("interpolate", "eikonal")


@dataclass
class SpaceTimeFitConfig(LoopSettings):
    """Settings of :func:`~neural_bake.fit.spacetime.fit_morph` and :func:`~neural_bake.fit.spacetime.fit_sequence`
    (the loop's first: :class:`~neural_bake.fit.training.LoopSettings`)."""

    steps: int = 3000  # the loop's settings with this fit's defaults
    lr: float = 2e-4
    width: int = 128
    """Hidden width W of the space-time Siren."""
    depth: int = 2
    """Number D of hidden W×W matrices (D + 1 hidden layers)."""
    omega_0: float = 30.0
    """ω0 of the first layer (hidden layers use 30); stored in the model file."""
    time_extent: float = 1.0
    """E: the fitted time range maps onto τ ∈ [−E, E] (a smaller E gives smoother motion in t)."""
    method: str = "interpolate"
    """What holds in between the given shapes. Morph: "interpolate" (supervised interpolation + eikonal;
    better quality per minute) or "lse" (level set equation). Sequence: "interpolate" (between the two
    neighbouring frames) or "eikonal" (the eikonal term alone)."""
    batch: int = 2048
    """Surface points per step, shared by the shapes (the morph's two ends, the frames)."""
    batch_near: int = 2048
    """Near-surface points (with true SDF) per step, shared by the shapes."""
    batch_uniform: int = 512
    """Uniform points in [-1, 1]³ (with true SDF) per step, shared by the shapes."""
    batch_between: int = 2048
    """Points at times in between per step (the LSE or interpolation term, and eikonal)."""
    w_surface: float = 3000.0
    """Weight of mean f² on surface samples."""
    w_normal: float = 100.0
    """Weight of mean (1 − cos(∇ₓf, n)) on surface samples."""
    w_eikonal: float = 50.0
    """Weight of mean (1 − |∇ₓf|)² on every point of the step."""
    w_sdf: float = 3000.0
    """Weight of mean (f − d)² on near and uniform samples at the shapes' times."""
    w_lse: float = 300.0
    """Morph "lse": weight of the mean squared LSE residual (∂f/∂t + v|∇ₓf|)² in between."""
    w_interp: float = 300.0
    """Morph "interpolate": weight of the mean (f − blend)² in between."""
    pool_surface: int = 50_000
    """Surface samples per shape (a sequence of K frames: this ÷ K per frame, at least 4,096)."""
    pool_near: int = 50_000
    """Near-surface samples per shape (a sequence: ÷ K, at least 4,096)."""
    pool_uniform: int = 12_500
    """Uniform samples per shape (a sequence: ÷ K, at least 1,024)."""
    pool_between: int = 50_000
    """Points (near either end of a morph or of a sequence's time step, and uniform) with the distances to
    both, for the in-between terms."""
    sigmas: tuple[float, ...] = (0.003, 0.01, 0.05)
    """Standard deviations (common unit frame) of the near-surface offsets, mixed in equal parts."""
    device: str | None = None
    """torch device ("cpu", "cuda", …); None: CPU."""
    dtype: str = "float32"
    """"float32" or "float64"."""


def config_from(config: SpaceTimeFitConfig | None = None, *, fn: str = "fit_morph",
                **overrides) -> SpaceTimeFitConfig:
    """``config`` (default :class:`SpaceTimeFitConfig`) with ``overrides`` (None leaves a field as it is, except
    ``minutes`` and ``device``), checked as ``fn`` ("fit_morph" or "fit_sequence", whose methods differ)
    takes it; FitError naming ``fn`` and the field otherwise."""
    methods = SEQUENCE_METHODS if fn == "fit_sequence" else MORPH_METHODS
    cfg = config or SpaceTimeFitConfig()
    names = {f.name for f in fields(SpaceTimeFitConfig)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise FitError(f"{fn}: unknown setting(s) {', '.join(unknown)}")
    cfg = replace(cfg, **{k: v for k, v in overrides.items() if v is not None or k in ("minutes", "device")})
    cfg = replace(cfg, sigmas=tuple(float(s) for s in np.atleast_1d(cfg.sigmas)))
    check_counts(cfg, fn, ("width", "batch", "pool_surface", "pool_near", "pool_uniform", "pool_between", "log_every"),
                 least=1)
    check_counts(cfg, fn, ("depth", "batch_near", "batch_uniform", "batch_between", "steps"), least=0)
    for name in ("omega_0", "time_extent", "lr"):
        v = getattr(cfg, name)
        if not (math.isfinite(v) and v > 0):
            raise FitError(f"{fn}: {name} must be a positive number, got {v!r}")
    check_weights(cfg, fn, ("w_surface", "w_normal", "w_eikonal", "w_sdf", "w_lse", "w_interp"))
    check_sigmas(cfg, fn)
    if cfg.method not in methods:
        raise FitError(f"{fn}: method must be one of {', '.join(methods)}, got {cfg.method!r}")
    if cfg.dtype not in _DTYPES:
        raise FitError(f"{fn}: dtype must be one of {', '.join(_DTYPES)}, got {cfg.dtype!r}")
    if cfg.minutes is not None and not (math.isfinite(cfg.minutes) and cfg.minutes > 0):
        raise FitError(f"{fn}: minutes must be a positive number or None, got {cfg.minutes!r}")
    return cfg


def parse_times(text: str, *, name: str = "times") -> list[float]:
    """Times from a spec: ``"a:b:n"`` (n evenly spaced times from a to b, both included; n = 1 gives a) or a
    comma-separated list ``"0,0.25,1"``. NeuralBakeError (one line naming ``name``) for anything else, for
    more than :data:`~neural_bake.constants.MAX_FRAMES` times (refused before they are made) and for times
    beyond ±:data:`~neural_bake.constants.MAX_TIME_MAGNITUDE`."""
    from ..constants import MAX_FRAMES, MAX_TIME_MAGNITUDE
    from ..errors import NeuralBakeError

    text = str(text).strip()
    try:
        if ":" in text:
            a, b, n = text.split(":")
            a, b, n = float(a), float(b), int(n)
            if n < 1:
                raise ValueError
            out = None
        else:
            out = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise NeuralBakeError(f"{name}: {text!r:.60} is not START:STOP:COUNT (e.g. 0:1:60) or a comma-separated "
                              f"list of times") from None
    if out is None:
        if n > MAX_FRAMES:
            raise NeuralBakeError(f"{name}: {text!r:.60} asks for {n} times, more than {MAX_FRAMES}")
        out = np.linspace(a, b, n).tolist() if n > 1 else [a]
    if len(out) > MAX_FRAMES:
        raise NeuralBakeError(f"{name}: {text!r:.60} gives {len(out)} times, more than {MAX_FRAMES}")
    if not out or not all(math.isfinite(v) for v in out):
        raise NeuralBakeError(f"{name}: {text!r:.60} gives no finite times")
    if any(abs(v) > MAX_TIME_MAGNITUDE for v in out):
        raise NeuralBakeError(f"{name}: {text!r:.60} has a time beyond ±{MAX_TIME_MAGNITUDE:g}")
    return [float(v) for v in out]
