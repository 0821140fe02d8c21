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

from ..constants import (LOSS_GRAD_FLOOR, MIN_BUDGET_MINUTES, MIN_SURFACE_GRAD, MINED_ZERO_SET_TOL,
                         UNIT_FRAME_EXTENT)
from ..errors import FitError, ModelFileError, NeuralBakeWarning
from ..fields.spacetime import SPACETIME_KIND, SpaceTimeField, check_time_mapping, time_to_tau
from ..nets.gemm import gemm_gradient
from ..nets.siren import Siren
from ..nets.timeslice import fix_last_input
from ..types import Frame, Mesh
from .record import FitRecord
from .training import LoopSettings, train

__all__ = ["SpaceTimeFitConfig", "SpaceTimeFit", "fit_morph", "fit_sequence", "MORPH_METHODS", "SEQUENCE_METHODS",
           "reframe", "common_frame", "time_to_tau", "spacetime_metrics", "load_spacetime", "SPACETIME_KIND",
           "parse_times", "nest_spacetime", "nesting_by_time", "choose_deltas", "DELTA_POLICIES"]


_DTYPES = {"float32": torch.float32, "float64": torch.float64}

#: The morph methods of :func:`fit_morph` (see the module docstring).
MORPH_METHODS = ("lse", "interpolate")

#: The in-between methods of :func:`fit_sequence` (see the module docstring).
SEQUENCE_METHODS = ("interpolate", "eikonal")


@dataclass
class SpaceTimeFitConfig(LoopSettings):
    """Settings of :func:`fit_morph` and :func:`fit_sequence` (the loop's first:
    :class:`~neural_bake.fit.training.LoopSettings`)."""

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


def _config_from(config: SpaceTimeFitConfig | None, fn: str, methods=MORPH_METHODS,
                 **overrides) -> SpaceTimeFitConfig:
    cfg = config or SpaceTimeFitConfig()
    names = {f.name for f in fields(SpaceTimeFitConfig)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise FitError(f"{fn}: unknown setting(s) {', '.join(unknown)}")
    cfg = replace(cfg, **{k: v for k, v in overrides.items() if v is not None or k in ("minutes", "device")})
    cfg = replace(cfg, sigmas=tuple(float(s) for s in np.atleast_1d(cfg.sigmas)))
    for name in ("width", "batch", "pool_surface", "pool_near", "pool_uniform", "pool_between", "log_every"):
        v = getattr(cfg, name)
        if int(v) != v or v < 1:
            raise FitError(f"{fn}: {name} must be a positive integer, got {v!r}")
    for name in ("depth", "batch_near", "batch_uniform", "batch_between", "steps"):
        v = getattr(cfg, name)
        if int(v) != v or v < 0:
            raise FitError(f"{fn}: {name} must be a non-negative integer, got {v!r}")
    for name in ("omega_0", "time_extent", "lr"):
        v = getattr(cfg, name)
        if not (math.isfinite(v) and v > 0):
            raise FitError(f"{fn}: {name} must be a positive number, got {v!r}")
    for name in ("w_surface", "w_normal", "w_eikonal", "w_sdf", "w_lse", "w_interp"):
        v = getattr(cfg, name)
        if not (math.isfinite(v) and v >= 0):
            raise FitError(f"{fn}: {name} must be a non-negative number, got {v!r}")
    if not cfg.sigmas or not all(math.isfinite(s) and s > 0 for s in cfg.sigmas):
        raise FitError(f"{fn}: sigmas must be positive numbers, got {cfg.sigmas!r}")
    if cfg.method not in methods:
        raise FitError(f"{fn}: method must be one of {', '.join(methods)}, got {cfg.method!r}")
    if cfg.dtype not in _DTYPES:
        raise FitError(f"{fn}: dtype must be one of {', '.join(_DTYPES)}, got {cfg.dtype!r}")
    if cfg.minutes is not None and not (math.isfinite(cfg.minutes) and cfg.minutes > 0):
        raise FitError(f"{fn}: minutes must be a positive number or None, got {cfg.minutes!r}")
    return cfg


# ----------------------------------------------------------------------------------------------- time
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


# ----------------------------------------------------------------------------------------------- frames
def common_frame(shapes: Sequence) -> Frame:
    """The unit frame that holds every shape: meshes (their vertices, in their source frame) and fitted fields
    (the source box of their unit cube's [−0.9, 0.9]³, where a normalised shape lies)."""
    pts = []
    half = UNIT_FRAME_EXTENT / 2
    corners = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)])
    for s in shapes:
        if isinstance(s, Mesh):
            pts.append(s.frame.to_source(s.vertices))
        else:
            pts.append(_field_parts(s, "shape")[1].to_source(corners))
    return Frame.fit(np.concatenate(pts))


