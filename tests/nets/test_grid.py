"""The multiresolution feature-grid network against a slow reference: values (float32 and float64, dense and hashed
levels, points on and outside the cube's faces), input derivatives against finite differences and autograd,
devices and dtypes, and its one-line setting errors."""

from __future__ import annotations

import math

import pytest
import torch

from neural_bake.errors import NeuralBakeError
from neural_bake.nets.grid import GridNet, check_grid_settings, grid_resolutions, grid_table_sizes

PRIMES = (1, 2654435761, 805459861)


def small(**kw) -> GridNet:
    """A grid whose coarse levels are dense and fine ones hashed (2^9 entries), features far from zero."""
    args = dict(levels=4, features=2, log2_table=9, base_resolution=3, max_resolution=40, width=8, depth=1)
    args.update(kw)
    net = GridNet(**args, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        net.table.normal_(generator=torch.Generator().manual_seed(2))
    return net


def reference(net: GridNet, points: torch.Tensor) -> torch.Tensor:
    """The network's values computed point by point, vertex by vertex, in float64 Python arithmetic."""
    table = net.table.detach().double()
    offsets = [sum(net.sizes[:level]) for level in range(net.levels)]
    out = []
    for row in points.double().tolist():
        p, normal = row[:3], row[3:]  # with normal inputs: the point, then its normal
        feats = []
        for level, (res, size) in enumerate(zip(net.resolutions, net.sizes)):
            u = [(min(max(c, -1.0), 1.0) + 1.0) / 2.0 * res for c in p]
            cell = [min(math.floor(c), res - 1) for c in u]
            frac = [c - k for c, k in zip(u, cell)]
            acc = torch.zeros(net.features, dtype=torch.float64)
            for corner in range(8):
                bits = [(corner >> k) & 1 for k in range(3)]
                v = [k + b for k, b in zip(cell, bits)]
                if (res + 1) ** 3 <= size:
                    index = v[0] + (res + 1) * (v[1] + (res + 1) * v[2])
                else:
                    index = ((v[0] * PRIMES[0]) ^ (v[1] * PRIMES[1]) ^ (v[2] * PRIMES[2])) % size
                w = math.prod(f if b else 1.0 - f for f, b in zip(frac, bits))
                acc += w * table[offsets[level] + index]
            feats.append(acc)
        h = torch.cat(feats)
        if net.normal_scale is not None:
            h = torch.cat([h, net.normal_scale * torch.tensor(normal, dtype=torch.float64)])
        for i, layer in enumerate(net.layers):
            h = layer.weight.detach().double() @ h + layer.bias.detach().double()
            if i < len(net.layers) - 1:
                h = torch.relu(h) if net.activation == "relu" else torch.sin(net.omega * h)
        out.append(h)
    return torch.stack(out)


def points(n: int, seed: int, dtype=torch.float64) -> torch.Tensor:
    """Random points of [-1.1, 1.1]³ (some outside the cube) and points on its faces, edges and corners."""
    x = torch.rand(n, 3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64) * 2.2 - 1.1
    edges = torch.tensor([[1.0, 1.0, 1.0], [-1.0, -1.0, -1.0], [1.0, 0.3, -1.0], [0.0, 0.0, 0.0], [-1.0, 0.5, 0.25]],
                         dtype=torch.float64)
    return torch.cat([x, edges]).to(dtype)


def test_levels_resolutions_and_tables():
    assert grid_resolutions(1, 16, 512) == [16]
    r = grid_resolutions(16, 16, 1024)
    assert r[0] == 16 and r[-1] == 1024 and all(a < b for a, b in zip(r[:-1], r[1:]))
    assert grid_table_sizes([3, 7, 40], 9) == [64, 512, 512]
    net = small()
    assert net.sizes == grid_table_sizes(net.resolutions, 9)
    assert any((res + 1) ** 3 <= s for res, s in zip(net.resolutions, net.sizes))  # dense levels
    assert any((res + 1) ** 3 > s for res, s in zip(net.resolutions, net.sizes))  # hashed levels
    assert net.table.shape == (sum(net.sizes), 2)
    assert set(net.state_dict()) == {"table"} | {f"layers.{i}.{k}" for i in range(3) for k in ("weight", "bias")}
    assert net.architecture == {"network": "grid", "levels": 4, "features": 2, "log2_table": 9, "base_resolution": 3,
                                "max_resolution": 40, "width": 8, "depth": 1, "in_dim": 3, "out_dim": 3,
                                "activation": "relu", "omega": 1.0}


@pytest.mark.parametrize("activation", ["relu", "sine"])
@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 2e-5)])
def test_values_match_the_slow_reference(activation, dtype, tol):
    net = small(activation=activation, omega=3.0).to(dtype)
    x = points(60, seed=3, dtype=dtype)
    got = net(x)
    assert got.dtype == dtype and got.shape == (len(x), 3)
    want = reference(net, x)
    scale = want.abs().max().item()
    assert scale > 0.1
    torch.testing.assert_close(got.double(), want, rtol=0, atol=tol * max(1.0, scale))


