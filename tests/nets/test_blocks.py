"""neural_bake.nets.blocks: the independent hidden blocks of a SIREN (a residual SDF kept as one network) found
from its matrices, and the no-grad paths that run them block by block, against autograd of the merged network
in float32 and float64."""

import pytest
import torch

from neural_bake.nets.blocks import MIN_BLOCK, hidden_blocks, split_layers
from neural_bake.nets.gemm import gemm_gradient
from neural_bake.nets.siren import Siren, siren_forward_inference
from neural_bake.nets.siren_sum import siren_sum


def random_siren(width, depth, omega_0=30.0, seed=0, dtype=torch.float32):
    return Siren(width, depth, omega_0=omega_0, generator=torch.Generator().manual_seed(seed)).to(dtype)


def test_blocks_of_sums_and_of_plain_networks():
    assert hidden_blocks(siren_sum(random_siren(32, 3, seed=0), random_siren(64, 3, seed=1)).affine_layers()) \
        == [(0, 32), (32, 96)]
    three = siren_sum(siren_sum(random_siren(32, 2, seed=0), random_siren(32, 2, seed=1)), random_siren(32, 2, seed=2))
    assert hidden_blocks(three.affine_layers()) == [(0, 32), (32, 64), (64, 96)]
    assert hidden_blocks(random_siren(96, 3).affine_layers()) == [(0, 96)]  # dense
    assert hidden_blocks(random_siren(96, 0).affine_layers()) == [(0, 96)]  # no hidden matrix
    # a block narrower than MIN_BLOCK joins its neighbour: nothing left to split
    small = siren_sum(random_siren(MIN_BLOCK // 2, 2, seed=0), random_siren(64, 2, seed=1))
    assert hidden_blocks(small.affine_layers()) == [(0, MIN_BLOCK // 2 + 64)]
    # one link between the blocks, in any hidden matrix, joins them
    linked = siren_sum(random_siren(32, 3, seed=0), random_siren(64, 3, seed=1))
    with torch.no_grad():
        linked.layers[2].weight[40, 5] = 0.01
    assert hidden_blocks(linked.affine_layers()) == [(0, 96)]


def test_split_layers_are_the_blocks_own_networks():
    h, r = random_siren(32, 2, 15.0, 0), random_siren(48, 2, 30.0, 1)
    layers = siren_sum(h, r).affine_layers()
    parts = split_layers(layers, hidden_blocks(layers))
    assert [p[0][0].shape[0] for p in parts] == [32, 48]
    assert all(w.is_contiguous() for p in parts for w, _ in p)
    torch.testing.assert_close(parts[1][-1][1], torch.zeros(1))  # the output bias once, in the first block
    assert split_layers(layers, [(0, 80)]) == [layers]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("mode", ["reverse", "forward"])
def test_block_by_block_agrees_with_autograd_of_the_merged_network(dtype, mode):
    h, r = random_siren(32, 3, 15.0, 0, dtype), random_siren(64, 3, 30.0, 1, dtype)
    merged = siren_sum(h, r).eval()
    x = (torch.rand(700, 3, generator=torch.Generator().manual_seed(2), dtype=dtype) * 2 - 1).requires_grad_(True)
    with torch.enable_grad():
        ref = merged(x)  # autograd's graph: the merged matrices, zeros and all
        (ref_grad,) = torch.autograd.grad(ref.sum(), x)
    tol = {"rtol": 1e-4, "atol": 1e-4} if dtype == torch.float32 else {"rtol": 1e-10, "atol": 1e-10}
    values, grads = gemm_gradient(merged, x.detach(), mode, chunk_size=128)  # several chunks per block
    torch.testing.assert_close(values, ref.detach(), **tol)
    torch.testing.assert_close(grads, ref_grad, **tol)
    with torch.no_grad():
        forward = siren_forward_inference(merged.affine_layers(dtype=dtype), x.detach(), chunk_size=100)
    torch.testing.assert_close(forward, ref.detach(), **tol)
    torch.testing.assert_close(merged(x.detach()), ref.detach(), **tol)  # Siren.forward without a graph


def test_vector_outputs_and_reduced_precision_split_too():
    h = Siren(32, 2, out_dim=3, generator=torch.Generator().manual_seed(0))
    r = Siren(64, 2, out_dim=3, generator=torch.Generator().manual_seed(1))
    merged = siren_sum(h, r)
    x = torch.rand(300, 3, generator=torch.Generator().manual_seed(2)) * 2 - 1
    values, jac = gemm_gradient(merged, x)
    hv, hj = gemm_gradient(h, x)
    rv, rj = gemm_gradient(r, x)
    torch.testing.assert_close(values, hv + rv, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(jac, hj + rj, rtol=1e-5, atol=1e-5)
    assert jac.shape == (300, 3, 3)
    low_values, _ = gemm_gradient(merged, x, gemm_dtype=torch.bfloat16)
    torch.testing.assert_close(low_values, values, rtol=0.05, atol=0.05)