def reframe(mesh: Mesh, frame: Frame) -> Mesh:
    """``mesh`` with its vertices moved into ``frame`` (same source geometry; normals unchanged: frames only
    scale uniformly and shift)."""
    vertices = frame.to_unit(mesh.frame.to_source(mesh.vertices))
    return replace(mesh, vertices=vertices, frame=frame)


def _field_parts(s, name: str) -> tuple[Siren, Frame]:
    """(3-D Siren, frame) of a fitted SDF: an SdfFit / SdfField (``model``, ``frame``) or a nested sequence
    (its fine level)."""
    model = s.levels[-1] if hasattr(s, "levels") else getattr(s, "model", None)
    frame = getattr(s, "frame", None)
    if not isinstance(model, Siren) or not isinstance(frame, Frame):
        raise FitError(f"{name}: expected a Mesh or a fitted SDF (a network with its frame), got {type(s).__name__}")
    if model.in_dim != 3 or model.out_dim != 1:
        raise FitError(f"{name}: an SDF maps R^3 to R, this network maps R^{model.in_dim} to R^{model.out_dim}")
    return model, frame


# ----------------------------------------------------------------------------------------------- shapes
class _MeshShape:
    """A mesh in the common frame: samples and exact signed distances (:mod:`neural_bake.fit.sampling`)."""

    def __init__(self, mesh: Mesh, frame: Frame, name: str):
        if mesh.n_faces == 0 or mesh.n_vertices == 0:
            raise FitError(f"{name}: the mesh has no faces to fit")
        if not np.isfinite(mesh.vertices).all():
            raise FitError(f"{name}: the mesh has non-finite vertex coordinates")
        self.mesh, self.name = reframe(mesh, frame), name

    def surface(self, n: int, seed: int):
        from .sampling import sample_surface

        s = sample_surface(self.mesh, n, seed=seed)
        if len(s) == 0:
            raise FitError(f"{self.name}: no surface samples (every face is degenerate)")
        return s.points, s.normals

    def near(self, n: int, sigmas, seed: int):
        from .sampling import sample_near

        v = sample_near(self.mesh, n, sigma=list(sigmas), seed=seed)
        return v.points, v.sdf

    def uniform(self, n: int, seed: int):
        from .sampling import sample_uniform

        v = sample_uniform(self.mesh, n, seed=seed)
        return v.points, v.sdf

    def distance(self, x: np.ndarray) -> np.ndarray:
        from .sampling import signed_distance

        return signed_distance(self.mesh, x)