def test_values_follow_the_input_dtype_and_are_continuous_across_cell_faces():
    net = small()
    x = points(20, seed=4, dtype=torch.float64)
    torch.testing.assert_close(net(x), net.double()(x), rtol=0, atol=0)  # float32 weights read in float64
    # across a face of a finest-level cell: x = 2 k / R - 1 ± ε
    res = net.resolutions[-1]
    face = 2 * 7 / res - 1
    a = torch.tensor([[face - 1e-9, 0.13, -0.42]], dtype=torch.float64)
    b = torch.tensor([[face + 1e-9, 0.13, -0.42]], dtype=torch.float64)
    assert (net(a) - net(b)).abs().max().item() < 1e-6


@pytest.mark.parametrize("activation", ["relu", "sine"])
def test_input_gradient_matches_finite_differences(activation):
    net = small(activation=activation, omega=2.0).double()
    x = points(40, seed=5)[:40] * 0.9  # inside the cube (the clamp's gradient is 0 outside)
    v = torch.randn(40, 3, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    xg = x.clone().requires_grad_(True)
    out = net(xg)
    jac = torch.stack([torch.autograd.grad(out[:, c].sum(), xg, retain_graph=True)[0] for c in range(3)], 1)
    eps = 1e-7
    fd = (net(x + eps * v) - net(x - eps * v)) / (2 * eps)
    autograd_jv = torch.einsum("noi,ni->no", jac, v)
    torch.testing.assert_close(autograd_jv, fd, rtol=1e-5, atol=1e-5 * fd.abs().max().item())
    values, jv = net.directional(x, v)
    torch.testing.assert_close(values, net(x), rtol=0, atol=1e-12)
    torch.testing.assert_close(jv, autograd_jv, rtol=1e-10, atol=1e-10)


def test_directional_derivative_is_zero_across_the_clamp_and_trains_the_parameters():
    net = small()
    outside = torch.tensor([[1.5, 0.2, 0.1]])
    _, jv = net.directional(outside, torch.tensor([[1.0, 0.0, 0.0]]))
    assert jv.abs().max().item() == 0.0
    x = points(30, seed=7, dtype=torch.float32) * 0.9
    _, jv = net.directional(x, torch.nn.functional.normalize(torch.randn(len(x), 3), dim=1))
    (jv ** 2).sum().backward()
    assert net.table.grad is not None and net.table.grad.abs().sum() > 0
    assert net.layers[0].weight.grad.abs().sum() > 0


def test_device_and_generator():
    a = GridNet(levels=2, log2_table=6, base_resolution=2, max_resolution=8, generator=torch.Generator().manual_seed(0))
    b = GridNet(levels=2, log2_table=6, base_resolution=2, max_resolution=8, generator=torch.Generator().manual_seed(0))
    assert all(torch.equal(p, q) for p, q in zip(a.state_dict().values(), b.state_dict().values()))
    assert a.table.abs().max().item() <= 1e-4
    x = torch.zeros(4, 3, device="meta")
    assert a.to("meta")(x).device.type == "meta"


@pytest.mark.parametrize("kw,message", [
    ({"levels": 0}, r"^levels: must be an integer in 1\.\.32, got 0$"),
    ({"features": 1.5}, r"^features: must be an integer in 1\.\.16, got 1\.5$"),
    ({"log2_table": 30}, r"^log2_table: must be an integer in 4\.\.24, got 30$"),
    ({"base_resolution": 64, "max_resolution": 32}, r"^base_resolution: must be an integer in 1\.\.32, got 64$"),
    ({"max_resolution": float("inf")}, r"^max_resolution: must be an integer in 1\.\.65536, got inf$"),
    ({"activation": "tanh"}, r"^activation: must be one of relu, sine, got 'tanh'$"),
    ({"width": 0}, r"^width: must be an integer in 1\.\.4096, got 0$"),
    ({"depth": -1}, r"^depth: must be an integer in 0\.\.32, got -1$"),
    ({"omega": 0.0}, r"^omega: must be a positive number, got 0\.0$"),
    ({"in_dim": 4}, r"^GridNet: in_dim must be 3"),
])
def test_bad_settings_are_one_line_errors_naming_the_parameter(kw, message):
    with pytest.raises(NeuralBakeError, match=message) as err:
        GridNet(**kw)
    assert "\n" not in str(err.value)
    assert err.value.parameter == message.split(":")[0].lstrip("^").replace("GridNet", "in_dim")


def test_prefix_and_error_class():
    from neural_bake.errors import FitError

    with pytest.raises(FitError, match=r"^grid_levels: must be an integer") as err:
        check_grid_settings(levels=99, features=2, log2_table=10, base_resolution=4, max_resolution=8,
                            activation="relu", error=FitError, prefix="grid_")
    assert err.value.parameter == "grid_levels"


def test_bad_points_shape():
    with pytest.raises(NeuralBakeError, match=r"GridNet: expected points of shape \(N, 3\), got \(5, 2\)"):
        small()(torch.zeros(5, 2))
    with pytest.raises(NeuralBakeError, match=r"GridNet: expected points and surface normals of shape \(N, 6\), "
                                              r"got \(5, 3\)"):
        small(in_dim=6)(torch.zeros(5, 3))


def with_normals(x: torch.Tensor, seed: int) -> torch.Tensor:
    """Points (N, 3) and random unit normals beside them: (N, 6)."""
    n = torch.nn.functional.normalize(torch.randn(len(x), 3, generator=torch.Generator().manual_seed(seed),
                                                  dtype=torch.float64), dim=1)
    return torch.cat([x, n.to(x.dtype)], dim=1)


@pytest.mark.parametrize("activation", ["relu", "sine"])
@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 2e-5)])
def test_normal_inputs_match_the_slow_reference(activation, dtype, tol):
    net = small(activation=activation, omega=3.0, in_dim=6, normal_scale=0.5).to(dtype)
    x = with_normals(points(60, seed=3, dtype=dtype), seed=4)
    assert net.normal_inputs and net.architecture["normal_scale"] == 0.5 and net.layers[0].in_features == 8 + 3
    want = reference(net, x)
    torch.testing.assert_close(net(x).double(), want, rtol=0, atol=tol * max(1.0, want.abs().max().item()))
    flipped = x.clone()
    flipped[:, 3:] *= -1
    assert (net(flipped) - net(x)).abs().max().item() > 1e-3  # the two sides of a surface differ
    assert GridNet(in_dim=6, log2_table=8, max_resolution=32).normal_scale == 0.2  # the default scale


