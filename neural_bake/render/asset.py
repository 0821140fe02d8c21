"""What the renderer draws: a small protocol over SDF levels, an optional texture, and a space-time field.

The renderer knows no file format and no training code. A :class:`RenderAsset` is a list of
:class:`TraceLevel` (coarse to fine; the last one is the fine SDF f) in one unit frame, each with a value
evaluator, a value-and-gradient evaluator (GEMM normals for networks), its nesting threshold δ_j and,
where it can be bounded over boxes, a range bound (affine arithmetic for a SIREN, a Lipschitz bound for an
analytic SDF); plus an optional :class:`TextureSource` (linear RGB). A :class:`SpaceTimeAsset` gives a
RenderAsset per time t (f(x, t) with t fixed).

:func:`as_render_asset` adapts what the field layer hands out by duck typing (a nested sequence: ``levels``,
``deltas``, ``frame``; an SDF field: ``value_and_gradient``, ``model``, ``frame``, ``delta``; a plain
:class:`~neural_bake.nets.siren.Siren`), so render sits beside bake without importing it.

Points are (N, 3) tensors in the asset's unit frame; values (N,), gradients (N, 3); dtype and device follow
the points.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import torch

from ..errors import NeuralBakeError
from ..fields.texture import ENCODINGS, decode_colors
from ..nets.gemm import gemm_gradient
from ..nets.siren import Siren, siren_forward_inference
from ..types import Frame

__all__ = [
    "RenderError", "TraceLevel", "TextureSource", "RenderAsset", "SpaceTimeAsset", "as_render_asset",
    "siren_level", "tiled_level", "analytic_level", "siren_texture", "analytic_texture", "as_texture", "level_names",
]


class RenderError(NeuralBakeError):
    """A scene, asset or render setting that cannot produce an image (bad levels, δ, iterations, channels…)."""


Values = Callable[[torch.Tensor], torch.Tensor]
ValuesGrads = Callable[[torch.Tensor], "tuple[torch.Tensor, torch.Tensor]"]
Bound = Callable[[torch.Tensor, torch.Tensor], "tuple[torch.Tensor, torch.Tensor]"]


@dataclass
class TraceLevel:
    """One SDF of a nested sequence, as the tracer uses it (unit frame).

    - ``name``: what evaluation counters call this network (e.g. ``"h1 (64,1)"``).
    - ``value``: points (N, 3) → values (N,).
    - ``value_and_gradient``: points (N, 3) → (values (N,), gradients (N, 3)).
    - ``delta``: δ_j, half-width of the band [|h_j| ≤ δ_j] that holds the finer surfaces (0 for f).
    - ``bound``: optional ``(centers (B, 3), axes (B, s, 3)) → (lo (B,), hi (B,))`` guaranteed range over
      boxes (empty-space skipping and the guaranteed caster need it).
    - ``model``: the network when there is one (a SIREN or a tiled SDF; a fingerprint keys the skipping
      cache), else None.
    """

    name: str
    value: Values
    value_and_gradient: ValuesGrads
    delta: float = 0.0
    bound: Bound | None = None
    model: torch.nn.Module | None = None

    def __post_init__(self):
        d = float(self.delta)
        if not math.isfinite(d) or d < 0:
            raise RenderError(f"level {self.name}: δ must be a finite number ≥ 0, got {self.delta!r}")
        self.delta = d

    def fingerprint(self) -> str:
        """A digest of the network's weights (``id`` of the callables for analytic levels)."""
        if self.model is None:
            return f"analytic-{id(self.value)}"
        h = hashlib.sha1(repr(getattr(self.model, "architecture", None)).encode())
        for t in self.model.state_dict().values():
            h.update(t.detach().to("cpu", torch.float64).contiguous().numpy().tobytes())
        return h.hexdigest()


@dataclass
class TextureSource:
    """A colour field: points (N, 3), unit frame → linear RGB (N, 3). ``name`` for the counters; ``delta``: its
    band δ (None: unknown), how far the renderer moves a read onto f = 0 (normal mapping); ``normal_inputs``:
    ``color`` also reads the unit surface normals there, ``color(points, normals)`` (the renderer passes ∇f's)."""

    name: str
    color: Values
    model: Siren | None = None
    delta: float | None = None
    normal_inputs: bool = False