class _FieldShape:
    """A fitted SDF seen from the common frame: d(x) = g(x in g's frame) in common-frame units. Outside g's
    unit cube the value is g at the nearest point of the cube plus the distance to it (the network is not
    trained there). Surface samples: uniform points of g's cube nearest to g = 0, projected onto it by Newton
    steps (not area-uniform), normals ∇g / |∇g|."""

    def __init__(self, s, frame: Frame, name: str):
        self.model, self.own = _field_parts(s, name)
        self.frame, self.name = frame, name
        p = next(self.model.parameters())
        self.dtype, self.device = p.dtype, p.device

    def _own(self, x: np.ndarray) -> np.ndarray:
        return self.own.to_unit(self.frame.to_source(x))

    def _common(self, u: np.ndarray) -> np.ndarray:
        return self.frame.to_unit(self.own.to_source(u))

    def _values(self, u: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            t = torch.as_tensor(u, dtype=self.dtype, device=self.device)
            return self.model(t)[:, 0].double().cpu().numpy()

    def distance(self, x: np.ndarray) -> np.ndarray:
        u = self._own(np.asarray(x, dtype=np.float64))
        inside = np.clip(u, -1.0, 1.0)
        d = self._values(inside) + np.linalg.norm(u - inside, axis=1)
        return d * self.frame.scale / self.own.scale

    def surface(self, n: int, seed: int):
        from .metrics import project_to_zero_set

        rng = np.random.default_rng([seed, 11])
        got_p, got_n, have = [], [], 0
        for _ in range(8):
            cand = rng.uniform(-1.0, 1.0, size=(16 * n, 3))
            near = cand[np.argsort(np.abs(self._values(cand)))[: 2 * n]]
            x = project_to_zero_set(self.model, torch.as_tensor(near, dtype=self.dtype, device=self.device), 3)
            values, grads = gemm_gradient(self.model, x)
            gn = torch.linalg.vector_norm(grads, dim=1)
            ok = (values[:, 0].abs() < MINED_ZERO_SET_TOL) & (gn > MIN_SURFACE_GRAD) & (x.abs() <= 1.0).all(dim=1)
            got_p.append(x[ok].double().cpu().numpy())
            got_n.append((grads[ok] / gn[ok, None]).double().cpu().numpy())
            have += int(ok.sum())
            if have >= n:
                break
        if have == 0:
            raise FitError(f"{self.name}: the field has no zero level set in its unit cube")
        p, nn = np.concatenate(got_p)[:n], np.concatenate(got_n)[:n]
        return self._common(p).astype(np.float32), nn.astype(np.float32)

    def near(self, n: int, sigmas, seed: int):
        rng = np.random.default_rng([seed, 13])
        p, _ = self.surface(n, seed)
        sig = np.asarray(sigmas, dtype=np.float64)[rng.integers(0, len(sigmas), len(p))]
        x = p + rng.normal(size=p.shape) * sig[:, None]
        return x.astype(np.float32), self.distance(x).astype(np.float32)

    def uniform(self, n: int, seed: int):
        x = np.random.default_rng([seed, 17]).uniform(-1.0, 1.0, size=(n, 3))
        return x.astype(np.float32), self.distance(x).astype(np.float32)


def _shape(s, frame: Frame, name: str):
    return _MeshShape(s, frame, name) if isinstance(s, Mesh) else _FieldShape(s, frame, name)


# ----------------------------------------------------------------------------------------------- result
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


# ----------------------------------------------------------------------------------------------- losses
def spacetime_loss_terms(model: Siren, surf: torch.Tensor, surf_n: torch.Tensor, vol: torch.Tensor,
                         vol_d: torch.Tensor, between: torch.Tensor, between_d: torch.Tensor | None,
                         cfg: SpaceTimeFitConfig, *, mode: str, dtau_dt: float,
                         between_w: torch.Tensor | None = None) -> dict:
    """The loss terms of one step (scalar tensors) and their weighted sum ``"loss"``.

    Args:
        surf, surf_n: (S, 4) surface points (x, τ) at shape times and (S, 3) their unit outward normals.
        vol, vol_d: (V, 4) near/uniform points at shape times and (V,) their true signed distances.
        between: (B, 4) points at times in between.
        between_d: (B, 2) the distances (d_A, d_B) of the shapes before and after each between point (None
            with "eikonal").
        mode: "lse", "interpolate" or "eikonal" (eikonal only in between).
        dtau_dt: dτ/dt = 2E / (t1 − t0), the factor turning ∂f/∂τ into ∂f/∂t.
        between_w: (B,) the interpolation weight s of d_B at each between point (default: a morph's,
            s = (τ / E + 1) / 2).

    One differentiable GEMM pass gives f and its full gradient at all S + V + B points (no double-backward).
    """
    s, v = surf.shape[0], vol.shape[0]
    pts = torch.cat([surf, vol, between], dim=0)
    values, grads = gemm_gradient(model, pts, "reverse", differentiable=True)
    f = values[:, 0]
    gx = grads[:, :3]
    gnorm = torch.linalg.vector_norm(gx, dim=1)
    zero = f.new_zeros(())
    terms = {
        "surface": (f[:s] ** 2).mean() if s else zero,
        "normal": (1.0 - (gx[:s] * surf_n).sum(1) / gnorm[:s].clamp_min(LOSS_GRAD_FLOOR)).mean() if s else zero,
        "sdf": ((f[s:s + v] - vol_d) ** 2).mean() if v else zero,
        "eikonal": ((1.0 - gnorm) ** 2).mean(),
    }
    loss = (cfg.w_surface * terms["surface"] + cfg.w_normal * terms["normal"] + cfg.w_sdf * terms["sdf"]
            + cfg.w_eikonal * terms["eikonal"])
    b = between.shape[0]
    if b and mode == "lse":
        f_t = grads[s + v:, 3] * dtau_dt
        speed = between_d[:, 0] - between_d[:, 1]  # v = d_A − d_B per unit of t (t1 − t0 = 1 for a morph)
        terms["lse"] = ((f_t + speed * gnorm[s + v:]) ** 2).mean()
        loss = loss + cfg.w_lse * terms["lse"]
    elif b and mode == "interpolate":
        w = (between[:, 3] / cfg.time_extent + 1.0) * 0.5 if between_w is None else between_w
        target = (1.0 - w) * between_d[:, 0] + w * between_d[:, 1]
        terms["interp"] = ((f[s + v:] - target) ** 2).mean()
        loss = loss + cfg.w_interp * terms["interp"]
    terms["loss"] = loss
    return terms


# ----------------------------------------------------------------------------------------------- pools
def _tensor(a, dtype, device) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)