def test_normal_inputs_directional_derivative_holds_the_normal_fixed():
    net = small(activation="sine", omega=2.0, in_dim=6).double()
    x = with_normals(points(40, seed=5)[:40] * 0.9, seed=8)
    v = torch.randn(40, 3, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    eps = 1e-7
    step = torch.cat([eps * v, torch.zeros_like(v)], dim=1)  # the point moves, its normal does not
    fd = (net(x + step) - net(x - step)) / (2 * eps)
    values, jv = net.directional(x, v)
    torch.testing.assert_close(values, net(x), rtol=0, atol=1e-12)
    torch.testing.assert_close(jv, fd, rtol=1e-5, atol=1e-5 * fd.abs().max().item())


@pytest.mark.parametrize("kw,message", [
    ({"in_dim": 3, "normal_scale": 0.2}, r"^GridNet: normal_scale needs in_dim 6 \(normal inputs\)$"),
    ({"in_dim": 6, "normal_scale": 0.0}, r"^GridNet: normal_scale must be a number in \(0, 100\], got 0\.0$"),
    ({"in_dim": 6, "normal_scale": float("nan")}, r"^GridNet: normal_scale must be a number in \(0, 100\], got nan$"),
    ({"in_dim": True}, r"^GridNet: in_dim must be 3 \(points of the unit frame\) or 6"),
])
def test_bad_normal_inputs_are_one_line_errors(kw, message):
    with pytest.raises(NeuralBakeError, match=message) as err:
        GridNet(**kw)
    assert "\n" not in str(err.value) and err.value.parameter == ("in_dim" if "in_dim must" in message else
                                                                  "normal_scale")


# ------------------------------------------------------------------------------------------- the C kernel
def _needs_kernel():
    from neural_bake.nets import grid

    if grid.KERNEL.lib() is None:
        pytest.skip(f"the grid's C kernel does not run here: {grid.kernel_status()}")


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-15), (torch.float32, 5e-7)])
@pytest.mark.parametrize("features", [1, 2, 3])
def test_kernel_encoding_and_table_gradient_match_torch(dtype, tol, features):
    """The C kernel's features and its gradient with respect to the table equal torch's, on points inside and
    outside the cube, on its faces and corners, at dense and hashed levels, in float32 and float64."""
    _needs_kernel()
    net = small(features=features).to(dtype)
    x = points(400, seed=5, dtype=dtype)
    got = net.encode(x)
    want = net._encode_torch(x)
    assert got.dtype == dtype and got.shape == want.shape == (len(x), net.levels * features)
    torch.testing.assert_close(got, want, rtol=0, atol=tol * want.abs().max().item())
    g = torch.randn(got.shape, generator=torch.Generator().manual_seed(6), dtype=dtype)
    net.zero_grad()
    (net.encode(x) * g).sum().backward()
    native = net.table.grad.clone()
    net.zero_grad()
    (net._encode_torch(x) * g).sum().backward()
    assert native.abs().max() > 0.1
    torch.testing.assert_close(native, net.table.grad, rtol=0, atol=4 * tol * net.table.grad.abs().max().item())


