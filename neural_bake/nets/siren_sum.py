"""Sums of SIRENs: one SIREN equal to a + b, and the values and GEMM gradients of a sum network by network.

Two SIRENs of the same depth, hidden ω and input/output sizes add up to one SIREN exactly: their hidden units
side by side (block-diagonal hidden matrices, width a.width + b.width), their output layers concatenated and
their output biases added. The first layer's ω0 of ``b`` is the sum's; ``a``'s first layer is rescaled by
ω0(a) / ω0(b), so every pre-activation is unchanged (up to rounding). The sum's gradient is the sum of the two
gradients, by GEMM normals per network (:func:`sum_gradient`) or of the merged network.
"""

from __future__ import annotations

from typing import cast

import torch
from torch import nn

from ..errors import NeuralBakeError
from .gemm import gemm_gradient
from .siren import Siren

__all__ = ["siren_sum", "sum_gradient"]


def siren_sum(a: Siren, b: Siren) -> Siren:
    """A Siren x ↦ a(x) + b(x) of width ``a.width + b.width`` (depth, hidden ω, in/out sizes of both; ω0 of
    ``b``), on ``b``'s device and dtype. NeuralBakeError when the two differ in depth, hidden ω or sizes."""
    for name in ("depth", "in_dim", "out_dim", "hidden_omega"):
        if getattr(a, name) != getattr(b, name):
            raise NeuralBakeError(f"siren_sum: the networks differ in {name} ({getattr(a, name)!r} and "
                                  f"{getattr(b, name)!r}); only SIRENs of the same {name} add up to one")
    p = next(b.parameters())
    out = Siren(a.width + b.width, b.depth, in_dim=b.in_dim, out_dim=b.out_dim, omega_0=b.omega_0,
                hidden_omega=b.hidden_omega).to(device=p.device, dtype=p.dtype)
    wa = a.width
    last = len(out.layers) - 1
    def linears(m: Siren) -> list[nn.Linear]:
        return [cast(nn.Linear, layer) for layer in m.layers]

    with torch.no_grad():
        for i, (la, lb, lo) in enumerate(zip(linears(a), linears(b), linears(out))):
            A, B, bias_a, bias_b = la.weight.to(p), lb.weight.to(p), la.bias.to(p), lb.bias.to(p)
            if i == 0:  # ω0 differs: a's first pre-activation ω0(a)·(W x + b) = ω0(b)·(s W x + s b)
                s = a.omega_0 / b.omega_0
                lo.weight.copy_(torch.cat([s * A, B]))
                lo.bias.copy_(torch.cat([s * bias_a, bias_b]))
            elif i == last:
                lo.weight.copy_(torch.cat([A, B], dim=1))
                lo.bias.copy_(bias_a + bias_b)
            else:
                lo.weight.zero_()
                lo.weight[:wa, :wa] = A
                lo.weight[wa:, wa:] = B
                lo.bias.copy_(torch.cat([bias_a, bias_b]))
    return out


def sum_gradient(models, points: torch.Tensor, **kwargs) -> tuple[torch.Tensor, torch.Tensor]:
    """Values (N, 1) and gradients (N, 3) of Σ ``models`` at ``points`` (N, 3): each network's by
    :func:`~neural_bake.nets.gemm.gemm_gradient` (``kwargs`` passed on), added. Dtype and device of ``points``."""
    models = list(models)
    if not models:
        raise NeuralBakeError("sum_gradient: no networks to add")
    values, grads = gemm_gradient(models[0], points, **kwargs)
    for m in models[1:]:
        v, g = gemm_gradient(m, points, **kwargs)
        values, grads = values + v, grads + g
    return values, grads
