"""Reduced-precision inference: the bf16 GEMM paths against a slow reference, and the fp32/bf16 decision."""

import numpy as np
import pytest
import torch

from neural_bake.errors import NeuralBakeError
from neural_bake.fields import SdfField, TextureField
from neural_bake.nets import precision as prec
from neural_bake.nets.gemm import _backward_mats, gemm_gradient
from neural_bake.nets.precision import gemm_dtype, resolve_precision
from neural_bake.nets.siren import Siren, siren_forward_inference


def slow_reference(model, x, low, chunk=None):
    """Values and gradients with the hidden W×W products rounded through ``low`` exactly as the fast path
    does, written plainly (no buffers, torch.sin/cos). ``chunk``: the rows of each product, as the fast path's
    chunks, and its operands laid out as there (a bfloat16 product may round a sum differently at another row
    count or layout, by one bfloat16 step)."""
    if chunk is not None:
        parts = [slow_reference(model, x[s:s + chunk], low) for s in range(0, x.shape[0], chunk)]
        return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])
    layers = model.affine_layers(dtype=x.dtype)
    h, coss = x, []
    for i, (w, b) in enumerate(layers[:-1]):
        a = h @ w.t() + b if i == 0 else torch.mm(h.to(low), w.t().to(low).contiguous()).to(x.dtype) + b
        h = torch.sin(a)
        coss.append(torch.cos(a))
    w_n, b_n = layers[-1]
    values = h @ w_n.t() + b_n
    mats = _backward_mats(layers)
    g = coss[-1]
    for i in range(len(coss) - 1, 0, -1):
        g = torch.mm(g.to(low), mats[i].to(low).contiguous()).to(x.dtype) * coss[i - 1]
    return values, g @ mats[0]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_bf16_gemm_gradient_matches_the_slow_reference(dtype):
    model = Siren(64, 2, generator=torch.Generator().manual_seed(0))
    x = (torch.rand(700, 3, generator=torch.Generator().manual_seed(1), dtype=dtype) * 2 - 1) * 0.8
    v, g = gemm_gradient(model, x, gemm_dtype=torch.bfloat16, chunk_size=256)  # several chunks, a short last one
    rv, rg = slow_reference(model, x, torch.bfloat16, chunk=256)
    assert v.dtype == g.dtype == dtype
    tol = 1e-5 if dtype == torch.float32 else 1e-9
    torch.testing.assert_close(v, rv, atol=tol * 10, rtol=tol)
    torch.testing.assert_close(g, rg, atol=tol * 100, rtol=tol * 10)
    # and it is a reduced precision: close to, but not equal to, the float32 path
    fv, fg = gemm_gradient(model, x)
    assert 0 < (g - fg).abs().max() < 0.05 * fg.abs().max()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_bf16_forward_inference_matches_the_slow_reference(dtype):
    model = Siren(64, 2, out_dim=3, generator=torch.Generator().manual_seed(2))
    x = torch.rand(300, 3, generator=torch.Generator().manual_seed(3), dtype=dtype) - 0.5
    with torch.no_grad():
        layers = model.affine_layers(dtype=dtype)
        out = siren_forward_inference(layers, x, chunk_size=128, gemm_dtype=torch.bfloat16)
    h = x
    for i, (w, b) in enumerate(layers[:-1]):
        h = torch.sin(h @ w.t() + b if i == 0 else
                      torch.mm(h.to(torch.bfloat16), w.t().to(torch.bfloat16).contiguous()).to(dtype) + b)
    ref = h @ layers[-1][0].t() + layers[-1][1]
    torch.testing.assert_close(out, ref, atol=1e-5 if dtype == torch.float32 else 1e-9, rtol=1e-5)


def test_auto_picks_bf16_only_where_the_measured_check_says_faster():
    model = Siren(128, 2, generator=torch.Generator().manual_seed(0))
    widths = []

    def fast(width, device):
        widths.append(width)
        return 2.0

    assert resolve_precision("auto", model, measure=fast)[0] == "bf16" and widths == [128]
    slow, why = resolve_precision("auto", model, measure=lambda w, d: 1.1)
    assert slow == "fp32" and "1.10×" in why
    assert resolve_precision("fp32", model, measure=fast) == ("fp32", "float32 asked for")
    assert resolve_precision("bf16", model)[0] == "bf16"


def test_a_measured_cpu_decision_is_kept_for_the_next_process(monkeypatch, tmp_path):
    import json

    model = Siren(48, 2, generator=torch.Generator().manual_seed(0))
    monkeypatch.setenv("NEURAL_BAKE_CACHE_DIR", str(tmp_path / "neural_bake"))
    monkeypatch.setattr(prec, "_decided", {})
    monkeypatch.setattr(prec, "bf16_supported", lambda device: (True, "bfloat16 GEMMs available"))
    monkeypatch.setattr(prec, "measure_bf16_speedup", lambda w, d: 1.1)  # the measurement (default path)
    out, why = resolve_precision("auto", model)
    kept = json.loads((tmp_path / "neural_bake" / "bf16-speedup.json").read_text())
    (key, value), = kept.items()
    assert value == [out, why] == ["fp32", why] and "width 48" in key and torch.__version__ in key
    monkeypatch.setattr(prec, "_decided", {})  # a new process: read, not measured
    monkeypatch.setattr(prec, "measure_bf16_speedup", lambda w, d: pytest.fail("measured again"))
    again, why_again = resolve_precision("auto", model)
    assert again == "fp32" and why_again.startswith(why) and "measured on this machine before" in why_again
    # an injected measurement is neither read from nor written to the file
    assert resolve_precision("auto", model, measure=lambda w, d: 3.0)[0] == "bf16"
    assert json.loads((tmp_path / "neural_bake" / "bf16-speedup.json").read_text()) == kept


