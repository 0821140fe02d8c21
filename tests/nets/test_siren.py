"""Siren: shapes, initialisation, the inference fast path against the autograd path."""

import math

import pytest
import torch

from neural_bake.errors import NeuralBakeError
from neural_bake.nets.siren import Siren, siren_forward_inference


def _reference_forward(model, x):
    """The papers' form, ω kept apart: sin(ω_i (W_i h + b_i)), linear output."""
    h = x
    for layer, w in zip(model.layers[:-1], model.omegas[:-1]):
        h = torch.sin(w * (h @ layer.weight.t() + layer.bias))
    return h @ model.layers[-1].weight.t() + model.layers[-1].bias


@pytest.mark.parametrize("width,depth", [(64, 1), (256, 3), (8, 0)])
def test_architecture_and_shapes(width, depth):
    m = Siren(width, depth)
    assert len(m.layers) == depth + 2
    assert [layer.weight.shape for layer in m.layers[1:-1]] == [(width, width)] * depth
    assert m.architecture == {"width": width, "depth": depth, "in_dim": 3, "out_dim": 1,
                              "omega_0": 30.0, "hidden_omega": 30.0}
    assert m(torch.zeros(5, 3)).shape == (5, 1)
    assert Siren(16, 1, in_dim=4, out_dim=3)(torch.zeros(2, 4)).shape == (2, 3)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fast_path_matches_graph_path_and_reference(dtype):
    m = Siren(32, 2, out_dim=3, generator=torch.Generator().manual_seed(0)).to(dtype)
    x = torch.rand(300, 3, dtype=dtype) * 2 - 1
    y_graph = m(x)  # parameters require grad: graph path
    assert y_graph.requires_grad
    with torch.no_grad():
        y_fast = m(x)
    assert not y_fast.requires_grad
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(y_fast, y_graph.detach(), rtol=tol, atol=tol)
    torch.testing.assert_close(y_fast, _reference_forward(m, x).detach(), rtol=tol, atol=tol)
    layers = [(w.detach(), b.detach()) for w, b in m.affine_layers()]
    with torch.no_grad():
        for chunk in (1, 7, 1000):
            torch.testing.assert_close(siren_forward_inference(layers, x, chunk), y_fast, rtol=tol, atol=tol)
        assert siren_forward_inference(layers, x[:0]).shape == (0, 3)


def test_batched_leading_dims_and_dtype_follow_input():
    m = Siren(8, 1)
    x = torch.rand(2, 5, 3)
    with torch.no_grad():
        assert m(x).shape == (2, 5, 1)
        y64 = m(x[0].double())
    assert y64.dtype == torch.float64


def test_initialisation_keeps_preactivations_unit_scale():
    m = Siren(256, 3, generator=torch.Generator().manual_seed(0))
    x = torch.rand(4096, 3) * 2 - 1
    with torch.no_grad():
        h = x
        for w, b in m.affine_layers()[:-1]:
            a = h @ w.t() + b
            if h is not x:  # hidden layers: ~ arcsine-distributed input, pre-activation std ~ 1
                assert 0.5 < a.std().item() < 2.0
            h = torch.sin(a)
    g1 = Siren(16, 1, generator=torch.Generator().manual_seed(5))
    g2 = Siren(16, 1, generator=torch.Generator().manual_seed(5))
    assert all(torch.equal(a, b) for a, b in zip(g1.parameters(), g2.parameters()))


def test_affine_layers_fold_omega_and_convert_before_folding():
    m = Siren(4, 1, omega_0=30.0, hidden_omega=10.0)
    (w0, b0), (w1, _), (w2, b2) = m.affine_layers()
    assert torch.equal(w0, m.layers[0].weight * 30.0) and torch.equal(w1, m.layers[1].weight * 10.0)
    assert torch.equal(w2, m.layers[2].weight) and torch.equal(b2, m.layers[2].bias)
    (w0d, _), *_ = m.affine_layers(dtype=torch.float64)
    assert w0d.dtype == torch.float64 and torch.equal(w0d, m.layers[0].weight.double() * 30.0)


def test_bad_arguments():
    with pytest.raises(NeuralBakeError, match="Siren: width must be a positive integer, got 0"):
        Siren(0, 1)
    with pytest.raises(NeuralBakeError, match="Siren: depth must be a non-negative integer, got -1"):
        Siren(8, -1)
    with pytest.raises(NeuralBakeError, match="Siren: omega_0 and hidden_omega must be positive"):
        Siren(8, 1, omega_0=math.nan)
    with pytest.raises(NeuralBakeError, match=r"Siren: expected points of shape \(N, 3\), got \(5, 2\)"):
        Siren(8, 1)(torch.zeros(5, 2))


def test_works_inside_torch_func_transforms():
    m = Siren(8, 1, generator=torch.Generator().manual_seed(2))
    x = torch.rand(2, 5, 3)
    with torch.no_grad():
        expected = m(x.reshape(10, 3)).reshape(2, 5, 1)
        torch.testing.assert_close(torch.func.vmap(m)(x), expected)
    m.requires_grad_(False)
    jac = torch.func.vmap(torch.func.jacrev(lambda p: m(p[None])[0]))(x[0])
    xr = x[0].clone().requires_grad_(True)
    (ref,) = torch.autograd.grad(m(xr).sum(), xr)
    torch.testing.assert_close(jac[:, 0], ref)