@dataclass
class RenderAsset:
    """Levels coarse → fine (the last is the fine SDF f) in one unit ``frame``, and an optional texture."""

    levels: list[TraceLevel]
    frame: Frame = field(default_factory=Frame)
    texture: TextureSource | None = None

    def __post_init__(self):
        if not self.levels:
            raise RenderError("asset: needs at least one SDF level")
        names = [lv.name for lv in self.levels]
        if len(set(names)) != len(names):
            raise RenderError(f"asset: level names must differ, got {names}")

    def with_texture(self, texture: TextureSource | None) -> "RenderAsset":
        return replace(self, texture=texture)


@dataclass
class SpaceTimeAsset:
    """A space-time field: ``at(t)`` gives the RenderAsset of f(·, t); ``time_range`` the valid [t0, t1]."""

    at: Callable[[float], RenderAsset]
    time_range: tuple[float, float] = (0.0, 1.0)

    def __post_init__(self):
        t0, t1 = (float(v) for v in self.time_range)
        if not (math.isfinite(t0) and math.isfinite(t1) and t0 <= t1):
            raise RenderError(f"space-time asset: time_range must be finite with t0 ≤ t1, got {self.time_range!r}")
        self.time_range = (t0, t1)


# ------------------------------------------------------------------------------------------- constructors
def _gemm_dtype(precision: str, model: Siren):
    """The hidden GEMMs' dtype for ``model`` at ``precision`` (the baker's and the renderer's one decision)."""
    from ..nets.precision import gemm_dtype, resolve_precision

    return gemm_dtype(resolve_precision(precision, model)[0])


def _arch_name(model) -> str:
    """"(W,D)" of a SIREN; a tiled SDF's label ("64x3+44x(64x2)")."""
    if getattr(model, "composite", False):
        return str(model.label)
    return f"({model.width},{model.depth})"


def _is_network(m) -> bool:
    """A SIREN or a tiled SDF (nets.tiles.TiledSdf: a level of several networks with their own bounds)."""
    return isinstance(m, Siren) or getattr(m, "composite", False)


def tiled_level(model, delta: float = 0.0, *, name: str | None = None) -> TraceLevel:
    """A level from a tiled SDF (:class:`~neural_bake.nets.tiles.TiledSdf`): its forward values, GEMM gradients
    and range bounds (float32 throughout: its networks have no reduced-precision path)."""
    def value_and_gradient(p):
        v, g = gemm_gradient(model, p)
        return v.reshape(-1), g

    return TraceLevel(name or _arch_name(model), lambda p: model.value(p).reshape(-1), value_and_gradient, delta,
                      lambda c, a: model.range_bound(c, a, "affine-fixed"), model)


class _SirenEval:
    """Value and GEMM value-and-gradient of a scalar SIREN, with ω-folded weights cached per dtype/device."""

    def __init__(self, model: Siren, time: float | None = None, gemm_dtype: torch.dtype | None = None):
        if int(model.out_dim) != 1:
            raise RenderError(f"SDF level: the network must have 1 output, this one has {model.out_dim}")
        want = 3 if time is None else 4
        if int(model.in_dim) != want:
            raise RenderError(f"SDF level: expected a network of {want} inputs "
                              f"({'x, y, z' if time is None else 'x, y, z, t'}), got {model.in_dim}")
        self.model, self.time, self.gemm_dtype = model, time, gemm_dtype
        self._layers: dict = {}

    def _inputs(self, points: torch.Tensor) -> torch.Tensor:
        if self.time is None:
            return points
        t = points.new_full((points.shape[0], 1), float(self.time))
        return torch.cat([points, t], dim=1)

    def value(self, points: torch.Tensor) -> torch.Tensor:
        key = (points.dtype, points.device)
        if key not in self._layers:
            with torch.no_grad():
                self._layers[key] = [(w.detach(), b.detach()) for w, b in
                                     self.model.affine_layers(dtype=points.dtype, device=points.device)]
        with torch.no_grad():
            return siren_forward_inference(self._layers[key], self._inputs(points),
                                           gemm_dtype=self.gemm_dtype).reshape(-1)

    def value_and_gradient(self, points: torch.Tensor):
        values, grads = gemm_gradient(self.model, self._inputs(points), gemm_dtype=self.gemm_dtype)
        return values.reshape(-1), grads[:, :3]

    def bound(self, centers: torch.Tensor, axes: torch.Tensor):
        from ..nets.range_analysis import range_bound

        if self.time is not None:  # time is fixed: a zero-width fourth coordinate
            centers = self._inputs(centers)
            axes = torch.cat([axes, axes.new_zeros(axes.shape[:-1] + (1,))], dim=-1)
        return range_bound(self.model, centers, axes, "affine-fixed")


