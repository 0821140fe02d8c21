"""fix_last_input: the slice f(·, τ) of a space-time Siren is the 4-D network at τ, values and gradients."""

import pytest
import torch

from neural_bake.errors import NeuralBakeError
from neural_bake.nets.gemm import gemm_gradient
from neural_bake.nets.siren import Siren
from neural_bake.nets.timeslice import fix_last_input


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("width,depth", [(16, 0), (32, 2)])
def test_slice_is_the_network_at_the_fixed_input(dtype, width, depth):
    gen = torch.Generator().manual_seed(3)
    model = Siren(width, depth, in_dim=4, generator=gen).to(dtype)
    x = torch.rand(500, 3, generator=gen, dtype=dtype) * 2 - 1
    for tau in (-1.0, 0.37, 1.0):
        s = fix_last_input(model, tau)
        assert s.in_dim == 3 and s.width == width and s.depth == depth and s.layers[0].weight.dtype == dtype
        full = torch.cat([x, torch.full((500, 1), tau, dtype=dtype)], 1)
        tol = 1e-12 if dtype == torch.float64 else 2e-5
        torch.testing.assert_close(s(x), model(full), atol=tol, rtol=0)
        v3, g3 = gemm_gradient(s, x)
        v4, g4 = gemm_gradient(model, full)
        torch.testing.assert_close(v3, v4, atol=tol, rtol=0)
        torch.testing.assert_close(g3, g4[:, :3], atol=tol * 100, rtol=0)


def test_slice_owns_its_parameters():
    model = Siren(8, 1, in_dim=4)
    s = fix_last_input(model, 0.5)
    assert not any(p.requires_grad for p in s.parameters())
    before = model.layers[1].weight.detach().clone()
    with torch.no_grad():
        s.layers[1].weight.add_(1.0)
    torch.testing.assert_close(model.layers[1].weight.detach(), before)


def test_errors():
    with pytest.raises(NeuralBakeError, match="a slice needs at least 2"):
        fix_last_input(Siren(8, 1, in_dim=1), 0.0)
    with pytest.raises(NeuralBakeError, match="value must be a finite number"):
        fix_last_input(Siren(8, 1, in_dim=4), float("inf"))
