"""neural_bake.nets.siren_sum: two SIRENs of one depth as one (block-diagonal), and their summed GEMM gradients,
against autograd of the sum in float32 and float64."""

import pytest
import torch

from neural_bake.errors import NeuralBakeError
from neural_bake.nets.gemm import gemm_gradient
from neural_bake.nets.siren import Siren
from neural_bake.nets.siren_sum import siren_sum, sum_gradient


def random_siren(width, depth, omega_0, seed, dtype=torch.float32):
    return Siren(width, depth, omega_0=omega_0, generator=torch.Generator().manual_seed(seed)).to(dtype)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_sum_normals_agree_with_autograd_of_the_sum(dtype):
    h, r = random_siren(16, 2, 15.0, 0, dtype), random_siren(24, 2, 45.0, 1, dtype)
    x = (torch.rand(300, 3, generator=torch.Generator().manual_seed(2), dtype=dtype) * 2 - 1).requires_grad_(True)
    values, grads = sum_gradient([h, r], x.detach())
    ref = h(x) + r(x)
    (ref_grad,) = torch.autograd.grad(ref.sum(), x)
    tol = {"rtol": 1e-4, "atol": 1e-4} if dtype == torch.float32 else {"rtol": 1e-10, "atol": 1e-10}
    torch.testing.assert_close(values, ref.detach(), **tol)
    torch.testing.assert_close(grads, ref_grad, **tol)
    # the sum as one SIREN (block-diagonal, the ω0 of r): the same values and GEMM normals
    merged = siren_sum(h, r)
    assert merged.width == 40 and merged.omega_0 == 45.0 and next(merged.parameters()).dtype == dtype
    m_values, m_grads = gemm_gradient(merged, x.detach())
    torch.testing.assert_close(m_values, ref.detach(), **tol)
    torch.testing.assert_close(m_grads, ref_grad, **tol)


def test_siren_sum_refuses_networks_of_different_depth():
    with pytest.raises(NeuralBakeError, match="differ in depth"):
        siren_sum(random_siren(16, 1, 30.0, 0), random_siren(16, 2, 30.0, 1))
    with pytest.raises(NeuralBakeError, match="no networks"):
        sum_gradient([], torch.zeros(1, 3))