def siren_level(model: Siren, delta: float = 0.0, *, name: str | None = None, time: float | None = None,
                precision: str = "fp32") -> TraceLevel:
    """A level from a scalar SIREN (3 inputs; 4 inputs (x, y, z, t) with ``time`` fixing t). ``precision``:
    "fp32", "bf16" or "auto" (:func:`neural_bake.nets.precision.resolve_precision`) for its hidden GEMMs."""
    ev = _SirenEval(model, time, _gemm_dtype(precision, model))
    return TraceLevel(name or _arch_name(model), ev.value, ev.value_and_gradient, delta, ev.bound, model)


def analytic_level(
    fn: Values, gradient: Values | None = None, delta: float = 0.0, *, name: str = "analytic",
    lipschitz: float | None = 1.0,
) -> TraceLevel:
    """A level from an analytic torch SDF ``fn`` (points (N, 3) → (N,)). ``gradient`` defaults to autograd of
    ``fn``. With ``lipschitz`` L (1 for a true SDF) boxes are bounded by ``f(c) ± L Σ_k |v_k|``; None: no
    bound (no skipping, no guaranteed casting)."""

    def value(p):
        with torch.no_grad():
            return fn(p).reshape(-1)

    def value_and_gradient(p):
        if gradient is not None:
            with torch.no_grad():
                return fn(p).reshape(-1), gradient(p).reshape(-1, 3)
        with torch.enable_grad():
            q = p.detach().requires_grad_(True)
            v = fn(q).reshape(-1)
            (g,) = torch.autograd.grad(v.sum(), q)
        return v.detach(), g.detach()

    bound = None if lipschitz is None else _lipschitz_bound(value, float(lipschitz))
    return TraceLevel(name, value, value_and_gradient, delta, bound, None)


def _lipschitz_bound(value: Values, lip: float) -> Bound:
    """``f(c) ± L Σ_k |v_k|`` over boxes: guaranteed for an L-Lipschitz f."""

    def bound(centers, axes):
        c = value(centers)
        r = lip * axes.norm(dim=-1).sum(dim=-1)
        return c - r, c + r

    return bound


def siren_texture(model: Siren, *, name: str | None = None, time: float | None = None,
                  precision: str = "fp32", delta: float | None = None, encoding: str = "linear") -> TextureSource:
    """A texture from a SIREN with 3 (RGB) or 4 (RGBA: alpha dropped) outputs; non-finite colours become 0.
    ``precision`` as :func:`siren_level`; ``encoding``: what the network outputs, "linear" or "srgb" (decoded
    to linear, :func:`~neural_bake.fields.texture.decode_colors`)."""
    if encoding not in ENCODINGS:
        raise RenderError(f"texture: colour encoding must be one of {', '.join(ENCODINGS)}, got {encoding!r}")
    low = _gemm_dtype(precision, model)
    if int(model.out_dim) not in (3, 4):
        raise RenderError(f"texture: the network must have 3 or 4 outputs, this one has {model.out_dim}")
    layers: dict = {}

    def color(points):
        key = (points.dtype, points.device)
        if key not in layers:
            with torch.no_grad():
                layers[key] = [(w.detach(), b.detach()) for w, b in
                               model.affine_layers(dtype=points.dtype, device=points.device)]
        x = points if time is None else torch.cat([points, points.new_full((len(points), 1), float(time))], 1)
        with torch.no_grad():
            out = siren_forward_inference(layers[key], x, gemm_dtype=low)[:, :3]
        return decode_colors(torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0), encoding)

    return TextureSource(name or f"texture {_arch_name(model)}", color, model, delta)


def analytic_texture(fn: Values, *, name: str = "texture", normal_inputs: bool = False) -> TextureSource:
    """A texture from a torch callable points (N, 3) → linear RGB (N, 3); with ``normal_inputs`` the callable
    is ``fn(points, normals)``."""

    def color(points, *normals):
        with torch.no_grad():
            out = fn(points, *normals).reshape(points.shape[0], -1)[:, :3]
        return torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)

    return TextureSource(name, color, None, normal_inputs=bool(normal_inputs))


# ------------------------------------------------------------------------------------------- adaptation
def level_names(models: Sequence[Siren]) -> list[str]:
    """Counter names of a sequence's networks: ``h1 (64,1)``, …, ``f (256,3)`` (the last is f)."""
    names = []
    for i, m in enumerate(models):
        base = _arch_name(m)
        names.append(f"f {base}" if i == len(models) - 1 else f"h{i + 1} {base}")
    return names


