"""Space-time SDF fields f(x, t): one network of (x, y, z, τ) over a common unit frame and a time range.

τ, the network's time input, is the time t mapped linearly from the fitted range [t0, t1] onto [−E, E]
(E = ``time_extent``; τ = 0 when t0 = t1). A t outside [t0, t1] is refused with a one-line
:class:`~neural_bake.errors.TimeRangeError`, never extrapolated (times within
:data:`~neural_bake.constants.TIME_RANGE_TOL` of the range are clamped onto it). ``at(t)`` is the static
:class:`~neural_bake.fields.sdf.SdfField` of f(·, t): an ordinary 3-input Siren
(:func:`~neural_bake.nets.timeslice.fix_last_input`), so every static tool applies to it.

Files: the ``neural_bake.model`` container with ``kind`` ``"spacetime_sdf"``; the header stores ``frame``,
``time_range`` [t0, t1] and ``time_extent`` E (checked on load). A nested sequence of space-time levels is a
:class:`~neural_bake.fields.nested.NestedSequence` of 4-input networks with ``metadata["spacetime"]`` holding
the same time mapping (:func:`time_mapping` reads either).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..constants import MAX_TIME_MAGNITUDE, TIME_RANGE_TOL
from ..errors import ModelFileError, TimeRangeError
from ..types import Frame
from .files import register_kind
from .header import check_frame
from .sdf import SdfField

__all__ = ["SpaceTimeField", "SPACETIME_KIND", "time_to_tau", "check_time_mapping", "time_mapping"]

#: The ``kind`` of a space-time SDF model file.
SPACETIME_KIND = "spacetime_sdf"


def time_to_tau(t, time_range: tuple[float, float], extent: float, *, name: str = "t") -> np.ndarray:
    """The network's time input τ of times ``t`` (scalar or array): [t0, t1] ↦ [−extent, extent] linearly
    (τ = 0 when t0 = t1). Times within :data:`~neural_bake.constants.TIME_RANGE_TOL` of the range (relative
    to its length, absolute for a single time) are clamped onto it.

    Raises:
        TimeRangeError: a non-finite t or one outside [t0, t1] (one line naming ``name`` and the range).
    """
    t0, t1 = float(time_range[0]), float(time_range[1])
    ts = np.asarray(t, dtype=np.float64)
    tol = TIME_RANGE_TOL * max(t1 - t0, 1.0)
    bad = ~np.isfinite(ts) | (ts < t0 - tol) | (ts > t1 + tol)
    if bad.any():
        first = float(ts.reshape(-1)[np.argmax(bad.reshape(-1))])
        raise TimeRangeError(f"{name} = {first:g} is outside the fitted time range [{t0:g}, {t1:g}]")
    ts = np.clip(ts, t0, t1)
    if t1 == t0:
        return np.zeros_like(ts)
    return (2.0 * (ts - t0) / (t1 - t0) - 1.0) * float(extent)


def check_time_mapping(meta: dict, path) -> tuple[tuple[float, float], float]:
    """``(time_range, time_extent)`` of a header: finite, t0 ≤ t1, 0 < time_extent, every value within
    ±:data:`~neural_bake.constants.MAX_TIME_MAGNITUDE`; ModelFileError (one line naming ``path`` and the field)."""
    tr = meta.get("time_range")
    try:
        t0, t1 = (float(v) for v in tr)
        ok = math.isfinite(t0) and math.isfinite(t1) and t0 <= t1
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ModelFileError(f"{path}: time_range = {tr!r:.40} is not two finite times t0 <= t1")
    if max(abs(t0), abs(t1)) > MAX_TIME_MAGNITUDE:
        raise ModelFileError(f"{path}: time_range = {tr!r:.40} has an end beyond ±{MAX_TIME_MAGNITUDE:g}")
    extent = meta.get("time_extent")
    if not isinstance(extent, (int, float)) or isinstance(extent, bool) or not (math.isfinite(extent) and extent > 0):
        raise ModelFileError(f"{path}: time_extent = {extent!r:.40} is not a positive number")
    if extent > MAX_TIME_MAGNITUDE:
        raise ModelFileError(f"{path}: time_extent = {extent!r:.40} is larger than {MAX_TIME_MAGNITUDE:g} (the "
                             f"network's time input would not be a finite float32)")
    return (t0, t1), float(extent)


class SpaceTimeField:
    """A space-time SDF f(x, t): ``model`` (a Siren (N, 4) → (N, 1): x in ``frame``'s unit frame, then τ),
    ``time_range`` [t0, t1], ``time_extent`` E, ``delta`` (nesting band, or None), ``name``, ``metadata``."""

    def __init__(self, model, *, frame: Frame, time_range=(0.0, 1.0), time_extent: float = 1.0,
                 delta: float | None = None, name: str = "spacetime", metadata: dict | None = None):
        if int(model.in_dim) != 4 or int(model.out_dim) != 1:
            raise ModelFileError(f"{name}: a space-time SDF maps R^4 to R, this network maps R^{model.in_dim} to "
                                 f"R^{model.out_dim}")
        self.model, self.frame, self.delta, self.name = model, frame, delta, name
        self.time_range = (float(time_range[0]), float(time_range[1]))
        self.time_extent = float(time_extent)
        self.metadata = dict(metadata or {})

    def tau(self, t) -> np.ndarray:
        """τ of times ``t`` (TimeRangeError outside :attr:`time_range`)."""
        return time_to_tau(t, self.time_range, self.time_extent)

    def time_input(self, t: float) -> float:
        """The network's time input of one time ``t`` (what a renderer appends to the points)."""
        return float(self.tau(float(t)))

    def slice(self, t: float):
        """f(·, t) as a 3-input Siren."""
        from ..nets.timeslice import fix_last_input

        return fix_last_input(self.model, self.time_input(t))

    def at(self, t: float) -> SdfField:
        """f(·, t) as a static :class:`SdfField` (same frame and δ)."""
        return SdfField.from_model(self.slice(t), frame=self.frame, delta=self.delta, name=f"{self.name}@t={t:g}")

    def header(self) -> dict:
        meta = {k: v for k, v in self.metadata.items()
                if k not in ("kind", "frame", "time_range", "time_extent", "delta")}
        meta.update(kind=SPACETIME_KIND, frame=self.frame.to_dict(), time_range=list(self.time_range),
                    time_extent=self.time_extent, delta=self.delta)
        return meta

    def save(self, path) -> Path:
        """Write the model file atomically (kind ``"spacetime_sdf"``)."""
        from .files import save_model

        return save_model(self.model, path, **self.header())


def read_spacetime(path: Path, header: dict, *, device=None, dtype=None) -> SpaceTimeField:
    """The reader :func:`~neural_bake.fields.load_field` calls for kind ``"spacetime_sdf"``."""
    from ..nets.model_io import build_siren, expected_shapes, read_state
    from .header import check_delta

    arch, meta = header["architecture"], header["metadata"]
    if arch["in_dim"] != 4 or arch["out_dim"] != 1:
        raise ModelFileError(f"{path}: a space-time SDF maps R^4 to R, this network maps R^{arch['in_dim']} to "
                             f"R^{arch['out_dim']}")
    frame = check_frame(meta.get("frame"), path, required=True)
    time_range, extent = check_time_mapping(meta, path)
    delta = check_delta(meta.get("delta"), path)
    model = build_siren(arch, read_state(path, expected_shapes(arch)), path, device=device, dtype=dtype)
    return SpaceTimeField(model, frame=frame, time_range=time_range, time_extent=extent, delta=delta,
                          name=Path(path).name, metadata=meta)


def time_mapping(field):
    """``(time_range, time_input)`` of a space-time field (a :class:`SpaceTimeField`, or a nested sequence of
    4-input levels with ``metadata["spacetime"]``); None for a static field."""
    if isinstance(field, SpaceTimeField):
        return field.time_range, field.time_input
    st = (getattr(field, "metadata", None) or {}).get("spacetime")
    if isinstance(st, dict):
        time_range, extent = check_time_mapping(st, getattr(field, "name", "nested sequence"))
        return time_range, lambda t: float(time_to_tau(float(t), time_range, extent))
    return None


def _register() -> None:
    from ..nets.model_io import MODEL_FORMAT

    register_kind(SPACETIME_KIND, MODEL_FORMAT, read_spacetime, SpaceTimeField)


_register()