def test_kernel_gives_the_same_bits_on_any_thread_count():
    _needs_kernel()
    net = small(log2_table=10, max_resolution=200)
    x = points(5000, seed=7, dtype=torch.float32)
    g = torch.randn(len(x), net.levels * net.features, generator=torch.Generator().manual_seed(8))
    before = torch.get_num_threads()
    out = {}
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            net.zero_grad()
            f = net.encode(x)
            (f * g).sum().backward()
            out[n] = (f.detach().clone(), net.table.grad.clone())
    finally:
        torch.set_num_threads(before)
    assert torch.equal(out[1][0], out[2][0]) and torch.equal(out[1][1], out[2][1])


def test_points_that_need_a_gradient_and_a_switched_off_kernel_take_torch(monkeypatch):
    """Points with requires_grad are encoded in torch (the kernel has no gradient for them); with the switch off
    the status says torch runs and the values are torch's."""
    from neural_bake.nets import grid
    from neural_bake.nets.native import Kernel

    net = small()
    x = points(50, seed=9).requires_grad_(True)
    net.encode(x).sum().backward()
    assert x.grad is not None and x.grad.abs().max() > 0
    monkeypatch.setenv(grid.ENV_SWITCH, "0")
    monkeypatch.setattr(grid, "KERNEL", Kernel(grid.KERNEL.source, switch=grid.ENV_SWITCH, declare=grid._declare,
                                               openmp=True))
    assert grid.kernel_status().startswith("torch (off")
    y = points(50, seed=9)
    assert not net._native(y)
    torch.testing.assert_close(net(y), reference(net, y), rtol=0, atol=1e-12)


def test_kernel_gives_nan_features_for_nan_points_and_clamps_infinite_ones():
    _needs_kernel()
    net = small()
    x = torch.tensor([[float("nan"), 0.0, 0.0], [float("inf"), -float("inf"), 0.5], [1.0, -1.0, 0.5]],
                     dtype=torch.float64)
    f = net.encode(x)
    assert torch.isnan(f[0]).all() and torch.isfinite(f[1:]).all()
    torch.testing.assert_close(f[1], f[2], rtol=0, atol=0)
