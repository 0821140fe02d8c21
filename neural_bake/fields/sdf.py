"""An SDF field: signed distances f and unit normals ∇f / |∇f| of a fitted network or an analytic callable.

Points are (N, 3) tensors in the field's unit frame; outputs follow the points' device and dtype (a network
evaluates in its own dtype: callers convert at the boundary). Normals of a network come from GEMM normals
(closed form, no autograd); a zero or non-finite gradient gives a zero normal and ``valid = False``, never NaN.
"""

from __future__ import annotations

from typing import Any, Callable

import torch

from ..constants import GRAD_EPS
from ..errors import ModelFileError
from ..types import Frame

__all__ = ["SdfField", "unit_normals", "closest_surface_points"]


class SdfField:
    """A signed distance field f with unit normals ∇f / |∇f|.

    - ``fn``: callable, points (N, 3) tensor -> values (N,) or (N, 1) tensor (differentiable in torch
      unless ``gradient`` is given).
    - ``gradient``: optional callable, points (N, 3) -> ∇f (N, 3); default: autograd of ``fn``.
    - ``frame``: the unit frame the field lives in (a model's frame; None = the mesh's).
    - ``delta``: the band half-width δ of the field (|f| ≤ δ is where neural normal and texture mapping
      hold: a nested sequence's band, or a fitted SDF's sampled distance error to its mesh), or None.
    - ``name``: what messages and reports call it (the file name for a loaded field).
    - ``metadata``: provenance, the file's JSON metadata (kind, training config, how δ was obtained…).
    - ``model``: the :class:`~neural_bake.nets.siren.Siren` of a fitted field (or the
      :class:`~neural_bake.nets.tiles.TiledSdf` of a tiled one), None for an analytic one.
    - ``gemm_dtype``: None, or the reduced precision of the network's hidden GEMMs (:meth:`with_precision`).
    """

    def __init__(
        self,
        fn: Callable[[torch.Tensor], torch.Tensor],
        gradient: Callable[[torch.Tensor], torch.Tensor] | None = None,
        *,
        frame: Frame | None = None,
        delta: float | None = None,
        name: str = "analytic",
        metadata: dict | None = None,
    ):
        self.fn, self.gradient, self.frame, self.delta, self.name = fn, gradient, frame, delta, name
        self.metadata = dict(metadata or {})
        self.model: Any = None
        self._pair: Callable | None = None
        self.gemm_dtype: torch.dtype | None = None

    @classmethod
    def from_model(
        cls, model, *, frame: Frame | None = None, delta: float | None = None, name: str = "siren",
        metadata: dict | None = None,
    ) -> "SdfField":
        """A Siren with one output; normals by GEMM normals (closed form, no autograd)."""
        if getattr(model, "out_dim", 1) != 1:
            raise ModelFileError(f"{name}: an SDF model must have 1 output, this one has {model.out_dim}")
        field = cls(model, frame=frame, delta=delta, name=name, metadata=metadata)
        field.model = model
        return field

    @classmethod
    def from_value_and_gradient(
        cls, fn: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]], *, frame: Frame | None = None,
        delta: float | None = None, name: str = "analytic",
    ) -> "SdfField":
        """A field from one callable ``points (N, 3) -> (values (N,), gradients (N, 3))`` (analytic SDFs)."""
        field = cls(lambda p: fn(p)[0], frame=frame, delta=delta, name=name)
        field._pair = fn
        return field

    def with_precision(self, precision: str, *, measure=None, probe: torch.Tensor | None = None
                       ) -> tuple["SdfField", str, str]:
        """``(field, resolved, reason)``: this field evaluating its hidden GEMMs at ``precision`` ("fp32",
        "bf16", "auto"; :func:`~neural_bake.nets.precision.resolve_precision`, ``measure`` passed on) — a
        shallow copy sharing the network, or this field itself when the result is fp32.

        With ``probe`` (P, 3) points, "auto" also compares the normals there with float32 ones and keeps
        float32 when their median angle exceeds :data:`~neural_bake.constants.BF16_MAX_MEDIAN_DEG`."""
        from ..constants import BF16_MAX_MEDIAN_DEG
        from ..nets.precision import reduced_copy

        out, resolved, reason = reduced_copy(self, precision, measure=measure)
        if out is self:
            return self, resolved, reason
        if precision == "auto" and probe is not None and len(probe):
            ref, fast = self.value_and_normal(probe)[1], out.value_and_normal(probe)[1]
            cos = (ref * fast).sum(dim=1).clamp(-1.0, 1.0).double()
            median = float(torch.rad2deg(torch.acos(cos)).median())
            if median > BF16_MAX_MEDIAN_DEG:
                return self, "fp32", (f"{reason}, but its normals measured {median:.3f}° median off float32 at "
                                      f"{len(probe)} points (> {BF16_MAX_MEDIAN_DEG}°)")
            reason += f"; normals {median:.3f}° median off float32 at {len(probe)} points"
        return out, resolved, reason

    @property
    def in_dim(self) -> int:
        """Input dimension: 3 (space); a space-time field has 4."""
        return int(getattr(self.model, "in_dim", 3))

    def value_and_gradient(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """f (N,) and ∇f (N, 3) at ``points`` (N, 3); no autograd graph is kept."""
        if self.model is not None:
            from ..nets.gemm import gemm_gradient

            values, grads = gemm_gradient(self.model, points, gemm_dtype=self.gemm_dtype)
            return values.reshape(-1), grads.reshape(-1, points.shape[-1])
        if self._pair is not None:
            with torch.no_grad():
                values, grads = self._pair(points)
            return values.reshape(-1), grads.reshape(-1, points.shape[-1])
        if self.gradient is not None:
            with torch.no_grad():
                return self.fn(points).reshape(-1), self.gradient(points).reshape(-1, points.shape[-1])
        with torch.enable_grad():
            p = points.detach().requires_grad_(True)
            values = self.fn(p).reshape(-1)
            (grads,) = torch.autograd.grad(values.sum(), p)
        return values.detach(), grads.detach()

    def value(self, points: torch.Tensor) -> torch.Tensor:
        """f (N,) at ``points`` (N, 3) without the gradient (a network's forward pass alone, its hidden GEMMs
        at ``gemm_dtype``); a NaN value becomes +inf, as in :meth:`value_and_normal`."""
        with torch.no_grad():
            if getattr(self.model, "composite", False):  # several networks (nets.tiles.TiledSdf)
                values = self.model.value(points, gemm_dtype=self.gemm_dtype)
            elif self.model is not None:
                from ..nets.siren import siren_forward_inference

                layers = self.model.affine_layers(dtype=points.dtype, device=points.device)
                values = siren_forward_inference(layers, points, gemm_dtype=self.gemm_dtype)
            elif self._pair is not None:
                values = self._pair(points)[0]
            else:
                values = self.fn(points)
        return torch.nan_to_num(values.reshape(-1), nan=float("inf"))

    def value_and_normal(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """f (N,), unit normals ∇f/|∇f| (N, 3) and ``valid`` (N,) bool (False where |∇f| < GRAD_EPS or
        non-finite; those normals are zero, never NaN). A NaN value becomes +inf (outside every band)."""
        values, grads = self.value_and_gradient(points)
        unit, valid = unit_normals(grads)
        values = torch.nan_to_num(values, nan=float("inf"))
        return values, unit, valid

    def __repr__(self) -> str:
        arch = "analytic" if self.model is None else getattr(self.model, "label", None) or \
            f"{self.model.width}x{self.model.depth}"
        return f"SdfField({self.name!r}, {arch}, delta={self.delta})"


def closest_surface_points(points: torch.Tensor, values: torch.Tensor, normals: torch.Tensor, valid: torch.Tensor,
                           reach: float | None = None) -> torch.Tensor:
    """The closest points q = p − f(p)·n(p) of an SDF's zero set (§3 of the nested-neighbourhoods paper: the
    point whose attributes a neighbourhood point carries), in the points' frame and dtype: ``values`` (N,) f,
    ``normals`` (N, 3) unit ∇f, ``valid`` (N,) bool; |f| clamped to ``reach`` (a colour field's band δ; None:
    no clamp); points without a valid gradient stay where they are."""
    step = torch.where(valid.reshape(-1), values.reshape(-1).to(points.dtype), torch.zeros((), dtype=points.dtype,
                                                                                           device=points.device))
    if reach is not None:
        step = step.clamp(-reach, reach)
    return points - step[:, None] * normals.to(points.dtype)


def unit_normals(grads: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit vectors (N, d) along ``grads`` (N, d) and ``valid`` (N,) bool (|∇f| ≥ GRAD_EPS and finite);
    invalid rows are zero."""
    from ..nets.gemm import normalized_gradient

    unit, valid = normalized_gradient(grads, GRAD_EPS)
    unit = torch.nan_to_num(unit, nan=0.0, posinf=0.0, neginf=0.0)
    return unit, valid.reshape(-1).bool()
