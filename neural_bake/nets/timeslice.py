"""A SIREN with its last input held fixed is a SIREN of one input fewer: f(·, τ) of a space-time field.

The first layer computes ``sin(ω0 (W [x; τ] + b)) = sin(ω0 (W_x x + (b + W_τ τ)))``, so fixing τ folds the
column W_τ into the bias and leaves every other layer as it is. The slice is an ordinary
:class:`~neural_bake.nets.siren.Siren` (``in_dim - 1`` inputs), so every tool made for static fields — GEMM
normals, range analysis, marching cubes, the renderer — works on f(·, τ) unchanged and at the same cost.
"""

from __future__ import annotations

import math

import torch

from ..errors import NeuralBakeError
from .siren import Siren

__all__ = ["fix_last_input"]


def fix_last_input(model: Siren, value: float) -> Siren:
    """The network ``x ↦ model([x, value])``: a new :class:`Siren` with ``in_dim - 1`` inputs (same width, depth,
    ω, dtype and device; its parameters are copies, not views, and carry no gradient).

    Args:
        model: a Siren with ``in_dim >= 2`` (a space-time SDF has in_dim 4: (x, y, z, τ)).
        value: the fixed last input (τ, in the network's own input units).

    Raises:
        NeuralBakeError: a model with fewer than two inputs, a non-finite value.
    """
    if model.in_dim < 2:
        raise NeuralBakeError(f"fix_last_input: the model has {model.in_dim} input; a slice needs at least 2")
    value = float(value)
    if not math.isfinite(value):
        raise NeuralBakeError(f"fix_last_input: value must be a finite number, got {value!r}")
    first = model.layers[0]
    out = Siren(model.width, model.depth, in_dim=model.in_dim - 1, out_dim=model.out_dim, omega_0=model.omega_0,
                hidden_omega=model.hidden_omega)
    out = out.to(device=first.weight.device, dtype=first.weight.dtype)
    with torch.no_grad():
        out.load_state_dict({k: v.detach().clone() for k, v in model.state_dict().items()
                             if not k.startswith("layers.0.")}, strict=False)
        out.layers[0].weight.copy_(first.weight[:, :-1])
        # in float64 then rounded once: the bias of the slice is b + W_τ τ
        bias = first.bias.double() + first.weight[:, -1].double() * value
        out.layers[0].bias.copy_(bias.to(first.bias.dtype))
    out.requires_grad_(False)
    return out.train(model.training)
