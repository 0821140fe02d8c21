"""GEMM normals: a SIREN's gradient in closed form, by matrix products alone (no autograd graph).

Paper: "Nested neighborhoods for textured neural SDFs", §4.3 and Appendix A.1 (Algorithm 2). For a SIREN
with ω folded into the weights (:meth:`Siren.affine_layers`), hidden layer i is ``h_i = sin(A_i)`` with
``A_i = W_i h_{i-1} + b_i`` (``h_{-1} = x``) and the output is ``y = W_n h_D + b_n``. By the chain rule

    ∇y = W_n · diag(cos A_D) · W_D · … · diag(cos A_0) · W_0.

Two evaluation orders, both batched over points so that every product is one GEMM:

- ``mode="forward"`` (Algorithm 2): ``in_dim`` tangent streams ``G_0[j] = W_0[:, j] ⊙ cos A_0``,
  ``G_i = (W_i G_{i-1}) ⊙ cos A_i``, ``G_n = W_n G_D``, stacked into one (in_dim·N, W) matrix so the
  streams share each GEMM; interleaved with the forward pass (nothing but the current layer is kept).
- ``mode="reverse"``: the same product evaluated from the output back, keeping ``cos A_i`` of every layer:
  ``g = W_n ⊙ cos A_D``, ``g = (g W_i) ⊙ cos A_{i-1}``, ``∇y = g W_0``. One (out_dim·N, W) stream instead
  of in_dim, so for a scalar SDF it costs about one forward pass of GEMMs more, against in_dim for forward.

Without ``differentiable`` the work runs under ``torch.no_grad()``, chunk by chunk of points with buffers
reused across layers and chunks (``addmm``/``mm`` with ``out=``, ``sin``/``cos`` written in place by the
fused kernel of :mod:`neural_bake.nets.fastmath` where it is available), so the memory stays bounded
whatever N and no fresh (page-faulting) allocation happens per layer; the chunk size
(:func:`default_chunk_size`) was chosen by measurement. On the CPU a network of independent hidden blocks (a
residual SDF, :mod:`neural_bake.nets.blocks`) runs block by block, its zero blocks skipped. With
``differentiable=True`` the same formulas keep the graph to the weights (no chunking), so a loss on the
gradients (eikonal, orthogonality) backpropagates to the weights with one ordinary backward pass — no
double-backward. For a scalar field in reverse mode (the SDF training losses) the whole pass is one autograd
node with a hand-written backward (:class:`_ReverseScalar`: the same GEMMs, half the element-wise passes,
differentiable once); otherwise it is torch's graph of the formulas, with :func:`sin_cos` as the one node per
layer.
"""

from __future__ import annotations

import contextlib

import torch
from torch.autograd.function import once_differentiable

from ..constants import GRAD_EPS
from ..errors import NeuralBakeError
from .blocks import hidden_blocks, split_layers
from .cpu_gemm import gemm_route
from .fastmath import sincos, sincos_

__all__ = ["gemm_gradient", "normalized_gradient", "autograd_graph_only", "default_chunk_size", "sin_cos",
           "GEMM_CHUNK_ELEMENTS", "MODES"]

#: The evaluation orders of :func:`gemm_gradient`.
MODES = ("reverse", "forward")

#: Size (points × streams × width) of the largest buffer of a chunk of the no-grad path: 2^18 elements
#: (1 MB in float32), i.e. 1,024 points of a (256, D) scalar SDF in reverse mode (341 in forward mode,
#: 3 streams) and 4,096 of a (64, D) one: reverse mode keeps D + 1 cos buffers of this size, and the
#: working set must stay in a core's L2 cache (the chunk sweep of `neural-bake bench normals`: docs/findings.md).
GEMM_CHUNK_ELEMENTS = 1 << 18


