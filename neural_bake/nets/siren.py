"""SIREN: the sine MLP of Sitzmann et al. (2020), in the papers' (W, D) notation."""

from __future__ import annotations

import math

import torch
from torch import nn

from ..constants import DEFAULT_OMEGA_0
from ..errors import NeuralBakeError
from .blocks import hidden_blocks, split_layers
from .cpu_gemm import gemm_route
from .fastmath import sin_

__all__ = ["Siren", "siren_forward_inference", "forward_chunk_size", "FORWARD_CHUNK_ELEMENTS"]

#: Size (points × width) of a chunk of the inference forward pass: 2^18, i.e. 1,024 points of a width-256
#: network (a 1 MB float32 buffer, a typical core's L2 cache) and 4,096 of a width-64 one. Chosen by the
#: chunk sweep of `neural-bake bench normals` (docs/findings.md); much smaller chunks lose to per-call thread
#: synchronisation.
FORWARD_CHUNK_ELEMENTS = 1 << 18


def forward_chunk_size(width: int) -> int:
    """Points per chunk of :func:`siren_forward_inference` by default: :data:`FORWARD_CHUNK_ELEMENTS` ÷ width,
    at least 256."""
    return max(256, FORWARD_CHUNK_ELEMENTS // int(width))


class Siren(nn.Module):
    """A sine MLP ``R^in_dim -> R^out_dim``.

    ``depth`` hidden ``width``×``width`` matrices, i.e. ``depth + 1`` hidden layers of ``width``:
    (64, 1) has two hidden layers of 64, (256, 3) has four of 256. Layer i computes
    ``sin(ω_i (W_i x + b_i))`` with ω_0 = ``omega_0`` on the first layer and ``hidden_omega`` after it;
    the output layer is linear. Initialisation as Sitzmann et al.: first layer U(-1/in, 1/in), later layers
    U(-√(6/n)/ω, √(6/n)/ω), so every pre-activation is about unit-variance.

    Works on any device and dtype (``.to(...)``); inputs are (N, in_dim) tensors, outputs (N, out_dim).
    :meth:`affine_layers` gives the weights with ω folded in — the form GEMM normals and range analysis use,
    where every hidden layer is plain ``sin(W x + b)``.
    """

    def __init__(
        self,
        width: int = 256,
        depth: int = 3,
        in_dim: int = 3,
        out_dim: int = 1,
        omega_0: float = DEFAULT_OMEGA_0,
        hidden_omega: float = DEFAULT_OMEGA_0,
        *,
        generator: torch.Generator | None = None,
    ):
        super().__init__()
        for name, v in (("width", width), ("in_dim", in_dim), ("out_dim", out_dim)):
            if int(v) != v or v < 1:
                raise NeuralBakeError(f"Siren: {name} must be a positive integer, got {v!r}")
        if int(depth) != depth or depth < 0:
            raise NeuralBakeError(f"Siren: depth must be a non-negative integer, got {depth!r}")
        if not (math.isfinite(omega_0) and omega_0 > 0 and math.isfinite(hidden_omega) and hidden_omega > 0):
            raise NeuralBakeError(f"Siren: omega_0 and hidden_omega must be positive, got {omega_0!r}, {hidden_omega!r}")
        self.width, self.depth = int(width), int(depth)
        self.in_dim, self.out_dim = int(in_dim), int(out_dim)
        self.omega_0, self.hidden_omega = float(omega_0), float(hidden_omega)
        dims = [self.in_dim] + [self.width] * (self.depth + 1) + [self.out_dim]
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))
        self.reset_parameters(generator)

    @property
    def omegas(self) -> list[float]:
        """ω of each layer (1.0 for the linear output layer)."""
        return [self.omega_0] + [self.hidden_omega] * self.depth + [1.0]

    @property
    def architecture(self) -> dict:
        """The constructor arguments: what a model file stores to rebuild this network."""
        return {
            "width": self.width,
            "depth": self.depth,
            "in_dim": self.in_dim,
            "out_dim": self.out_dim,
            "omega_0": self.omega_0,
            "hidden_omega": self.hidden_omega,
        }

    @torch.no_grad()
    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """Sitzmann et al.'s initialisation (reproducible with ``generator``)."""
        for i, layer in enumerate(self.layers):
            fan_in = layer.in_features
            if i == 0:
                bound_w = 1.0 / fan_in
            else:
                bound_w = math.sqrt(6.0 / fan_in) / self.omegas[i - 1 if i == len(self.layers) - 1 else i]
            layer.weight.uniform_(-bound_w, bound_w, generator=generator)
            layer.bias.uniform_(-1.0 / math.sqrt(fan_in), 1.0 / math.sqrt(fan_in), generator=generator)

    def affine_layers(
        self, *, dtype: torch.dtype | None = None, device: torch.device | str | None = None
    ) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """[(W_i, b_i)] with ω folded in: hidden layer i is ``sin(x @ W_i.T + b_i)``, the last is linear.

        ``W_i`` is (out_i, in_i), ``b_i`` (out_i,). With ``dtype``/``device`` the parameters are converted
        *before* ω is folded in (so float64 callers get float64-exact products). Differentiable with
        respect to the parameters (used inside training losses).
        """
        return [
            (layer.weight.to(device=device, dtype=dtype) * w, layer.bias.to(device=device, dtype=dtype) * w)
            for layer, w in zip(self.layers, self.omegas)
        ]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Values (N, out_dim) at points ``x`` (N, in_dim) (or (..., in_dim)); dtype and device of ``x``.

        With autograd off (``torch.no_grad()``, or neither ``x`` nor any parameter requiring grad) it runs a
        chunked in-place path (:func:`siren_forward_inference`) whose memory stays bounded; otherwise (and
        inside ``torch.func`` transforms) the plain differentiable path. Parameters are converted to the
        dtype/device of ``x`` before use.
        """
        if x.shape[-1] != self.in_dim:
            raise NeuralBakeError(f"Siren: expected points of shape (N, {self.in_dim}), got {tuple(x.shape)}")
        needs_graph = torch.is_grad_enabled() and (
            x.requires_grad or any(p.requires_grad for p in self.parameters())
        )
        if not needs_graph and x.dim() == 2 and not _is_functorch_wrapped(x):
            with torch.no_grad():
                layers = self.affine_layers(dtype=x.dtype, device=x.device)
                return siren_forward_inference(layers, x)
        layers = self.affine_layers(dtype=x.dtype, device=x.device)
        h = x
        for w, b in layers[:-1]:
            h = torch.sin(torch.addmm(b, h, w.t()) if h.dim() == 2 else h @ w.t() + b)
        w, b = layers[-1]
        return torch.addmm(b, h, w.t()) if h.dim() == 2 else h @ w.t() + b

    def extra_repr(self) -> str:
        return f"(W, D) = ({self.width}, {self.depth}), in={self.in_dim}, out={self.out_dim}, ω0={self.omega_0:g}"


def _is_functorch_wrapped(x: torch.Tensor) -> bool:
    """True inside torch.func transforms (vmap, grad, jacrev…), where out= and in-place buffers do not work."""
    try:
        return bool(torch._C._functorch.is_functorch_wrapped_tensor(x))
    except AttributeError:  # pragma: no cover - older torch without the functorch C API
        return False


def siren_forward_inference(
    layers: list[tuple[torch.Tensor, torch.Tensor]], x: torch.Tensor, chunk_size: int | None = None,
    gemm_dtype: torch.dtype | None = None, blocks: bool = True,
) -> torch.Tensor:
    """A SIREN's values without autograd: ``layers`` from :meth:`Siren.affine_layers` (ω folded in).

    ``x``: (N, in_dim) tensor; returns (N, out_dim) of the same dtype and device. Works chunk by chunk of
    ``chunk_size`` points (default :data:`FORWARD_CHUNK_ELEMENTS` ÷ width, at least 256) with two reused
    activation buffers: ``addmm`` into a buffer, then the sine in place (:func:`~neural_bake.nets.fastmath.sin_`:
    the C kernel where it measured faster than ``torch.sin``), so no temporary is allocated per layer. Call
    under ``torch.no_grad()``. ``gemm_dtype`` (e.g. ``torch.bfloat16``): the hidden W×W products on operands
    of that dtype, added to the biases in ``x``'s dtype (as :func:`~neural_bake.nets.gemm.gemm_gradient`). On
    the CPU a network of independent blocks (:mod:`neural_bake.nets.blocks`) runs block by block (``blocks``
    False: its merged matrices).
    """
    n = x.shape[0]
    w_last, b_last = layers[-1]
    out = x.new_empty((n, w_last.shape[0]))
    if n == 0:
        return out
    # on the CPU, a network of independent blocks (a residual SDF) block by block (nets.blocks)
    parts = split_layers(layers, hidden_blocks(layers)) if blocks and x.device.type == "cpu" else [layers]
    for k, part in enumerate(parts):
        width = part[0][0].shape[0]
        dest = out if k == 0 else torch.empty_like(out)
        with gemm_route(width, x.device):  # float32 CPU GEMMs where they run fastest (nets.cpu_gemm)
            _forward_chunks(part, x, dest, max(1, int(chunk_size or forward_chunk_size(width))), gemm_dtype)
        if k:
            out.add_(dest)
    return out


def _forward_chunks(layers, x, out, chunk, gemm_dtype):
    n = x.shape[0]
    w_last, b_last = layers[-1]
    width = layers[0][0].shape[0]
    c0 = min(chunk, n)
    bufs = [x.new_empty((c0, width)), x.new_empty((c0, width))]
    low = [None] + [w.t().to(gemm_dtype).contiguous() for w, _ in layers[1:-1]] if gemm_dtype is not None else None
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        c = stop - start
        h = x[start:stop]
        for i, (w, b) in enumerate(layers[:-1]):
            a = bufs[i % 2][:c]
            if low is not None and i > 0:
                torch.add(b, torch.mm(h.to(gemm_dtype), low[i]), out=a)
            else:
                torch.addmm(b, h, w.t(), out=a)
            sin_(a)  # the fast C sine where it measured faster than torch.sin (nets.fastmath)
            h = a
        torch.addmm(b_last, h, w_last.t(), out=out[start:stop])
