"""GEMM normals against torch.autograd, central finite differences, and double-backward autograd."""

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from neural_bake.errors import NeuralBakeError
from neural_bake.nets.gemm import gemm_gradient, normalized_gradient
from neural_bake.nets.siren import Siren

MODES = ("reverse", "forward")
TOL = {torch.float32: 1e-5, torch.float64: 1e-10}


def _model(width, depth, in_dim, out_dim, omega, dtype, seed=0):
    g = torch.Generator().manual_seed(seed)
    return Siren(width, depth, in_dim, out_dim, omega_0=omega, generator=g).to(dtype)


def _points(n, in_dim, dtype, seed=1):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(n, in_dim, generator=g, dtype=torch.float64) * 2 - 1).to(dtype)


def _autograd_jacobian(model, x):
    """Reference: values (N, k) and Jacobians (N, k, d) by first-order autograd, one backward per output."""
    x = x.detach().clone().requires_grad_(True)
    with torch.enable_grad():
        y = model(x)
        rows = [torch.autograd.grad(y[:, k].sum(), x, retain_graph=True)[0] for k in range(y.shape[1])]
    return y.detach(), torch.stack(rows, dim=1)


def _as_jacobian(grads, out_dim):
    return grads.unsqueeze(1) if out_dim == 1 else grads


def _assert_rel(actual, expected, rtol):
    """|actual - expected| <= rtol * max|expected| everywhere (relative to the scale of the field)."""
    scale = expected.abs().max().item()
    err = (actual - expected).abs().max().item()
    assert err <= rtol * max(scale, 1e-30), f"max error {err:.3g} > {rtol:g} × scale {scale:.3g}"


@settings(max_examples=40, deadline=None)
@given(
    width=st.integers(1, 24),
    depth=st.integers(0, 4),
    in_dim=st.sampled_from([3, 4]),
    out_dim=st.sampled_from([1, 3]),
    omega=st.floats(1.0, 100.0),
    n=st.integers(1, 40),
    seed=st.integers(0, 2**16),
    dtype=st.sampled_from([torch.float32, torch.float64]),
    mode=st.sampled_from(MODES),
)
def test_matches_autograd_property(width, depth, in_dim, out_dim, omega, n, seed, dtype, mode):
    model = _model(width, depth, in_dim, out_dim, omega, dtype, seed)
    x = _points(n, in_dim, dtype, seed + 1)
    y_ref, j_ref = _autograd_jacobian(model, x)
    with torch.no_grad():
        y, g = gemm_gradient(model, x, mode)
    assert y.shape == (n, out_dim) and y.dtype == dtype
    assert g.shape == ((n, in_dim) if out_dim == 1 else (n, out_dim, in_dim)) and g.dtype == dtype
    _assert_rel(y, y_ref, TOL[dtype])
    _assert_rel(_as_jacobian(g, out_dim), j_ref, TOL[dtype])


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("in_dim,out_dim", [(3, 1), (4, 1), (3, 3), (4, 3)])
def test_matches_central_differences_float64(mode, in_dim, out_dim):
    model = _model(16, 2, in_dim, out_dim, 30.0, torch.float64, seed=in_dim + out_dim)
    x = _points(25, in_dim, torch.float64)
    _, g = gemm_gradient(model, x, mode)  # points do not require grad, grad mode on: still no graph
    assert g.grad_fn is None and not g.requires_grad
    h = 1e-6
    fd = torch.empty(25, out_dim, in_dim, dtype=torch.float64)
    with torch.no_grad():
        for j in range(in_dim):
            e = torch.zeros(in_dim, dtype=torch.float64)
            e[j] = h
            fd[:, :, j] = (model(x + e) - model(x - e)) / (2 * h)
    _assert_rel(_as_jacobian(g, out_dim), fd, 1e-6)  # the FD truncation/round-off error, not ours