def default_chunk_size(mode: str, width: int, in_dim: int = 3, out_dim: int = 1) -> int:
    """Points per chunk that :func:`gemm_gradient` uses when ``chunk_size`` is None (at least 256)."""
    streams = out_dim if mode == "reverse" else in_dim
    return max(256, GEMM_CHUNK_ELEMENTS // (int(width) * int(streams)))


def gemm_gradient(
    model,
    points: torch.Tensor,
    mode: str = "reverse",
    *,
    differentiable: bool = False,
    chunk_size: int | None = None,
    gemm_dtype: torch.dtype | None = None,
    blocks: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Values and gradients of a SIREN at a batch of points, by GEMMs (no autograd).

    Args:
        model: a :class:`~neural_bake.nets.siren.Siren` (anything with ``affine_layers(dtype=, device=)``,
            ``in_dim`` and ``out_dim``).
        points: (N, in_dim) floating tensor, in the frame the network was fitted in (the unit frame for
            SDFs; (x, y, z, t) for space-time fields). Its dtype and device are those of the results; the
            weights are cast to them if they differ.
        mode: ``"reverse"`` (default; fewest FLOPs for a scalar field) or ``"forward"`` (Algorithm 2).
        differentiable: keep the autograd graph so a loss on the gradients backpropagates to the weights
            (and to ``points`` if it requires grad). No chunking. Default False: no graph, chunked.
        chunk_size: points per chunk of the no-grad path (default :func:`default_chunk_size`); ignored
            when ``differentiable``.
        gemm_dtype: None (default: every product in the points' dtype) or a reduced precision such as
            ``torch.bfloat16`` for the hidden W×W products of the no-grad reverse path (forward and gradient
            stream): operands converted to it, accumulated by the BLAS in float32, results added to the
            float32 biases and streams; the first (3 → W) and last layers and sin/cos stay in the points'
            dtype (:mod:`neural_bake.nets.precision` decides where it pays). Ignored when ``differentiable``
            and in forward mode.
        blocks: on the CPU, run a network of independent hidden blocks (:mod:`neural_bake.nets.blocks`) block
            by block (default); False: its merged matrices, zero blocks and all (for comparison).

    Returns:
        ``(values, grads)``: values (N, out_dim); grads (N, in_dim) if ``out_dim == 1`` else
        (N, out_dim, in_dim) with ``grads[n, k, j] = ∂y_k/∂x_j`` at point n (a Jacobian per point).

    Raises:
        NeuralBakeError: points not a floating (N, in_dim) tensor, an unknown mode, a chunk size < 1.
    """
    in_dim, out_dim = int(model.in_dim), int(model.out_dim)
    if getattr(model, "composite", False):  # a field of several networks (nets.tiles.TiledSdf) adds its own
        return model.gemm_gradient(points, mode=mode, differentiable=differentiable, chunk_size=chunk_size,
                                   gemm_dtype=gemm_dtype)
    if not isinstance(points, torch.Tensor):
        raise NeuralBakeError(f"gemm_gradient: points must be a torch tensor, got {type(points).__name__}")
    if points.dim() != 2 or points.shape[1] != in_dim:
        raise NeuralBakeError(
            f"gemm_gradient: points must have shape (N, {in_dim}) for this network, got {tuple(points.shape)}"
        )
    if not points.is_floating_point():
        raise NeuralBakeError(f"gemm_gradient: points must be a floating tensor, got {points.dtype}")
    if mode not in MODES:
        raise NeuralBakeError(f"gemm_gradient: mode must be one of {', '.join(MODES)}; got {mode!r}")
    if chunk_size is not None and (int(chunk_size) != chunk_size or chunk_size < 1):
        raise NeuralBakeError(f"gemm_gradient: chunk_size must be a positive integer, got {chunk_size!r}")
    # (not inside a compiled training step: the check reads a tensor, a graph break there, on points it drew)
    if not torch.compiler.is_compiling() and not bool(torch.isfinite(points).all()):
        raise NeuralBakeError(f"gemm_gradient: points has {int((~torch.isfinite(points)).sum())} non-finite values")

    dtype, device = points.dtype, points.device
    if differentiable and torch.is_grad_enabled():  # a training step: its loop picks the GEMM route
        layers = model.affine_layers(dtype=dtype, device=device)
        values, grads = (_reverse_graph if mode == "reverse" else _forward_graph)(layers, points)
    else:
        with torch.no_grad():
            layers = model.affine_layers(dtype=dtype, device=device)
            # on the CPU, a network of independent blocks (a residual SDF) block by block (nets.blocks)
            parts = split_layers(layers, hidden_blocks(layers)) if blocks and device.type == "cpu" else [layers]
            values = grads = None
            for part in parts:
                width = int(part[0][0].shape[0])
                chunk = int(chunk_size) if chunk_size is not None else default_chunk_size(mode, width, in_dim,
                                                                                          out_dim)
                # float32 CPU GEMMs on the route that runs them fastest here (nets.cpu_gemm)
                with gemm_route(width, device):
                    if mode == "reverse":
                        v, g = _reverse_chunked(part, points, chunk, gemm_dtype)
                    else:
                        v, g = _forward_chunked(part, points, chunk)
                values, grads = (v, g) if values is None else (values.add_(v), grads.add_(g))
    if out_dim == 1:
        grads = grads.reshape(points.shape[0], in_dim)
    return values, grads


def normalized_gradient(grads: torch.Tensor, eps: float = GRAD_EPS) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit vectors along ``grads`` with a validity mask, never NaN.

    Args:
        grads: (..., d) floating tensor (e.g. (N, 3) SDF gradients from :func:`gemm_gradient`).
        eps: gradients with norm below this (or not finite) are invalid.

    Returns:
        ``(unit, valid)``: unit (..., d) same dtype/device (a zero vector where invalid) and valid (...) bool.
    """
    norm = torch.linalg.vector_norm(grads, dim=-1, keepdim=True)
    valid = torch.isfinite(norm) & (norm >= eps)
    safe = torch.where(valid, norm, torch.ones_like(norm))
    unit = torch.where(valid, grads / safe, torch.zeros_like(grads))
    return unit, valid.squeeze(-1)


# --- differentiable paths (autograd graph of the weights; no in-place, no chunking) -----------------------


class _SinCos(torch.autograd.Function):
    """(sin a, cos a) as one node whose backward reuses both outputs: ``ḡ_a = ḡ_s cos a − ḡ_c sin a``.

    Separate ``torch.sin``/``torch.cos`` nodes each recompute the other function in their backward (two
    more transcendental passes over every hidden unit per training step); this node computes none.
    The backward is built from differentiable ops on the saved outputs, so higher derivatives stay exact.
    """

    @staticmethod
    def forward(ctx, a):
        s, c = sincos(a.detach())
        ctx.save_for_backward(s, c)
        return s, c

    @staticmethod
    def backward(ctx, grad_s, grad_c):
        s, c = ctx.saved_tensors
        if grad_c is None:
            return grad_s * c
        if grad_s is None:
            return -(grad_c * s)
        return torch.addcmul(grad_s * c, grad_c, s, value=-1.0)  # two passes over the layer, not three


def sin_cos(a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(sin a, cos a)``; on the autograd graph (when ``a`` requires grad) one node whose backward needs no
    transcendental function."""
    if torch.is_grad_enabled() and a.requires_grad:
        return _SinCos.apply(a)
    return sincos(a)



def _backward_mats(layers):
    """The hidden weights W_0 … W_D that the reverse chain rule multiplies by; for a scalar field the output
    row is folded into W_D, (cos A_D ⊙ w_n) W_D = cos A_D (diag(w_n) W_D), which saves an element-wise pass
    over the (N, W) gradient stream (and, on the autograd graph, its backward)."""
    mats = [w for w, _ in layers[:-1]]
    w_n = layers[-1][0]
    if w_n.shape[0] == 1:
        mats[-1] = mats[-1] * w_n[0].unsqueeze(1)
    # The last product, (N, W) @ W_0 with W_0 (W, in_dim), is skinny: MKL runs it faster when W_0 is the
    # transposed view of a contiguous (in_dim, W) array.
    mats[0] = mats[0].t().contiguous().t()
    return mats


class _ReverseScalar(torch.autograd.Function):
    """Values and reverse-mode GEMM gradient of a scalar SIREN as one autograd node with a hand-written
    backward (the training losses' path: :func:`_reverse_graph` for ``out_dim == 1``).

    Forward (layers as in the module docstring, ``M_i`` the matrices of :func:`_backward_mats`):
    ``h_i = sin A_i``, ``c_i = cos A_i``, ``f = w_n h_D + b_n``; the stream ``g_D = c_D``,
    ``u_i = g_i M_i``, ``g_{i-1} = u_i ⊙ c_{i-1}``, ``∇f = g_0 M_0``. Backward, for ``φ = ∂L/∂f`` and
    ``ψ = ∂L/∂∇f``: down the stream, ``ḡ_0 = ψ M_0ᵀ`` and for i = 1 … D ``ū_i = ḡ_{i-1} ⊙ c_{i-1}``,
    ``c̄_{i-1} = ḡ_{i-1} ⊙ u_i``, ``M̄_i = g_iᵀ ū_i``, ``ḡ_i = ū_i M_iᵀ``, ending with ``c̄_D = ḡ_D``; then
    down the forward pass, ``h̄_D = φ w_n`` and for i = D … 0 ``Ā_i = h̄_i ⊙ c_i − c̄_i ⊙ h_i``,
    ``W̄_i = Ā_iᵀ h_{i-1} + M̄_i`` (one GEMM accumulating onto M̄_i), ``b̄_i = Σ Ā_i``, ``h̄_{i-1} = Ā_i W_i``.
    ``M_D = diag(w_n) W_D`` sends ``diag(w_n) M̄_D`` to W_D and the rows of ``M̄_D ⊙ W_D`` to w_n.

    The same GEMMs as the autograd graph of the same formulas, with about half its element-wise passes
    (written in place, no gradient accumulation buffers) and no per-operation graph bookkeeping. It is
    differentiable once: a loss on ∇f trains the weights by one ordinary backward, which is all the GEMM
    gradient is for; a second derivative through it raises.
    """

    @staticmethod
    def forward(ctx, x, *params):
        layers = list(zip(params[0::2], params[1::2]))
        hidden, (w_n, b_n) = layers[:-1], layers[-1]
        acts, coss = [x], []
        h = x
        for w, b in hidden:
            a = torch.addmm(b, h, w.t())
            h = torch.empty_like(a)
            sincos_(a, h)  # a becomes cos A in place
            acts.append(h)
            coss.append(a)
        values = torch.addmm(b_n, h, w_n.t())
        mats = _backward_mats(layers)
        stream, pre = [coss[-1]], []  # g_D, …, g_0 and u_D, …, u_1
        for i in range(len(hidden) - 1, 0, -1):
            u = stream[-1] @ mats[i]
            pre.append(u)
            stream.append(u * coss[i - 1])
        grads = stream[-1] @ mats[0]
        ctx.save_for_backward(*acts, *coss, *stream, *pre, *mats, *params)
        ctx.depth = len(hidden) - 1
        return values, grads

    @staticmethod
    @once_differentiable
    def backward(ctx, d_values, d_grads):  # both given (autograd fills an unused output's with zeros)
        saved = ctx.saved_tensors
        d = ctx.depth
        acts = saved[: d + 2]  # x, h_0 … h_D
        coss = saved[d + 2: 2 * d + 3]  # c_0 … c_D
        stream = saved[2 * d + 3: 3 * d + 4][::-1]  # g_0 … g_D
        pre = (None,) + saved[3 * d + 4: 4 * d + 4][::-1]  # u_1 … u_D at index 1 … D
        mats = saved[4 * d + 4: 5 * d + 5]  # M_0 … M_D, as the forward built them
        params = saved[5 * d + 5:]
        layers = list(zip(params[0::2], params[1::2]))
        w_n = layers[-1][0]
        # down the stream: M̄_i and c̄_i
        # (ψᵀ g_0)ᵀ, not g_0ᵀ ψ: a (3, N) @ (N, W) product runs faster than (W, N) @ (N, 3)
        d_mats = [(d_grads.t() @ stream[0]).t()]
        d_cos = []
        dg = d_grads @ mats[0].t()
        for i in range(1, d + 1):
            du = dg * coss[i - 1]
            d_cos.append(dg.mul_(pre[i]))  # ḡ_{i-1} is not needed after this
            d_mats.append(stream[i].t() @ du)
            dg = du @ mats[i].t()
        d_cos.append(dg)
        out: list = [None] * (len(params) + 1)
        out[-2] = d_values.t() @ acts[-1] + (d_mats[d] * layers[d][0]).sum(1).unsqueeze(0)  # M_D = diag(w_n) W_D
        out[-1] = d_values.sum(0)
        d_mats[d] = d_mats[d] * w_n[0].unsqueeze(1)
        # down the forward pass
        dh = d_values * w_n  # (N, 1) ⊙ (1, W): an outer product
        for i in range(d, -1, -1):
            da = dh.mul_(coss[i]).addcmul_(d_cos[i], acts[i + 1], value=-1.0)
            if i == 0:  # W̄_0 = (xᵀ Ā_0 + M̄_0ᵀ)ᵀ, the skinny product in its fast orientation (as M̄_0)
                out[1] = torch.addmm(d_mats[0].t(), acts[0].t(), da).t()
            else:
                out[2 * i + 1] = torch.addmm(d_mats[i], da.t(), acts[i])
            out[2 * i + 2] = da.sum(0)
            dh = da @ layers[i][0] if (i > 0 or ctx.needs_input_grad[0]) else None
        out[0] = dh
        return tuple(out)


#: Whether the differentiable reverse path of a scalar field takes :class:`_ReverseScalar` (see
#: :func:`autograd_graph_only`).
_fused = {"scalar": True}


@contextlib.contextmanager
def autograd_graph_only():
    """Within the block, the differentiable reverse path builds torch's autograd graph of the formulas even
    for scalar fields instead of the hand-written backward: for A/B timings (``bench fit``) and tests. The
    numbers are the same; not thread-safe (it switches a module setting)."""
    before = _fused["scalar"]
    _fused["scalar"] = False
    try:
        yield
    finally:
        _fused["scalar"] = before


def _reverse_graph(layers, x):
    """Values and reverse-mode gradient with the graph to the weights (and to ``x``)."""
    if _fused["scalar"] and layers[-1][0].shape[0] == 1 and len(layers) > 1:  # a scalar field
        values, grads = _ReverseScalar.apply(x, *(t for layer in layers for t in layer))
        return values, grads.unsqueeze(1)
    return _reverse_graph_autograd(layers, x)


def _reverse_graph_autograd(layers, x):
    """:func:`_reverse_graph` on torch's autograd graph (any out_dim; the reference of :class:`_ReverseScalar`)."""
    n = x.shape[0]
    derivs = []
    h = x
    for w, b in layers[:-1]:
        h, c = sin_cos(torch.addmm(b, h, w.t()))
        derivs.append(c)
    w_n, b_n = layers[-1]
    values = torch.addmm(b_n, h, w_n.t())
    k = w_n.shape[0]
    mats = _backward_mats(layers)
    # (N, k, W); a scalar field's output row is already in mats[-1]
    g = derivs[-1].unsqueeze(1) if k == 1 else derivs[-1].unsqueeze(1) * w_n.unsqueeze(0)
    for i in range(len(derivs) - 1, 0, -1):
        g = (g.reshape(n * k, -1) @ mats[i]).reshape(n, k, -1) * derivs[i - 1].unsqueeze(1)
    grads = (g.reshape(n * k, -1) @ mats[0]).reshape(n, k, -1)
    return values, grads


def _forward_graph(layers, x):
    n, d = x.shape
    w_0, b_0 = layers[0]
    h, c = sin_cos(torch.addmm(b_0, x, w_0.t()))
    g = c.unsqueeze(0) * w_0.t().unsqueeze(1)  # (d, N, W): stream j is W_0[:, j] ⊙ cos A_0
    for w, b in layers[1:-1]:
        h, c = sin_cos(torch.addmm(b, h, w.t()))
        g = (g.reshape(d * n, -1) @ w.t()).reshape(d, n, -1) * c.unsqueeze(0)
    w_n, b_n = layers[-1]
    values = torch.addmm(b_n, h, w_n.t())
    grads = (g.reshape(d * n, -1) @ w_n.t()).reshape(d, n, -1).permute(1, 2, 0)  # (N, k, d)
    return values, grads


# --- no-grad chunked paths (buffers reused across layers and chunks) --------------------------------------


def _reverse_chunked(layers, x, chunk, low=None):
    n, d = x.shape
    w_n, b_n = layers[-1]
    k, width = w_n.shape
    values = x.new_empty((n, k))
    grads = x.new_empty((n, k, d))
    if n == 0:
        return values, grads
    c0 = min(chunk, n)
    hidden = layers[:-1]
    # reduced precision: the hidden W×W products on ``low`` operands (the BLAS accumulates in float32; the
    # result, rounded to ``low``, is added to the float32 bias / multiplied into the float32 stream)
    low_fwd = [None] + [w.t().to(low).contiguous() for w, _ in hidden[1:]] if low is not None else None
    # cos A_i of every hidden layer (the pre-activation is written there first, then turned into cos
    # in place), two activation buffers and two gradient-stream buffers.
    cos_bufs = [x.new_empty((c0, width)) for _ in hidden]
    act = [x.new_empty((c0, width)), x.new_empty((c0, width))]
    gbuf = [x.new_empty((c0 * k, width)), x.new_empty((c0 * k, width))]
    w_n_row = w_n.unsqueeze(0)  # (1, k, W)
    mats = _backward_mats(layers)[::-1]  # backward GEMM weights, last layer first
    low_bwd = [m.to(low).contiguous() for m in mats[:-1]] if low is not None else None
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        c = stop - start
        h = x[start:stop]
        for i, (w, b) in enumerate(hidden):
            a = cos_bufs[i][:c]
            if low_fwd is not None and i > 0:
                torch.add(b, torch.mm(h.to(low), low_fwd[i]), out=a)
            else:
                torch.addmm(b, h, w.t(), out=a)
            h = act[i % 2][:c]
            sincos_(a, h)
        torch.addmm(b_n, h, w_n.t(), out=values[start:stop])
        if k == 1:
            g = cos_bufs[-1][:c]  # w_n is folded into mats[0]
        else:
            g = gbuf[0][: c * k]
            torch.mul(cos_bufs[-1][:c].unsqueeze(1), w_n_row, out=g.view(c, k, width))
        for i in range(len(hidden) - 1, 0, -1):
            g_next = gbuf[(len(hidden) - i) % 2][: c * k]
            if low_bwd is not None:
                g_next.copy_(torch.mm(g.to(low), low_bwd[len(hidden) - 1 - i]))
            else:
                torch.mm(g, mats[len(hidden) - 1 - i], out=g_next)
            if k == 1:
                g_next.mul_(cos_bufs[i - 1][:c])
            else:
                g_next.view(c, k, width).mul_(cos_bufs[i - 1][:c].unsqueeze(1))
            g = g_next
        torch.mm(g, mats[-1], out=grads[start:stop].view(c * k, d))
    return values, grads


def _forward_chunked(layers, x, chunk):
    n, d = x.shape
    w_0, b_0 = layers[0]
    w_n, b_n = layers[-1]
    k, width = w_n.shape
    values = x.new_empty((n, k))
    grads = x.new_empty((n, k, d))
    if n == 0:
        return values, grads
    c0 = min(chunk, n)
    a_buf = x.new_empty((c0, width))
    act = [x.new_empty((c0, width)), x.new_empty((c0, width))]
    # flat buffers viewed as (d, c, ·) so that a short last chunk is still contiguous
    gbuf = [x.new_empty(d * c0 * width), x.new_empty(d * c0 * width)]
    gout = x.new_empty(d * c0 * k)
    w_0_cols = w_0.t().unsqueeze(1)  # (d, 1, W): row j is column j of W_0
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        c = stop - start
        a = a_buf[:c]
        torch.addmm(b_0, x[start:stop], w_0.t(), out=a)
        h = act[0][:c]
        sincos_(a, h)
        g = gbuf[0][: d * c * width].view(d, c, width)
        torch.mul(a.unsqueeze(0), w_0_cols, out=g)
        for i, (w, b) in enumerate(layers[1:-1], start=1):
            torch.addmm(b, h, w.t(), out=a)
            h = act[i % 2][:c]
            sincos_(a, h)
            g_next = gbuf[i % 2][: d * c * width].view(d, c, width)
            torch.mm(g.view(d * c, width), w.t(), out=g_next.view(d * c, width))
            g_next.mul_(a.unsqueeze(0))
            g = g_next
        torch.addmm(b_n, h, w_n.t(), out=values[start:stop])
        go = gout[: d * c * k].view(d, c, k)
        torch.mm(g.view(d * c, width), w_n.t(), out=go.view(d * c, k))
        grads[start:stop].copy_(go.permute(1, 2, 0))
    return values, grads