def as_render_asset(obj, *, deltas: Sequence[float] | None = None, texture=None, frame: Frame | None = None,
                    precision: str = "fp32") -> RenderAsset:
    """A RenderAsset from a nested sequence, an SDF field, a Siren, a list of Sirens or a RenderAsset.

    - nested sequence (``levels`` list of Sirens, the fine one possibly a tiled SDF, ``deltas``, ``frame``): one
      level per network, δ from
      ``deltas`` (argument) or the sequence's; the last level's δ is 0 (f is traced itself).
    - SDF field (``value_and_gradient``; ``model`` a Siren, a tiled SDF or None): one level.
    - ``texture``: a TextureSource, a Siren, or a texture field (``color(points)``); ``frame`` overrides.
    - ``precision``: "fp32", "bf16" or "auto" for the networks' hidden GEMMs (:func:`siren_level`).

    Raises RenderError for anything else, or a δ list of the wrong length.
    """
    if isinstance(obj, RenderAsset):
        asset = obj
    elif isinstance(obj, Siren) or (isinstance(obj, (list, tuple)) and obj and all(_is_network(m) for m in obj)):
        models = [obj] if isinstance(obj, Siren) else list(obj)
        asset = _from_models(models, deltas, frame or Frame(), precision)
    elif hasattr(obj, "levels") and isinstance(getattr(obj, "levels"), (list, tuple)):
        models = list(obj.levels)
        if not all(_is_network(m) for m in models):
            raise RenderError("asset: a nested sequence's levels must be Sirens (the fine one may be a tiled SDF)")
        ds = deltas if deltas is not None else list(getattr(obj, "deltas", [0.0] * len(models)))
        asset = _from_models(models, ds, frame or getattr(obj, "frame", None) or Frame(), precision)
    elif hasattr(obj, "value_and_gradient"):
        model = getattr(obj, "model", None)
        name = str(getattr(obj, "name", "f"))
        if isinstance(model, Siren):
            level = siren_level(model, 0.0, name=f"f {_arch_name(model)}", precision=precision)
        elif getattr(model, "composite", False):  # several networks (nets.tiles.TiledSdf): their own bounds
            level = tiled_level(model, 0.0, name=f"f {model.label}")
        else:
            level = TraceLevel(name, lambda p: obj.value_and_gradient(p)[0].reshape(-1),
                               lambda p: tuple(t for t in obj.value_and_gradient(p)), 0.0, None, None)
        asset = RenderAsset([level], frame or getattr(obj, "frame", None) or Frame())
    else:
        raise RenderError(f"asset: cannot render a {type(obj).__name__} (expected a nested sequence, an SDF "
                          "field or a Siren)")
    if texture is not None:
        asset = asset.with_texture(as_texture(texture, precision))
    return asset


def _from_models(models: list[Siren], deltas, frame: Frame, precision: str = "fp32") -> RenderAsset:
    deltas = [0.0] * len(models) if deltas is None else [float(d) for d in deltas]
    if len(deltas) != len(models):
        raise RenderError(f"asset: {len(models)} levels but {len(deltas)} δ values")
    deltas[-1] = 0.0  # the last level is f itself
    names = level_names(models)
    return RenderAsset([tiled_level(m, d, name=n) if getattr(m, "composite", False)
                        else siren_level(m, d, name=n, precision=precision) for m, d, n in zip(models, deltas, names)],
                       frame)


def as_texture(tex, precision: str = "fp32") -> TextureSource:
    """The :class:`TextureSource` of ``tex``: a SIREN (or a field holding one) through its GEMM forward pass,
    any other texture field (a feature grid, an analytic one) through its ``color``."""
    if isinstance(tex, TextureSource):
        return tex
    if isinstance(tex, Siren):
        return siren_texture(tex, precision=precision)
    model = getattr(tex, "model", None)
    delta = getattr(tex, "delta", None)
    if isinstance(model, Siren) and int(model.out_dim) in (3, 4):
        return siren_texture(model, precision=precision, delta=delta, encoding=getattr(tex, "encoding", "linear"))
    if hasattr(tex, "color"):
        return replace(analytic_texture(tex.color, name=str(getattr(tex, "name", "texture")),
                                        normal_inputs=bool(getattr(tex, "normal_inputs", False))), delta=delta)
    raise RenderError(f"texture: cannot use a {type(tex).__name__} (expected a texture field or a Siren)")
