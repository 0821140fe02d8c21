"""SIREN weights of the reference implementations, imported: the field file computes the reference network's
values and gradients (GEMM normals against autograd), in float32 and float64, for every recognised layout."""

import math

import numpy as np
import pytest
import torch
from torch import nn

from neural_bake.errors import ModelFileError, NeuralBakeError
from neural_bake.fields import SdfField, load_field
from neural_bake.fields.imported import (import_siren, raw_siren_size, read_raw_siren, read_siren_state,
                                         siren_from_state_dict)
from neural_bake.types import Frame


class Sine(nn.Module):
    """sin(ω x): no parameters, as in the reference code."""

    def __init__(self, omega):
        super().__init__()
        self.omega = omega

    def forward(self, x):
        return torch.sin(self.omega * x)


class SineLayer(nn.Module):
    """The notebooks' sine layer: sin(ω (W x + b)) with the linear map as ``.linear``."""

    def __init__(self, a, b, omega):
        super().__init__()
        self.omega, self.linear = omega, nn.Linear(a, b)

    def forward(self, x):
        return torch.sin(self.omega * self.linear(x))


def _linears(width, depth, in_dim=3, out_dim=1):
    dims = [in_dim] + [width] * (depth + 1) + [out_dim]
    return [nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:])]


def reference(layout, width=16, depth=2, omega=30.0, hidden=30.0, seed=0, dtype=torch.float32):
    """A SIREN in one of the reference layouts, SIREN-initialised: its forward is sin(ω (W x + b)) on the hidden
    layers and a linear last layer."""
    torch.manual_seed(seed)
    lin = _linears(width, depth)
    with torch.no_grad():
        for i, layer in enumerate(lin):
            bound = 1 / layer.in_features if i == 0 else math.sqrt(6 / layer.in_features) / hidden
            layer.weight.uniform_(-bound, bound)
    omegas = [omega] + [hidden] * depth
    net = nn.Module()
    if layout == "Siren":
        layers = []
        for layer, w in zip(lin[:-1], omegas):
            s = SineLayer(layer.in_features, layer.out_features, w)
            s.linear = layer
            layers.append(s)
        net.net = nn.Sequential(*layers, lin[-1])
    else:
        body = nn.Sequential(*[nn.Sequential(layer, Sine(w)) for layer, w in zip(lin[:-1], omegas)],
                             nn.Sequential(lin[-1]))
        if layout == "SingleBVPNet":
            net.net = nn.Module()
            net.net.net = body
        else:
            net.net = body
    net.forward = lambda x: net.net(x) if layout != "SingleBVPNet" else net.net.net(x)
    return net.to(dtype)


def _reference_value_and_gradient(net, x):
    x = x.clone().requires_grad_(True)
    y = net.forward(x)[:, 0]
    (g,) = torch.autograd.grad(y.sum(), x)
    return y.detach(), g


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("layout,omega,hidden", [("SingleBVPNet", 30.0, 30.0), ("FCBlock", 20.0, 30.0),
                                                 ("Siren", 15.0, 25.0)])
def test_imported_field_computes_the_reference_network(tmp_path, layout, omega, hidden, dtype):
    net = reference(layout, omega=omega, hidden=hidden, dtype=dtype)
    state = net.state_dict()
    if layout == "FCBlock":  # a DataParallel save: every key under module.
        state = {"module." + k: v for k, v in state.items()}
    torch.save(state, tmp_path / "w.pth")
    frame = Frame((0.5, -1.0, 2.0), 0.25)
    import_siren(tmp_path / "w.pth", tmp_path / "w.sdf", omega_0=omega, hidden_omega=None if omega == hidden
                 else hidden, frame=frame)
    field = load_field(tmp_path / "w.sdf")
    assert isinstance(field, SdfField) and field.frame == frame and field.delta is None
    assert field.model.architecture == {"width": 16, "depth": 2, "in_dim": 3, "out_dim": 1, "omega_0": omega,
                                        "hidden_omega": hidden}
    assert next(field.model.parameters()).dtype == dtype  # float64 weights stay float64
    assert field.metadata["imported_from"] == {"file": "w.pth", "format": "torch state dict", "layout": layout}
    x = torch.rand(500, 3, generator=torch.Generator().manual_seed(3), dtype=dtype) * 2.4 - 1.2
    ref_v, ref_g = _reference_value_and_gradient(net, x)
    values, grads = field.value_and_gradient(x)
    assert values.dtype == dtype and grads.dtype == dtype
    tol = 1e-12 if dtype == torch.float64 else 2e-5
    scale = max(1.0, float(ref_g.abs().max()))  # gradients of an ω-30 network can be large: relative to them
    assert torch.allclose(values, ref_v, rtol=0, atol=tol * 10)
    assert torch.allclose(grads, ref_g, rtol=0, atol=tol * scale * 10)
    assert torch.allclose(field.value(x), ref_v, rtol=0, atol=tol * 10)