def test_sphere_like_analytic_oracle():
    """Depth 0, width 1: f(x) = a sin(w·x + b) + c, so ∇f = a cos(w·x + b) w exactly."""
    model = _model(1, 0, 3, 1, 1.0, torch.float64)
    (w0, b0), (w1, b1) = model.affine_layers()
    x = _points(50, 3, torch.float64)
    expected = w1[0, 0] * torch.cos(x @ w0[0] + b0[0])[:, None] * w0[0][None, :]
    for mode in MODES:
        y, g = gemm_gradient(model, x, mode)
        torch.testing.assert_close(g, expected.detach(), rtol=1e-14, atol=1e-14)
        torch.testing.assert_close(y[:, 0], (w1[0, 0] * torch.sin(x @ w0[0] + b0[0]) + b1[0]).detach())


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("out_dim", [1, 3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_chunking_gives_identical_results(mode, out_dim, dtype):
    model = _model(32, 2, 3, out_dim, 30.0, dtype)
    x = _points(203, 3, dtype)
    y_full, g_full = gemm_gradient(model, x, mode, chunk_size=203)
    for chunk in (1, 7, 64, 1000):
        y, g = gemm_gradient(model, x, mode, chunk_size=chunk)
        _assert_rel(y, y_full, TOL[dtype] / 10)  # GEMM blocking may change the rounding, nothing more
        _assert_rel(g, g_full, TOL[dtype] / 10)


@pytest.mark.parametrize("mode", MODES)
def test_chunking_bitwise_on_rows_of_equal_blocks(mode):
    """Chunks of the same size hold identical rows: the results do not depend on where a point lands."""
    model = _model(32, 2, 3, 1, 30.0, torch.float32)
    x = _points(64, 3, torch.float32)
    _, g1 = gemm_gradient(model, x, mode, chunk_size=32)
    _, g2 = gemm_gradient(model, torch.cat([x[32:], x[:32]]), mode, chunk_size=32)
    assert torch.equal(g1, torch.cat([g2[32:], g2[:32]]))


@pytest.mark.parametrize("mode", MODES)
def test_modes_agree_float64(mode):
    model = _model(24, 3, 4, 3, 50.0, torch.float64)
    x = _points(60, 4, torch.float64)
    _, g_rev = gemm_gradient(model, x, "reverse")
    _, g = gemm_gradient(model, x, mode)
    _assert_rel(g, g_rev, 1e-12)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("out_dim", [1, 3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("depth", [0, 2])  # depth 0: the scalar output row folds into W_0 itself
def test_differentiable_matches_double_backward(mode, out_dim, dtype, depth):
    """A loss on the gradients backpropagates to the weights exactly as double-backward autograd does."""
    model = _model(16, depth, 3, out_dim, 30.0, dtype, seed=3)
    x = _points(40, 3, dtype)

    def loss_of(jac):  # eikonal-like on the first output + a term on all Jacobian entries
        return ((jac[:, 0].norm(dim=-1) - 1) ** 2).mean() + (jac**2).sum(dim=(1, 2)).mean() * 0.1

    xr = x.clone().requires_grad_(True)
    y = model(xr)
    rows = [torch.autograd.grad(y[:, k].sum(), xr, create_graph=True)[0] for k in range(out_dim)]
    ref = torch.autograd.grad(loss_of(torch.stack(rows, 1)) + y.mean(), list(model.parameters()))

    values, g = gemm_gradient(model, x, mode, differentiable=True)
    assert g.requires_grad
    ours = torch.autograd.grad(loss_of(_as_jacobian(g, out_dim)) + values.mean(), list(model.parameters()))
    for a, b in zip(ours, ref):
        _assert_rel(a, b, 1e-4 if dtype == torch.float32 else 1e-10)


def test_differentiable_flows_to_points():
    model = _model(8, 1, 3, 1, 10.0, torch.float64)
    x = _points(10, 3, torch.float64).requires_grad_(True)
    _, g = gemm_gradient(model, x, differentiable=True)
    (gx,) = torch.autograd.grad(g[:, 0].sum(), x)
    xr = x.detach().clone().requires_grad_(True)
    (gr,) = torch.autograd.grad(model(xr).sum(), xr, create_graph=True)
    (ref,) = torch.autograd.grad(gr[:, 0].sum(), xr)
    _assert_rel(gx, ref, 1e-10)


@pytest.mark.parametrize("mode", MODES)
def test_no_graph_without_differentiable(mode):
    model = _model(8, 1, 3, 1, 30.0, torch.float32)
    x = _points(10, 3, torch.float32).requires_grad_(True)
    y, g = gemm_gradient(model, x, mode)
    assert not y.requires_grad and not g.requires_grad
    with torch.no_grad():  # differentiable under no_grad: same numbers, no graph
        y2, g2 = gemm_gradient(model, x, mode, differentiable=True)
    assert not g2.requires_grad
    torch.testing.assert_close(g2, g, rtol=1e-5, atol=1e-6)
    with torch.inference_mode():
        _, g3 = gemm_gradient(model, x.detach(), mode)
    torch.testing.assert_close(g3, g, rtol=0, atol=0)


def test_dtype_follows_points():
    model = _model(8, 1, 3, 1, 30.0, torch.float32)
    x64 = _points(10, 3, torch.float64)
    _, g = gemm_gradient(model, x64)
    assert g.dtype == torch.float64 and g.device == x64.device
    _, j_ref = _autograd_jacobian(model.double(), x64)
    _assert_rel(g, j_ref[:, 0], 1e-10)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("out_dim", [1, 3])
def test_empty_batch(mode, out_dim):
    model = _model(8, 1, 3, out_dim, 30.0, torch.float32)
    y, g = gemm_gradient(model, torch.zeros(0, 3), mode)
    assert y.shape == (0, out_dim) and g.shape == ((0, 3) if out_dim == 1 else (0, out_dim, 3))


def test_bad_input_errors():
    model = _model(8, 1, 3, 1, 30.0, torch.float32)
    with pytest.raises(NeuralBakeError, match=r"points must have shape \(N, 3\).*\(10, 4\)"):
        gemm_gradient(model, torch.zeros(10, 4))
    with pytest.raises(NeuralBakeError, match=r"points must have shape \(N, 3\).*\(3,\)"):
        gemm_gradient(model, torch.zeros(3))
    with pytest.raises(NeuralBakeError, match="points must be a torch tensor, got ndarray"):
        gemm_gradient(model, torch.zeros(2, 3).numpy())
    with pytest.raises(NeuralBakeError, match="points has 2 non-finite values"):
        gemm_gradient(model, torch.tensor([[0.0, float("nan"), 0.0], [float("inf"), 0.0, 0.0]]))
    with pytest.raises(NeuralBakeError, match="points must be a floating tensor, got torch.int64"):
        gemm_gradient(model, torch.zeros(2, 3, dtype=torch.int64))
    with pytest.raises(NeuralBakeError, match="mode must be one of reverse, forward; got 'backward'"):
        gemm_gradient(model, torch.zeros(2, 3), "backward")
    with pytest.raises(NeuralBakeError, match="chunk_size must be a positive integer, got 0"):
        gemm_gradient(model, torch.zeros(2, 3), chunk_size=0)


def test_normalized_gradient_guard():
    g = torch.tensor([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [1e-12, 0.0, 0.0], [float("nan"), 1.0, 0.0],
                      [float("inf"), 0.0, 0.0], [0.0, -2.0, 0.0]])
    unit, valid = normalized_gradient(g)
    assert valid.tolist() == [True, False, False, False, False, True]
    assert torch.isfinite(unit).all()
    torch.testing.assert_close(unit[0], torch.tensor([0.6, 0.8, 0.0]))
    torch.testing.assert_close(unit[5], torch.tensor([0.0, -1.0, 0.0]))
    assert (unit[1:5] == 0).all()
    unit, valid = normalized_gradient(g[:2], eps=10.0)
    assert valid.tolist() == [False, False] and (unit == 0).all()


def test_normalized_gradient_no_nan_in_backward():
    g = torch.tensor([[0.0, 0.0, 0.0], [1.0, 2.0, 2.0]], dtype=torch.float64, requires_grad=True)
    unit, valid = normalized_gradient(g)
    unit.sum().backward()
    assert torch.isfinite(g.grad).all() and valid.tolist() == [False, True]


def test_normalized_gradient_batched_jacobians():
    j = torch.randn(5, 3, 4, dtype=torch.float64)
    unit, valid = normalized_gradient(j)
    assert unit.shape == (5, 3, 4) and valid.shape == (5, 3) and valid.all()
    torch.testing.assert_close(unit.norm(dim=-1), torch.ones(5, 3, dtype=torch.float64))


def test_high_omega_depth_four_float32_reverse_and_forward():
    model = _model(64, 4, 3, 1, 100.0, torch.float32, seed=9)
    x = _points(300, 3, torch.float32)
    _, j_ref = _autograd_jacobian(model, x)
    for mode in MODES:
        _, g = gemm_gradient(model, x, mode, chunk_size=128)
        _assert_rel(g, j_ref[:, 0], 1e-5)
        assert math.isfinite(g.abs().max().item())


def test_default_chunk_size():
    from neural_bake.nets.gemm import GEMM_CHUNK_ELEMENTS, default_chunk_size

    assert default_chunk_size("reverse", 256) == GEMM_CHUNK_ELEMENTS // 256
    assert default_chunk_size("forward", 256, in_dim=3) == GEMM_CHUNK_ELEMENTS // 768
    assert default_chunk_size("reverse", 64, out_dim=3) == GEMM_CHUNK_ELEMENTS // 192
    assert default_chunk_size("reverse", 10**9) == 256


# --- sin_cos: the fused (sin, cos) node of the differentiable paths ---------------------------------------


@pytest.mark.parametrize("which", ["both", "sin", "cos"])
def test_sin_cos_gradcheck(which):
    """First and second derivatives of the fused node against finite differences (float64)."""
    from neural_bake.nets.gemm import sin_cos

    a = (torch.rand(5, 7, dtype=torch.float64) * 20 - 10).requires_grad_(True)
    wsin = torch.rand(5, 7, dtype=torch.float64)
    wcos = torch.rand(5, 7, dtype=torch.float64)

    def f(x):
        s, c = sin_cos(x)
        if which == "sin":
            return (s * wsin).sum()
        if which == "cos":
            return (c * wcos).sum()
        return (s * wsin).sum() + (c * wcos * s).sum()

    assert torch.autograd.gradcheck(f, (a,))
    assert torch.autograd.gradgradcheck(f, (a,))


def test_sin_cos_values_and_no_graph():
    from neural_bake.nets.gemm import sin_cos

    a = torch.linspace(-50, 50, 1001, dtype=torch.float32)
    s, c = sin_cos(a)
    # the fused kernel (nets/fastmath.py) where built: within 2e-7 of float64 sin/cos, as torch.sin is within 4e-8
    torch.testing.assert_close(s.double(), torch.sin(a.double()), rtol=0, atol=2e-7)
    torch.testing.assert_close(c.double(), torch.cos(a.double()), rtol=0, atol=2e-7)
    assert s.grad_fn is None  # no node for tensors that do not require grad
    s2, c2 = sin_cos(a.clone().requires_grad_(True))
    assert torch.equal(s2.detach(), s) and torch.equal(c2.detach(), c)
    assert s2.grad_fn is not None and c2.grad_fn is s2.grad_fn  # one node for both


# --- _ReverseScalar: the hand-written backward of the scalar reverse path ---------------------------------


def _graph_grads(model, x, which, graph):
    """Gradients of a loss on (values, ∇f) w.r.t. the parameters (and x) through ``graph`` (one of the two
    reverse-mode graph builders); ``which`` picks the terms the loss uses."""
    layers = model.affine_layers(dtype=x.dtype)
    values, grads = graph(layers, x)
    g = grads[:, 0]
    loss = x.new_zeros(())
    if which in ("values", "both"):
        loss = loss + (values[:, 0] ** 2 * torch.linspace(0.5, 2.0, x.shape[0], dtype=x.dtype)).sum()
    if which in ("grads", "both"):
        loss = loss + ((g.norm(dim=1) - 1) ** 2).sum() + (g * torch.tensor([0.3, -1.0, 2.0], dtype=x.dtype)).sum()
    inputs = list(model.parameters()) + ([x] if x.requires_grad else [])
    return torch.autograd.grad(loss, inputs, allow_unused=True)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("depth", [0, 1, 3])
@pytest.mark.parametrize("which", ["values", "grads", "both"])
@pytest.mark.parametrize("points_grad", [False, True])
def test_fused_backward_matches_the_autograd_graph(dtype, depth, which, points_grad):
    """The hand-written backward against torch's autograd through the same formulas, including losses that
    use only the values or only ∇f, depth 0 (the output row folded into W_0), and gradients to the points."""
    from neural_bake.nets.gemm import _reverse_graph, _reverse_graph_autograd

    model = _model(24, depth, 3, 1, 30.0, dtype, seed=5)
    x = _points(50, 3, dtype, seed=2).requires_grad_(points_grad)
    ours = _graph_grads(model, x, which, _reverse_graph)
    ref = _graph_grads(model, x, which, _reverse_graph_autograd)
    assert len(ours) == len(ref) == len(list(model.parameters())) + points_grad
    for a, b in zip(ours, ref):
        if b is None:  # e.g. the output bias with a loss on ∇f alone: ours gives zeros
            assert a is None or not a.any()
            continue
        _assert_rel(a, b, 2e-5 if dtype == torch.float32 else 1e-12)


def test_fused_backward_is_the_scalar_path_and_differentiable_once():
    from neural_bake.nets.gemm import _ReverseScalar

    model = _model(8, 2, 3, 1, 30.0, torch.float64)
    x = _points(10, 3, torch.float64)
    values, grads = gemm_gradient(model, x, differentiable=True)
    assert type(grads.grad_fn).__name__ == "ViewBackward0"  # the reshape of the node's (N, 1, 3) view
    assert isinstance(values.grad_fn, _ReverseScalar._backward_cls)
    loss = (grads ** 2).sum()
    (gw,) = torch.autograd.grad(loss, [model.layers[0].weight], create_graph=True)
    with pytest.raises(RuntimeError, match="once_differentiable"):
        gw.sum().backward()


@pytest.mark.parametrize("omega", [1.0, 30.0, 3000.0])
def test_fused_backward_finite_at_large_omega_and_zero_gradient(omega):
    """Large ω0 (pre-activations of thousands) and a field whose gradient vanishes (zero first-layer
    weights): the weights' gradients stay finite and match the autograd graph."""
    from neural_bake.nets.gemm import _reverse_graph, _reverse_graph_autograd

    model = _model(16, 2, 3, 1, omega, torch.float64, seed=7)
    x = _points(30, 3, torch.float64)
    for zero in (False, True):
        if zero:
            with torch.no_grad():
                model.layers[0].weight.zero_()
        ours = _graph_grads(model, x, "both", _reverse_graph)
        ref = _graph_grads(model, x, "both", _reverse_graph_autograd)
        for a, b in zip(ours, ref):
            assert torch.isfinite(a).all()
            _assert_rel(a, b, 1e-11)
