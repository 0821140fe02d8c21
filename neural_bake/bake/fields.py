"""What the baker evaluates: an SDF field (values and unit normals) and a colour field.

Both wrap either a trained :class:`~neural_bake.nets.siren.Siren` (``from_model``) or an analytic torch
callable (the samples' ground truth, tests). Points are (N, 3) tensors in the field's unit frame; outputs
follow the points' device and dtype.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import torch

from ..constants import GRAD_EPS
from ..errors import ModelFileError
from ..types import Frame

__all__ = ["SdfField", "ColorField", "load_field"]


class SdfField:
    """A signed distance field f with unit normals ∇f / |∇f|.

    - ``fn``: callable, points (N, 3) tensor -> values (N,) or (N, 1) tensor (differentiable in torch
      unless ``gradient`` is given).
    - ``gradient``: optional callable, points (N, 3) -> ∇f (N, 3); default: autograd of ``fn``.
    - ``frame``: the unit frame the field lives in (a model's frame; None = the mesh's).
    - ``delta``: the nesting band half-width δ of the field (|f| ≤ δ is where neural normal mapping is
      valid), or None when unknown.
    - ``name``: what reports call it.
    """

    def __init__(
        self,
        fn: Callable[[torch.Tensor], torch.Tensor],
        gradient: Callable[[torch.Tensor], torch.Tensor] | None = None,
        *,
        frame: Frame | None = None,
        delta: float | None = None,
        name: str = "analytic",
    ):
        self.fn, self.gradient, self.frame, self.delta, self.name = fn, gradient, frame, delta, name
        self.model = None

    @classmethod
    def from_model(
        cls, model, *, frame: Frame | None = None, delta: float | None = None, name: str = "siren"
    ) -> "SdfField":
        """A Siren with one output; normals by GEMM normals (closed form, no autograd)."""
        if getattr(model, "out_dim", 1) != 1:
            raise ModelFileError(f"{name}: an SDF model must have 1 output, this one has {model.out_dim}")
        field = cls(model, frame=frame, delta=delta, name=name)
        field.model = model
        return field

    def value_and_gradient(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """f (N,) and ∇f (N, 3) at ``points`` (N, 3); no autograd graph is kept."""
        if self.model is not None:
            from ..nets.gemm import gemm_gradient

            values, grads = gemm_gradient(self.model, points)
            return values.reshape(-1), grads.reshape(-1, 3)
        if self.gradient is not None:
            with torch.no_grad():
                return self.fn(points).reshape(-1), self.gradient(points).reshape(-1, 3)
        with torch.enable_grad():
            p = points.detach().requires_grad_(True)
            values = self.fn(p).reshape(-1)
            (grads,) = torch.autograd.grad(values.sum(), p)
        return values.detach(), grads.detach()

    def value_and_normal(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """f (N,), unit normals ∇f/|∇f| (N, 3) and ``valid`` (N,) bool (False where |∇f| ≤ GRAD_EPS or
        non-finite; those normals are zero, never NaN)."""
        values, grads = self.value_and_gradient(points)
        unit, valid = _normalized(grads)
        values = torch.nan_to_num(values, nan=float("inf"))
        return values, unit, valid


class ColorField:
    """A colour field g: points (N, 3) -> linear RGB (N, 3) (or RGBA (N, 4)).

    - ``fn``: callable on (N, 3) tensors (a Siren with 3 or 4 outputs, or analytic).
    - ``frame``: the unit frame the field lives in (None = the mesh's).
    - ``name``: what reports call it.
    - ``delta``: half-width of the band |f| <= δ the colours were fitted to be constant across (or None).
    """

    def __init__(self, fn: Callable[[torch.Tensor], torch.Tensor], *, frame: Frame | None = None, name: str = "analytic",
                 delta: float | None = None):
        self.fn, self.frame, self.name, self.delta = fn, frame, name, delta

    @classmethod
    def from_model(cls, model, *, frame: Frame | None = None, name: str = "siren",
                   delta: float | None = None) -> "ColorField":
        if getattr(model, "out_dim", 3) not in (3, 4):
            raise ModelFileError(f"{name}: a texture model must have 3 or 4 outputs, this one has {model.out_dim}")
        return cls(model, frame=frame, name=name, delta=delta)

    def color(self, points: torch.Tensor) -> torch.Tensor:
        """Linear RGB(A) (N, C) at ``points`` (N, 3); non-finite outputs become 0."""
        with torch.no_grad():
            out = self.fn(points)
        return torch.nan_to_num(out.reshape(points.shape[0], -1), nan=0.0, posinf=0.0, neginf=0.0)


def _normalized(grads: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    from ..nets.gemm import normalized_gradient

    unit, valid = normalized_gradient(grads, GRAD_EPS)
    unit = torch.nan_to_num(unit, nan=0.0, posinf=0.0, neginf=0.0)
    return unit, valid.reshape(-1).bool()


def load_field(path: str | Path, kind: str, *, argument: str = "--sdf"):
    """Load a model file as an :class:`SdfField` (``kind="sdf"``) or :class:`ColorField` (``"texture"``).

    Raises :class:`ModelFileError` naming ``argument`` and the file if it is missing or of the other kind.
    """
    from ..nets.model_io import load_model

    path = Path(path)
    if not path.exists():
        raise ModelFileError(f"{argument} {path}: no such model file")
    model, meta = load_model(path)
    got = meta.get("kind")
    if got != kind:
        raise ModelFileError(f"{argument} {path}: model of kind {got!r}, expected {kind!r}")
    frame = Frame.from_dict(meta["frame"]) if meta.get("frame") else None
    model.eval()
    delta = meta.get("delta")
    delta = None if delta is None else float(delta)
    if kind == "sdf":
        return SdfField.from_model(model, frame=frame, delta=delta, name=path.name)
    return ColorField.from_model(model, frame=frame, name=path.name, delta=delta)