def test_half_precision_weights_are_widened_and_the_layout_reported(tmp_path):
    net = reference("Siren", width=8, depth=0)
    state = {k: v.half() for k, v in net.state_dict().items()}
    model, layout = siren_from_state_dict(state, "w.pth", omega_0=30)
    assert layout == "Siren" and (model.width, model.depth) == (8, 0)
    assert next(model.parameters()).dtype == torch.float32
    assert torch.equal(model.layers[1].weight, state["net.1.weight"].float())


def test_raw_float32_file_in_the_stated_order(tmp_path):
    net = reference("FCBlock", width=8, depth=1, omega=30.0, hidden=20.0)
    lin = [m[0] for m in net.net]
    flat = np.concatenate([np.concatenate([m.weight.detach().numpy().ravel(), m.bias.detach().numpy()])
                           for m in lin]).astype("<f4")
    assert flat.nbytes == raw_siren_size(8, 1)
    flat.tofile(tmp_path / "w.bin")
    import_siren(tmp_path / "w.bin", tmp_path / "w.sdf", omega_0=30.0, hidden_omega=20.0, raw=(8, 1))
    field = load_field(tmp_path / "w.sdf")
    assert field.frame == Frame() and field.metadata["imported_from"]["format"] == "raw float32"
    x = torch.rand(300, 3, generator=torch.Generator().manual_seed(4)) * 2 - 1
    ref_v, ref_g = _reference_value_and_gradient(net, x)
    values, grads = field.value_and_gradient(x)
    assert torch.allclose(values, ref_v, atol=2e-5) and torch.allclose(grads, ref_g, atol=2e-5 * float(ref_g.abs().max()))
    model = read_raw_siren(tmp_path / "w.bin", width=8, depth=1, omega_0=30.0, hidden_omega=20.0)
    assert torch.equal(model.layers[0].weight, lin[0].weight) and torch.equal(model.layers[2].bias, lin[2].bias)


def _state(layout="SingleBVPNet", **kw):
    return dict(reference(layout, width=8, depth=1, **kw).state_dict())


def _pe_state():
    s = _state()
    s["positional_encoding.freq_bands"] = torch.ones(4)
    return s


def _renamed(old, new):
    def make():
        s = _state()
        s[new] = s.pop(old)
        return s
    return make


def _changed(key, value):
    def make():
        s = _state()
        s[key] = value(s[key])
        return s
    return make


def _other_input(n):
    def make():
        s = _state()
        s["net.net.0.0.weight"] = torch.zeros(8, n)
        return s
    return make


BAD_STATES = [
    (lambda: [1, 2], "holds a list, not a state dict"),
    (lambda: {}, "an empty state dict"),
    (lambda: {**_state(), "net.net.0.1.weight": torch.zeros(3)}, "unknown keys net.net.0.1.weight; not a plain SIREN"),
    (lambda: {**_state(), "epoch": 3}, "unknown keys epoch"),
    (lambda: {**_state(), "module.net.net.1.0.bias": torch.zeros(8)}, "both net.net.1.0.bias and module.net.net.1.0.bias"),
    (_pe_state, "positional_encoding.freq_bands looks like a positional encoding"),
    (lambda: {**_state(), **{"net.0.0.weight": torch.zeros(8, 3)}}, "keys of different SIREN layouts mixed"),
    (lambda: {k: v for k, v in _state().items() if not k.startswith("net.net.1.")}, "layer 1 is missing"),
    (lambda: {k: v for k, v in _state().items() if k != "net.net.2.0.bias"}, "layer 2 has no bias"),
    (_changed("net.net.1.0.weight", lambda t: t.to(torch.int32)), "net.net.1.0.weight has dtype torch.int32"),
    (_changed("net.net.1.0.bias", lambda t: t.tolist()), "net.net.1.0.bias is a list, not a tensor"),
    (_changed("net.net.1.0.bias", lambda t: t[:4]), "layer 1 has weight (8, 8) and bias (4,)"),
    (_changed("net.net.2.0.weight", lambda t: torch.zeros(1, 5)), "shapes do not chain: layer 2 takes 5 inputs"),
    (_changed("net.net.1.0.weight", lambda t: torch.full_like(t, float("nan"))), "net.net.1.0.weight holds NaN"),
    (_other_input(4), "a network of 4 inputs (a space-time SDF?)"),
    (_other_input(39), "a network of 39 inputs (a positional encoding?)"),
    (lambda: {**_state(), "net.net.2.0.weight": torch.zeros(3, 8), "net.net.2.0.bias": torch.zeros(3)},
     "a network of 3 outputs; an SDF has one"),
    (lambda: {f"net.net.{i}.0.{p}": torch.zeros(*s) for i, (w, b) in enumerate([((8, 3), (8,)), ((6, 8), (6,)),
                                                                                ((1, 6), (1,))])
              for p, s in (("weight", w), ("bias", b))}, "hidden layers of unequal widths [6, 8]"),
    (lambda: {k.replace("net.2.", "net.2.linear."): v for k, v in _state("Siren").items()},
     "the output layer net.2.linear is a sine layer (outermost_linear=False)"),
    (lambda: {k.replace("net.0.linear.", "net.0."): v for k, v in _state("Siren").items()},
     "net.0.weight is a linear layer before the output layer"),
    (lambda: {"net.net.0.0.weight": torch.zeros(1, 3), "net.net.0.0.bias": torch.zeros(1)}, "a single layer"),
]