class _ShapePools:
    """Every shape's samples, concatenated with each sample's τ: surface (p, n, τ), volume (p, d, τ)."""

    def __init__(self, shapes, taus, cfg: SpaceTimeFitConfig, dtype, device, *, share: bool):
        k = len(shapes)
        per = (lambda n, low: max(n // k, min(n, low))) if share else (lambda n, low: n)
        sp, sn, st, vp, vd, vt = [], [], [], [], [], []
        for i, (shape, tau) in enumerate(zip(shapes, taus)):
            seed = int(cfg.seed) * 10_007 + 101 * i
            p, n = shape.surface(per(cfg.pool_surface, 4096), seed)
            sp.append(p), sn.append(n), st.append(np.full(len(p), tau))
            parts = []
            if cfg.batch_near:
                parts.append(shape.near(per(cfg.pool_near, 4096), cfg.sigmas, seed + 1))
            if cfg.batch_uniform:
                parts.append(shape.uniform(per(cfg.pool_uniform, 1024), seed + 2))
            for p, d in parts:
                ok = np.isfinite(d) & np.isfinite(p).all(axis=1)
                vp.append(p[ok]), vd.append(d[ok]), vt.append(np.full(int(ok.sum()), tau))
        t = lambda parts, shape: _tensor(np.concatenate(parts) if parts else np.zeros(shape), dtype, device)  # noqa: E731
        self.surf = torch.cat([t(sp, (0, 3)), t(st, (0,))[:, None]], dim=1)
        self.surf_n = t(sn, (0, 3))
        self.vol = torch.cat([t(vp, (0, 3)), t(vt, (0,))[:, None]], dim=1)
        self.vol_d = t(vd, (0,))

    def draw(self, cfg: SpaceTimeFitConfig, gen: torch.Generator):
        dev = self.surf.device
        si = torch.randint(0, self.surf.shape[0], (cfg.batch,), generator=gen).to(dev)
        nv = cfg.batch_near + cfg.batch_uniform
        vi = torch.randint(0, max(self.vol.shape[0], 1), (nv if self.vol.shape[0] else 0,), generator=gen).to(dev)
        take = torch.index_select
        return take(self.surf, 0, si), take(self.surf_n, 0, si), take(self.vol, 0, vi), take(self.vol_d, 0, vi)


def _between_pool(shapes, cfg: SpaceTimeFitConfig, dtype, device):
    """Morph: points near either end and uniform in the cube, with both ends' distances: (P, 3), (P, 2)."""
    rng_seed = int(cfg.seed) * 10_007 + 7_777
    n = int(cfg.pool_between)
    parts = [shapes[0].near(n // 3, cfg.sigmas, rng_seed)[0], shapes[1].near(n // 3, cfg.sigmas, rng_seed + 1)[0],
             np.random.default_rng([rng_seed, 3]).uniform(-1.0, 1.0, size=(n - 2 * (n // 3), 3))]
    x = np.concatenate(parts).astype(np.float64)
    d = np.stack([shapes[0].distance(x), shapes[1].distance(x)], axis=1)
    ok = np.isfinite(d).all(axis=1) & np.isfinite(x).all(axis=1)
    return _tensor(x[ok], dtype, device), _tensor(d[ok], dtype, device)


def _sequence_between_pool(shapes, taus, cfg: SpaceTimeFitConfig, dtype, device):
    """Sequence: points for the in-between terms, each in one time step [τ_k, τ_{k+1}] (steps drawn in
    proportion to their length, so τ ends up uniform): near frame k, near frame k + 1 and uniform in the cube,
    with the distances to both frames. Returns (P, 3) points, (P, 2) distances, (P, 2) the step's τ ends."""
    rng_seed = int(cfg.seed) * 10_007 + 7_777
    rng = np.random.default_rng([rng_seed, 5])
    lengths = np.diff(np.asarray(taus, dtype=np.float64))
    counts = rng.multinomial(int(cfg.pool_between), lengths / lengths.sum())
    xs, ds, ends = [], [], []
    for k, c in enumerate(counts):
        a, b = shapes[k], shapes[k + 1]
        third = int(c) // 3
        parts = [rng.uniform(-1.0, 1.0, size=(int(c) - 2 * third, 3))]
        if third:
            parts += [a.near(third, cfg.sigmas, rng_seed + 2 * k)[0], b.near(third, cfg.sigmas, rng_seed + 2 * k + 1)[0]]
        x = np.concatenate(parts).astype(np.float64)
        if len(x) == 0:
            continue
        xs.append(x)
        ds.append(np.stack([a.distance(x), b.distance(x)], axis=1))
        ends.append(np.tile([taus[k], taus[k + 1]], (len(x), 1)))
    x, d, e = np.concatenate(xs), np.concatenate(ds), np.concatenate(ends)
    ok = np.isfinite(d).all(axis=1) & np.isfinite(x).all(axis=1)
    return _tensor(x[ok], dtype, device), _tensor(d[ok], dtype, device), _tensor(e[ok], dtype, device)


# ----------------------------------------------------------------------------------------------- fitting
def _run(shapes, taus, kind: str, method: str, cfg: SpaceTimeFitConfig, frame: Frame, time_range, times, desc: str):
    device = torch.device(cfg.device or "cpu")
    dtype = _DTYPES[cfg.dtype]
    gen = torch.Generator().manual_seed(int(cfg.seed))
    model = Siren(cfg.width, cfg.depth, in_dim=4, omega_0=cfg.omega_0, generator=gen).to(device=device, dtype=dtype)
    model.train()
    t_start = time.perf_counter()
    pools = _ShapePools(shapes, taus, cfg, dtype, device, share=kind == "sequence")
    span = float(time_range[1] - time_range[0])
    dtau_dt = 2.0 * cfg.time_extent / span if span > 0 else 0.0
    single = span == 0.0
    between_p, between_d, between_ends = pools.vol[:, :3], None, None
    if cfg.batch_between and not single and method in ("lse", "interpolate"):
        if kind == "morph":
            between_p, between_d = _between_pool(shapes, cfg, dtype, device)
        else:
            between_p, between_d, between_ends = _sequence_between_pool(shapes, taus, cfg, dtype, device)
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
    cfg = _config_from(config, "fit_morph", **overrides)
    if align not in ("source", "unit"):
        raise FitError(f"fit_morph: align must be 'source' or 'unit', got {align!r}")
    if align == "unit":
        a, b = _unit_aligned(a), _unit_aligned(b)
    frame = common_frame([a, b]) if all(isinstance(s, Mesh) or hasattr(s, "frame") for s in (a, b)) else None
    if frame is None:
        raise FitError(f"fit_morph: expected two Meshes or fitted SDFs, got {type(a).__name__} and {type(b).__name__}")
    shapes = [_shape(a, frame, getattr(a, "name", "a")), _shape(b, frame, getattr(b, "name", "b"))]
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

    return _Aligned(_field_parts(s, "shape")[0])


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
    cfg = _config_from(config, "fit_sequence", SEQUENCE_METHODS, **overrides)
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
    shapes = [_MeshShape(m, frame, m.name if m.source else f"meshes[{i}]") for i, m in enumerate(meshes)]
    time_range = (float(ts[0]), float(ts[-1]))
    taus = time_to_tau(ts, time_range, cfg.time_extent)
    return _run(shapes, list(taus), "sequence", cfg.method, cfg, frame, time_range, ts.tolist(),
                f"fit sequence {cfg.width}x{cfg.depth}")


# ----------------------------------------------------------------------------------------------- metrics
def spacetime_metrics(fit: SpaceTimeFit, mesh: Mesh, t: float, **kwargs) -> dict:
    """:func:`~neural_bake.fit.metrics.sdf_metrics` of f(·, t) against ``mesh`` (any frame: it is moved into the
    fit's common frame). Distances in common-unit-frame units."""
    from .metrics import sdf_metrics

    return sdf_metrics(fit.at(t), reframe(mesh, fit.frame), **kwargs)


# ----------------------------------------------------------------------------------------------- nesting
#: How :func:`nest_spacetime` sets δ: from the certified bound (range analysis over space-time boxes, a
#: guarantee at every t) or from the sampled estimate (not guaranteed).
DELTA_POLICIES = ("certified", "estimated")


def nest_spacetime(fit: SpaceTimeFit, config=None, *, check_times: int = 11, delta: str = "certified",
                   **overrides):
    """Coarse space-time levels distilled from ``fit``'s network, with one δ per level that holds for every t
    of the fitted range: :func:`~neural_bake.fit.nested.fit_nested` with ``config`` (a
    :class:`~neural_bake.fit.nested.NestedFitConfig`; default: one (64, 1) level) and ``overrides`` (its
    fields) over [-1, 1]⁴ (space × the time input, which covers τ ∈ [−E, E] for E ≤ 1), sup-norms estimated
    over space-time samples and certified by range analysis over space-time boxes (``certify``, default on;
    ``max_boxes`` bounds its cost, recorded in ``levels_info[i]["certify"]["seconds"]``).

    The sampled sup of each level is also taken at ``check_times`` evenly spaced fixed times
    (:func:`nesting_by_time`, ``n_estimate`` samples each) and the estimated δ rebuilt from the larger value.
    Then δ is chosen by :func:`choose_deltas` with ``delta``: "certified" (default) makes δ_i − δ_{i+1} the
    certified bound wherever the certification ran, so the nesting [|h_{i+1}(·, t)| ≤ δ_{i+1}] ⊂
    [|h_i(·, t)| ≤ δ_i] is guaranteed at every t (a looser δ than the estimate: affine bounds over boxes are
    pessimistic); "estimated" keeps the sampled estimate (tighter, not guaranteed).

    Returns a :class:`~neural_bake.fit.nested.NestedSequence` of 4-input networks whose ``metadata`` holds
    ``"spacetime": {"time_range", "time_extent", "kind", "method", "times"}``.

    Raises:
        FitError: ``fit.time_extent`` above 1 (the nesting samples τ in [-1, 1] only), an unknown ``delta``,
            and fit_nested's errors.
    """
    import warnings

    from .nested import NestedFitConfig, fit_nested

    if fit.time_extent > 1.0:
        raise FitError(f"nest_spacetime: time_extent {fit.time_extent:g} > 1: the space-time band is sampled for "
                       f"τ in [-1, 1] only; fit with time_extent <= 1")
    if delta not in DELTA_POLICIES:
        raise FitError(f"nest_spacetime: delta must be one of {', '.join(DELTA_POLICIES)}, got {delta!r}")
    if delta == "certified":  # fit_nested's choice (certified only near the estimate) is replaced below
        overrides.setdefault("warn_ratio", math.inf)
    cfg = config or NestedFitConfig(levels="64x1")
    with warnings.catch_warnings():
        if delta == "certified":
            warnings.filterwarnings("ignore", message=r".*above the band .* where \|h - g\| was measured")
        seq = fit_nested(fit.model, cfg, frame=fit.frame, **overrides)
    n_estimate, seed = int(overrides.get("n_estimate", cfg.n_estimate)), int(overrides.get("seed", cfg.seed))
    seq.metadata["spacetime"] = {"time_range": list(fit.time_range), "time_extent": fit.time_extent,
                                 "kind": fit.kind, "method": fit.method, "times": list(fit.times)}
    # the space-time estimate samples [-1, 1]^4 uniformly: sharpen it at fixed times (the ends of the range
    # included, where uniform samples are sparse)
    rows = nesting_by_time(seq, np.linspace(*fit.time_range, check_times), n=n_estimate, seed=seed + 991)
    infos = seq.levels_info
    for r in rows:
        info = infos[r["level"]]
        info["sup_by_time"] = max(info.get("sup_by_time", 0.0), r["sup"])
    for info in infos[:-1]:
        info["sup_estimated"] = max(info["sup_estimated"], info.get("sup_by_time", 0.0))
    choose_deltas(seq, delta)
    if delta == "certified":
        for i, info in enumerate(infos[:-1]):
            if not info["nesting_guaranteed"]:
                why = ("certification was off" if info.get("sup_certified") is None else
                       f"the finer level's δ {infos[i + 1]['delta']:.4g} is above the band Δ = {seq.band:g}")
                warnings.warn(f"nest_spacetime: level {i}: δ is the sampled estimate, not guaranteed at every t "
                              f"({why})", NeuralBakeWarning, stacklevel=2)
    return seq


def choose_deltas(seq, delta: str = "certified"):
    """Set each level's ``delta``, ``delta_estimated``, ``delta_source`` and ``nesting_guaranteed`` from its
    stored sup-norms (in place; returns ``seq``), fine to coarse: δ_k = ε, δ_i = δ_{i+1} + sup_i.

    ``delta`` "certified": sup_i is the certified bound (``delta_source`` "certified",
    ``nesting_guaranteed`` True) wherever the certification ran and δ_{i+1} ≤ Δ (the certificate covers the
    band |·| < Δ only); elsewhere the sampled estimate (``delta_source`` "estimated", ``nesting_guaranteed``
    False: fresh samples may exceed it). "estimated": the estimate everywhere.

    Raises:
        FitError: an unknown ``delta``.
    """
    if delta not in DELTA_POLICIES:
        raise FitError(f"choose_deltas: delta must be one of {', '.join(DELTA_POLICIES)}, got {delta!r}")
    infos = seq.levels_info
    d_est = d_used = seq.eps
    infos[-1]["nesting_guaranteed"] = True  # the fine level itself: nothing to nest
    for i in range(len(infos) - 2, -1, -1):
        info = infos[i]
        d_est += info["sup_estimated"]
        info["delta_estimated"] = d_est
        cert = info.get("sup_certified")
        certified = (delta == "certified" and cert is not None and math.isfinite(cert) and d_used <= seq.band)
        d_used += cert if certified else info["sup_estimated"]
        info["delta"] = d_used
        info["delta_source"] = "certified" if certified else "estimated"
        info["nesting_guaranteed"] = bool(certified)
    return seq


@torch.no_grad()
def nesting_by_time(seq, times, *, n: int = 20_000, seed: int = 0) -> list[dict]:
    """Check a space-time nested sequence at each of ``times``: per coarse level i, the sampled sup of
    |h_i(·, t) − h_{i+1}(·, t)| over the Δ-band at t against the level's share δ_i − δ_{i+1} (Prop. 1 needs
    sup ≤ δ_i − δ_{i+1}). Rows ``{"t", "level", "sup", "allowed", "holds"}``."""
    from .nested import estimate_sup_norm

    st = seq.metadata.get("spacetime") or {}
    time_range = tuple(st.get("time_range", (0.0, 1.0)))
    extent = float(st.get("time_extent", 1.0))
    deltas = seq.deltas
    rows = []
    for t in times:
        tau = float(time_to_tau(float(t), time_range, extent))
        sl = [fix_last_input(m, tau) for m in seq.levels]
        for i in range(len(sl) - 1):
            sup = estimate_sup_norm(sl[i], sl[i + 1], band=seq.band, n=n, seed=seed + i)
            allowed = deltas[i] - deltas[i + 1]
            rows.append({"t": float(t), "level": i, "sup": sup, "allowed": allowed, "holds": bool(sup <= allowed)})
    return rows


# ----------------------------------------------------------------------------------------------- files
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
    from ..nets.model_io import load_model

    model, meta = load_model(path, device=device)
    return spacetime_from_header(model, meta, path)