def test_the_measurement_stops_when_bf16_is_far_slower():
    # each round reads the clock four times: float32 products take 1 s, bfloat16 ones 10 s
    readings = [t for r in range(5) for t in (100.0 * r, 100.0 * r + 1, 100.0 * r + 1, 100.0 * r + 11)]
    calls = []

    def clock():
        calls.append(1)
        return readings[len(calls) - 1]

    assert prec.measure_bf16_speedup(16, repeats=5, clock=clock) == pytest.approx(0.1)
    assert len(calls) == 4  # one round of each, then stopped


def test_auto_falls_back_where_bf16_is_not_supported(monkeypatch):
    model = Siren(128, 2, generator=torch.Generator().manual_seed(0))
    calls = []
    monkeypatch.setattr(prec, "bf16_supported", lambda device: (False, "no bfloat16 GEMM here"))
    out, why = resolve_precision("auto", model, measure=lambda w, d: calls.append(w) or 9.0)
    assert out == "fp32" and why == "no bfloat16 GEMM here" and calls == []  # not even measured
    with pytest.raises(NeuralBakeError, match="precision bf16: no bfloat16 GEMM here") as info:
        resolve_precision("bf16", model)
    assert info.value.parameter == "precision"


def test_auto_keeps_fp32_for_float64_networks_analytic_fields_and_no_hidden_matrix():
    double = Siren(64, 1, generator=torch.Generator().manual_seed(0)).double()
    assert resolve_precision("auto", double, measure=lambda w, d: 9.0) == ("fp32", "the network runs in float64, not float32")
    assert resolve_precision("auto", None)[0] == "fp32"
    flat = Siren(64, 0, generator=torch.Generator().manual_seed(0))
    assert resolve_precision("auto", flat, measure=lambda w, d: 9.0)[1] == "the network has no hidden W×W matrix"
    with pytest.raises(NeuralBakeError, match="precision bf16: an analytic field"):
        resolve_precision("bf16", None)


@pytest.mark.parametrize("bad", ["fp16", "", "FP32"])
def test_unknown_precision_is_refused(bad):
    with pytest.raises(NeuralBakeError, match="precision must be one of fp32, bf16, auto") as info:
        resolve_precision(bad, None)
    assert info.value.parameter == "precision"
    with pytest.raises(NeuralBakeError, match="resolved"):
        gemm_dtype("auto")


def test_field_with_precision_probe_keeps_fp32_when_bf16_is_too_far_off():
    model = Siren(64, 2, generator=torch.Generator().manual_seed(0))
    field = SdfField.from_model(model)
    probe = torch.rand(200, 3, generator=torch.Generator().manual_seed(4)) - 0.5
    fast, out, why = field.with_precision("auto", measure=lambda w, d: 5.0, probe=probe)
    # a random SIREN's normals are far more sensitive than a fitted one's: the probe decides either way, and
    # says what it measured
    assert "median off float32 at 200 points" in why
    if out == "bf16":
        assert fast is not field and fast.gemm_dtype == torch.bfloat16 and field.gemm_dtype is None
    else:
        assert fast is field
    same, out2, _ = field.with_precision("fp32")
    assert same is field and out2 == "fp32"
    tex = TextureField.from_model(Siren(32, 1, out_dim=3, generator=torch.Generator().manual_seed(1)))
    t_fast, t_out, t_why = tex.with_precision("bf16")
    assert t_out == "bf16" and t_fast.gemm_dtype == torch.bfloat16
    np.testing.assert_allclose(t_fast.color(probe).numpy(), tex.color(probe).numpy(), atol=0.02)


def test_renderer_and_baker_share_the_inference_path():
    from neural_bake.render.asset import siren_level, siren_texture

    model = Siren(64, 2, generator=torch.Generator().manual_seed(0))
    x = torch.rand(100, 3, generator=torch.Generator().manual_seed(5)) - 0.5
    level = siren_level(model, precision="bf16")
    v, g = level.value_and_gradient(x)
    rv, rg = slow_reference(model, x, torch.bfloat16)
    torch.testing.assert_close(g, rg, atol=1e-4, rtol=1e-5)
    torch.testing.assert_close(level.value(x), rv.reshape(-1), atol=1e-5, rtol=1e-5)
    field = SdfField.from_model(model)
    field.gemm_dtype = torch.bfloat16
    torch.testing.assert_close(field.value_and_gradient(x)[1], g)  # the baker's field: the same numbers
    tex = siren_texture(Siren(32, 1, out_dim=3, generator=torch.Generator().manual_seed(1)), precision="fp32")
    assert tex.color(x).shape == (100, 3)