@pytest.mark.parametrize("make,message", BAD_STATES)
def test_anything_but_a_plain_siren_is_one_line(make, message):
    with pytest.raises(ModelFileError) as err:
        siren_from_state_dict(make(), "w.pth", omega_0=30)
    text = str(err.value)
    assert text.startswith("w.pth: ") and message in text and "\n" not in text, text


def test_omegas_are_checked():
    for kw, name in (({"omega_0": 0}, "omega_0"), ({"omega_0": 30, "hidden_omega": float("nan")}, "hidden_omega")):
        with pytest.raises(NeuralBakeError, match=f"^{name} = ") as err:
            siren_from_state_dict(_state(), "w.pth", **kw)
        assert err.value.parameter == name


def test_files_that_are_no_state_dict(tmp_path):
    torch.save(SineLayer(3, 1, 30.0), tmp_path / "whole.pt")  # a whole module pickled, not its state dict
    with pytest.raises(ModelFileError, match=r"whole.pt: holds pickled Python objects \(.*SineLayer\) that weights-only "
                                             r"loading refuses; save the network's state_dict\(\)$"):
        read_siren_state(tmp_path / "whole.pt", omega_0=30)
    (tmp_path / "junk.pt").write_bytes(b"not a torch file")
    (tmp_path / "empty.pt").write_bytes(b"")
    data = (tmp_path / "whole.pt").read_bytes()
    (tmp_path / "cut.pt").write_bytes(data[: len(data) // 2])
    for name in ("junk.pt", "empty.pt", "cut.pt"):
        with pytest.raises(ModelFileError, match=f"{name}: not a PyTorch file saved with torch.save"):
            read_siren_state(tmp_path / name, omega_0=30)
    with pytest.raises(ModelFileError, match="none.pt: no such weights file"):
        read_siren_state(tmp_path / "none.pt", omega_0=30)
    with pytest.raises(ModelFileError, match=": not a file"):
        read_siren_state(tmp_path, omega_0=30)


def test_raw_files_of_the_wrong_size_or_values(tmp_path):
    need = raw_siren_size(8, 1)
    assert need == 4 * (8 * 3 + 8 + 8 * 8 + 8 + 8 + 1)
    np.zeros(need // 4 + 1, "<f4").tofile(tmp_path / "long.bin")
    with pytest.raises(ModelFileError, match=rf"long.bin: {need + 4} bytes, a raw float32 8x1 SIREN of \(x, y, z\) "
                                             rf"-> f has {need} \({need // 4} values\)$"):
        read_raw_siren(tmp_path / "long.bin", width=8, depth=1, omega_0=30)
    bad = np.zeros(need // 4, "<f4")
    bad[7] = np.inf
    bad.tofile(tmp_path / "inf.bin")
    with pytest.raises(ModelFileError, match="inf.bin: holds NaN or infinite values"):
        read_raw_siren(tmp_path / "inf.bin", width=8, depth=1, omega_0=30)
    for kw, name in (({"width": 0, "depth": 1}, "width"), ({"width": 8, "depth": -1}, "depth"),
                     ({"width": 8, "depth": 1.5}, "depth")):
        with pytest.raises(NeuralBakeError, match=f"^{name} = ") as err:
            read_raw_siren(tmp_path / "inf.bin", omega_0=30, **kw)
        assert err.value.parameter == name


def test_import_refuses_other_kinds_and_missing_folders(tmp_path):
    torch.save(_state(), tmp_path / "w.pth")
    with pytest.raises(NeuralBakeError, match="^kind = 'texture': only 'sdf'"):
        import_siren(tmp_path / "w.pth", tmp_path / "w.tex", omega_0=30, kind="texture")
    with pytest.raises(ModelFileError, match="does not exist"):
        import_siren(tmp_path / "w.pth", tmp_path / "nope" / "w.sdf", omega_0=30)
    assert not (tmp_path / "w.tex").exists()
