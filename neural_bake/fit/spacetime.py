"""Space-time SDFs f(x, t): a morph between two shapes, or a fit of a sequence of meshes (paper Appendix A.2).

The network is a :class:`~neural_bake.nets.siren.Siren` with ``in_dim`` 4 over ``(x, y, z, τ)``: x in one unit
frame shared by every shape (the frame that holds all of them, so a shape that moves keeps its place), τ the
time mapped linearly from the fitted range [t0, t1] onto [−E, E] (E = ``time_extent``; τ = 0 when t0 = t1,
a single frame). f(·, t) is a static SDF: :meth:`SpaceTimeFit.at` returns it as an ordinary 3-D Siren
(:func:`~neural_bake.nets.timeslice.fix_last_input`), so marching cubes, GEMM normals, range analysis and the
renderer apply to it unchanged. A t outside [t0, t1] is refused (:class:`~neural_bake.errors.TimeRangeError`),
never extrapolated. :meth:`SpaceTimeFit.field` is the fit as a field-layer
:class:`~neural_bake.fields.spacetime.SpaceTimeField` (what files hold).

Losses. Every step evaluates the values and the full gradient (∂f/∂x, ∂f/∂τ) of all its points in ONE
differentiable GEMM pass (:func:`~neural_bake.nets.gemm.gemm_gradient`, the closed-form gradient with a
hand-written backward): one ordinary ``backward()``, no double-backward autograd, as in static fitting.

- At the times where a shape is given (the morph's ends t = 0 and t = 1; every frame of a sequence), the
  static losses (:mod:`neural_bake.fit.sdf`): ``f²`` and ``1 − cos(∇f, n)`` on surface samples, ``(f − d)²``
  on near-surface and uniform samples with their true signed distance d, and the eikonal ``(1 − |∇ₓf|)²``.
- In between (τ uniform in (−E, E)), on points near either shape and uniform in the cube:
  - morph, ``method="lse"``: the level set equation ∂f/∂t + v |∇ₓf| = 0 (Novello et al. 2023) with the
    normal speed v(x) = d_A(x) − d_B(x) (per unit of t): each level set moves along its normal by the
    difference of the two ends' distances over the morph, so for two concentric spheres f(·, t) is exactly
    the SDF of the sphere of the interpolated radius. The loss fixes how level sets move, not f's values
    (any increasing remapping of f solves it too): the end terms pin the values, the eikonal term keeps
    f(·, t) a distance;
  - morph, ``method="interpolate"``: supervised interpolation (f − ((1 − s) d_A + s d_B))², s = (t − t0) /
    (t1 − t0), regularised by the eikonal term (the blend of two SDFs is no SDF where their normals differ:
    the eikonal term trades exactness of the blend for a distance field);
  - sequence, ``method="interpolate"`` (default): the same supervised interpolation between the two frames
    around each time, s = (t − t_k) / (t_{k+1} − t_k), on points near either frame and uniform in the cube;
  - sequence, ``method="eikonal"``: the eikonal term only (the frames pin the shape at their times, the
    network alone decides what lies between them).

Both morph methods give the same path where the blend of the ends' distances is itself a distance (concentric
spheres). At equal steps the interpolation reaches the end shapes and a distance field (eikonal residual) in
between clearly better for a slightly higher cost per step, so it is the default; the LSE is kept for a motion
prescribed by the level set equation (BENCHMARKS.md, "bench dynamic", has the figures). Shapes far apart:
the linear blend's zero set is empty in the middle of the morph (every point is far from one of the ends), so
the shape shrinks away and grows back — a property of the distance blend, not a failure of the fit.

The settings are in :mod:`~neural_bake.fit.spacetime_config`, the shapes in :mod:`~neural_bake.fit.spacetime_shapes`,
the loss in :mod:`~neural_bake.fit.spacetime_loss`, the pools in :mod:`~neural_bake.fit.spacetime_pools` and the
nesting in :mod:`~neural_bake.fit.spacetime_nesting`; this module keeps the fit, its result and its files.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ..constants import MIN_BUDGET_MINUTES
from ..errors import FitError, ModelFileError
from ..fields.spacetime import SPACETIME_KIND, SpaceTimeField, check_time_mapping, time_to_tau
from ..nets.siren import Siren
from ..nets.timeslice import fix_last_input
from ..types import Frame, Mesh
from .record import FitRecord
from .config_checks import DTYPES as _DTYPES
from .spacetime_config import MORPH_METHODS, SEQUENCE_METHODS, SpaceTimeFitConfig, config_from, parse_times
from .spacetime_loss import spacetime_loss_terms
from .spacetime_nesting import DELTA_POLICIES, choose_deltas, nest_spacetime, nesting_by_time
from .spacetime_pools import ShapePools, between_pool, sequence_between_pool
from .spacetime_shapes import MeshShape, common_frame, field_parts, reframe, shape_of
from .training import train

__all__ = ["SpaceTimeFitConfig", "SpaceTimeFit", "fit_morph", "fit_sequence", "MORPH_METHODS", "SEQUENCE_METHODS",
           "reframe", "common_frame", "time_to_tau", "spacetime_metrics", "load_spacetime", "SPACETIME_KIND",
           "parse_times", "nest_spacetime", "nesting_by_time", "choose_deltas", "DELTA_POLICIES",
           "spacetime_loss_terms", "config_from"]


@dataclass
class SpaceTimeFit(FitRecord):
    """A fitted space-time SDF f(x, τ(t)) over the common unit frame and the time range
    (:class:`~neural_bake.fit.record.FitRecord`): ``model`` is the Siren f: (N, 4) points (x, y, z, τ) → (N, 1)
    signed distance (common unit frame, negative inside), ``frame`` the common frame of every shape of the fit."""

    config: SpaceTimeFitConfig = field(default_factory=SpaceTimeFitConfig)
    time_range: tuple[float, float] = (0.0, 1.0)
    """[t0, t1]: the times the fit covers (a morph: [0, 1]; a sequence: its first and last frame times)."""
    time_extent: float = 1.0
    """E: [t0, t1] maps onto τ ∈ [−E, E] (:func:`time_to_tau`)."""
    kind: str = "morph"
    """"morph" or "sequence"."""
    method: str = "lse"
    """Morph: "lse" or "interpolate"; sequence: "interpolate" or "eikonal" ("frames" in earlier files)."""
    times: list[float] = field(default_factory=list)
    """The times where shapes were given (the morph's 0 and 1; the sequence's frame times)."""

    def tau(self, t) -> np.ndarray:
        """τ of times ``t`` (TimeRangeError outside :attr:`time_range`)."""
        return time_to_tau(t, self.time_range, self.time_extent)

    def at(self, t: float) -> Siren:
        """f(·, t) as a 3-D :class:`Siren` in the common unit frame (TimeRangeError outside the range)."""
        return fix_last_input(self.model, float(self.tau(float(t))))

    def inputs(self, points: torch.Tensor, t: float) -> torch.Tensor:
        """(N, 4) network inputs of unit-frame ``points`` (N, 3) at time ``t`` (dtype/device of the points)."""
        tau = float(self.tau(float(t)))
        return torch.cat([points, points.new_full((points.shape[0], 1), tau)], dim=1)

    def header(self) -> dict:
        """The JSON metadata of the model file (kind, frame, time range, how it was fitted)."""
        return {"kind": SPACETIME_KIND, "frame": self.frame.to_dict(), "time_range": list(self.time_range),
                "time_extent": self.time_extent, "animation": {"kind": self.kind, "method": self.method,
                                                               "times": list(self.times)},
                "config": json.loads(json.dumps(asdict(self.config), default=str)),
                "training": self.training()}

    def field(self) -> SpaceTimeField:
        """The fit as a field-layer :class:`~neural_bake.fields.spacetime.SpaceTimeField` (metadata: the header)."""
        return SpaceTimeField(self.model, frame=self.frame, time_range=self.time_range, time_extent=self.time_extent,
                              name=f"{self.kind} {self.method}", metadata=self.header())

    def save(self, path) -> Path:
        """Write the model file (safetensors + JSON metadata, kind ``"spacetime_sdf"``) atomically;
        :func:`~neural_bake.fields.load_field` reads it as a SpaceTimeField, :func:`load_spacetime` as a fit."""
        return self.field().save(path)


def _run(shapes, taus, kind: str, method: str, cfg: SpaceTimeFitConfig, frame: Frame, time_range, times, desc: str):
    device = torch.device(cfg.device or "cpu")
    dtype = _DTYPES[cfg.dtype]
    gen = torch.Generator().manual_seed(int(cfg.seed))
    model = Siren(cfg.width, cfg.depth, in_dim=4, omega_0=cfg.omega_0, generator=gen).to(device=device, dtype=dtype)
    model.train()
    t_start = time.perf_counter()
    pools = ShapePools(shapes, taus, cfg, dtype, device, share=kind == "sequence")
    span = float(time_range[1] - time_range[0])
    dtau_dt = 2.0 * cfg.time_extent / span if span > 0 else 0.0
    single = span == 0.0
    between_p, between_d, between_ends = pools.vol[:, :3], None, None
    if cfg.batch_between and not single and method in ("lse", "interpolate"):
        if kind == "morph":
            between_p, between_d = between_pool(shapes, cfg, dtype, device)
        else:
            between_p, between_d, between_ends = sequence_between_pool(shapes, taus, cfg, dtype, device)
    if between_p.shape[0] == 0:
        between_p, between_d, between_ends = pools.surf[:, :3], None, None
    mode = method if between_d is not None else "eikonal"

    def step_fn(step: int, g: torch.Generator) -> dict:
        surf, surf_n, vol, vol_d = pools.draw(cfg, g)
        nb = 0 if single else int(cfg.batch_between)
        bi = torch.randint(0, between_p.shape[0], (nb,), generator=g).to(device)
        u = torch.rand(nb, generator=g, dtype=torch.float64)
        w = None
        if between_ends is None:
            tau = ((u * 2.0 - 1.0) * cfg.time_extent).to(device=device, dtype=dtype)
        else:  # a sequence: τ uniform in each point's time step, s its place in the step
            lo_hi = torch.index_select(between_ends, 0, bi)
            w = u.to(device=device, dtype=dtype)
            tau = lo_hi[:, 0] + w * (lo_hi[:, 1] - lo_hi[:, 0])
        between = torch.cat([torch.index_select(between_p, 0, bi), tau[:, None]], 1)
        bd = torch.index_select(between_d, 0, bi) if between_d is not None else None
        return spacetime_loss_terms(model, surf, surf_n, vol, vol_d, between, bd, cfg, mode=mode, dtau_dt=dtau_dt,
                                    between_w=w)

    loop = cfg.loop_config(desc, minutes=None if cfg.minutes is None else  # the pools' time counts
                           max(cfg.minutes - (time.perf_counter() - t_start) / 60.0, MIN_BUDGET_MINUTES))
    res = train(model, step_fn, loop)
    model.eval()
    return SpaceTimeFit(model=model, frame=frame, time_range=(float(time_range[0]), float(time_range[1])),
                        time_extent=float(cfg.time_extent), kind=kind, method=method, times=[float(t) for t in times],
                        history=res.history, steps=res.steps, seconds=time.perf_counter() - t_start, config=cfg,
                        stopped_reason=res.stopped_reason, restarts=res.restarts, threads=res.threads)


def fit_morph(a, b, config: SpaceTimeFitConfig | None = None, *, align: str = "source", **overrides) -> SpaceTimeFit:
    """Train a space-time Siren whose zero level set moves from shape ``a`` at t = 0 to shape ``b`` at t = 1.

    Args:
        a, b: each a :class:`~neural_bake.types.Mesh` (e.g. from ``load_mesh``; exact signed distances) or a
            fitted SDF — anything with a 3-D Siren ``model`` and its ``frame`` (``SdfFit``, ``SdfField``), or a
            nested sequence (its fine level). Both are placed in one common unit frame
            (:func:`common_frame`), so their relative position in the source frame is kept.
        config: the settings (default :class:`SpaceTimeFitConfig`); ``method`` chooses "lse" or
            "interpolate" (module docstring).
        align: "source" (default): the shapes keep their places in the source frame; "unit": each is first
            centred and scaled into its own unit frame (two unrelated models, e.g. Spot into the bunny), and
            the result's frame is the identity.
        **overrides: any :class:`SpaceTimeFitConfig` field, e.g. ``width=64, depth=1, steps=300``.

    Returns:
        A :class:`SpaceTimeFit` with ``time_range`` (0, 1), ``kind`` "morph".

    Raises:
        FitError: invalid settings, a shape that is neither a mesh nor a fitted SDF, a mesh without faces,
            divergence that learning-rate halvings did not cure.
    """
    cfg = config_from(config, fn="fit_morph", **overrides)
    if align not in ("source", "unit"):
        raise FitError(f"fit_morph: align must be 'source' or 'unit', got {align!r}")
    if align == "unit":
        a, b = _unit_aligned(a), _unit_aligned(b)
    frame = common_frame([a, b]) if all(isinstance(s, Mesh) or hasattr(s, "frame") for s in (a, b)) else None
    if frame is None:
        raise FitError(f"fit_morph: expected two Meshes or fitted SDFs, got {type(a).__name__} and {type(b).__name__}")
    shapes = [shape_of(a, frame, getattr(a, "name", "a")), shape_of(b, frame, getattr(b, "name", "b"))]
    e = cfg.time_extent
    return _run(shapes, [-e, e], "morph", cfg.method, cfg, frame, (0.0, 1.0), [0.0, 1.0],
                f"fit morph {cfg.method} {cfg.width}x{cfg.depth}")


def _unit_aligned(s):
    """A shape whose source frame is its own unit frame (centred, longest side 1.8)."""
    if isinstance(s, Mesh):
        return replace(s, frame=Frame())

    class _Aligned:  # a fitted SDF seen in its unit frame
        def __init__(self, model):
            self.model, self.frame = model, Frame()

    return _Aligned(field_parts(s, "shape")[0])


def fit_sequence(meshes: Sequence[Mesh], times: Sequence[float], config: SpaceTimeFitConfig | None = None,
                 **overrides) -> SpaceTimeFit:
    """Train a space-time Siren through mesh frames: f(·, t_k) is the SDF of ``meshes[k]``.

    The static losses hold at each frame time; in between, the interpolation of the two neighbouring frames'
    distances (``method="interpolate"``, default) or the eikonal term alone (``"eikonal"``). Frames need no vertex
    correspondence (any vertex counts, any topology); they are placed in one common unit frame. A single
    frame gives a field over the single time ``times[0]``.

    Args:
        meshes: K ≥ 1 :class:`~neural_bake.types.Mesh` frames.
        times: K strictly increasing finite times (any units).
        config, **overrides: as in :func:`fit_morph`; ``method`` is "interpolate" or "eikonal".

    Returns:
        A :class:`SpaceTimeFit` with ``time_range`` (times[0], times[-1]), ``kind`` "sequence".

    Raises:
        FitError: no frames, a frame that is not a Mesh or has no faces, times of another length, not
            finite or not strictly increasing, invalid settings, divergence.
    """
    cfg = config_from(config, fn="fit_sequence", **overrides)
    meshes = list(meshes)
    if not meshes:
        raise FitError("fit_sequence: meshes is empty (give at least one frame)")
    for i, m in enumerate(meshes):
        if not isinstance(m, Mesh):
            raise FitError(f"fit_sequence: meshes[{i}] is a {type(m).__name__}, expected a neural_bake Mesh")
    ts = np.asarray(times, dtype=np.float64).reshape(-1)
    if ts.shape[0] != len(meshes):
        raise FitError(f"fit_sequence: {len(meshes)} meshes but {ts.shape[0]} times")
    if not np.isfinite(ts).all():
        raise FitError(f"fit_sequence: times must be finite numbers, got {ts.tolist()}")
    if (np.diff(ts) <= 0).any():
        raise FitError(f"fit_sequence: times must be strictly increasing, got {ts.tolist()}")
    frame = common_frame(meshes)
    shapes = [MeshShape(m, frame, m.name if m.source else f"meshes[{i}]") for i, m in enumerate(meshes)]
    time_range = (float(ts[0]), float(ts[-1]))
    taus = time_to_tau(ts, time_range, cfg.time_extent)
    return _run(shapes, list(taus), "sequence", cfg.method, cfg, frame, time_range, ts.tolist(),
                f"fit sequence {cfg.width}x{cfg.depth}")


def spacetime_metrics(fit: SpaceTimeFit, mesh: Mesh, t: float, **kwargs) -> dict:
    """:func:`~neural_bake.fit.metrics.sdf_metrics` of f(·, t) against ``mesh`` (any frame: it is moved into the
    fit's common frame). Distances in common-unit-frame units."""
    from .metrics import sdf_metrics

    return sdf_metrics(fit.at(t), reframe(mesh, fit.frame), **kwargs)


def spacetime_from_header(model: Siren, meta: dict, path) -> SpaceTimeFit:
    """A :class:`SpaceTimeFit` of a loaded network and its file metadata; ModelFileError (one line naming
    ``path`` and the field) for anything that is not a valid space-time SDF header."""
    if meta.get("kind") != SPACETIME_KIND:
        raise ModelFileError(f"{path}: not a space-time SDF model file (kind {meta.get('kind')!r:.40})")
    if model.in_dim != 4 or model.out_dim != 1:
        raise ModelFileError(f"{path}: a space-time SDF maps R^4 to R, this network maps R^{model.in_dim} to "
                             f"R^{model.out_dim}")
    try:
        frame = Frame.from_dict(meta["frame"])
        if not (math.isfinite(frame.scale) and frame.scale > 0 and np.isfinite(frame.center).all()):
            raise ValueError
    except (KeyError, TypeError, ValueError):
        raise ModelFileError(f"{path}: space-time SDF model file without a valid frame") from None
    (t0, t1), extent = check_time_mapping(meta, path)
    anim = meta.get("animation") if isinstance(meta.get("animation"), dict) else {}
    try:
        training = FitRecord.training_fields(meta.get("training"))
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f"{path}: unreadable training record ({exc})") from None
    names = {f.name for f in fields(SpaceTimeFitConfig)}
    cfg = {k: v for k, v in (meta.get("config") or {}).items() if k in names}
    if "sigmas" in cfg:
        cfg["sigmas"] = tuple(cfg["sigmas"])
    try:
        config = SpaceTimeFitConfig(**cfg)
    except TypeError:
        config = SpaceTimeFitConfig()
    return SpaceTimeFit(model=model, frame=frame, time_range=(t0, t1), time_extent=float(extent),
                        kind=str(anim.get("kind", "morph")), method=str(anim.get("method", "")),
                        times=[float(t) for t in anim.get("times", [])], config=config, **training)


def load_spacetime(path, *, device=None) -> SpaceTimeFit:
    """Read a space-time SDF model file written by :meth:`SpaceTimeFit.save` (ModelFileError otherwise)."""
    from ..fields import load_model

    model, meta = load_model(path, device=device)
    return spacetime_from_header(model, meta, path)
