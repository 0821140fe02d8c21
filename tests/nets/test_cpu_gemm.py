"""The float32 CPU GEMM route: the measured decision, the context that applies it, and the kernels on it."""

import pytest
import torch

from neural_bake.errors import NeuralBakeError
from neural_bake.fit.training import LoopConfig, train
from neural_bake.nets import cpu_gemm
from neural_bake.nets.cpu_gemm import decide_route, gemm_route, measure_route, model_width, route_in_use
from neural_bake.nets.gemm import gemm_gradient
from neural_bake.nets.siren import Siren, siren_forward_inference

needs_setting = pytest.mark.skipif(not cpu_gemm._onednn_setting_exists(),
                                   reason="this torch has no oneDNN float32 matmul setting")


def fake(speedup, onednn_error=5e-7):
    return lambda width: {"speedup": speedup, "blas_error": 5e-7, "onednn_error": onednn_error}


@needs_setting
def test_decision_takes_onednn_only_when_faster_and_float32_accurate():
    assert decide_route(256, measure=fake(1.8), env="auto")[0] == "onednn"
    route, why = decide_route(256, measure=fake(1.02), env="auto")
    assert route == "blas" and "1.02×" in why
    route, why = decide_route(256, measure=fake(3.0, onednn_error=2e-3), env="auto")
    assert route == "blas" and "not float32-accurate" in why
    # forcing oneDNN still refuses an inaccurate route; forcing the BLAS needs no measurement
    assert decide_route(256, measure=fake(0.5), env="onednn")[0] == "onednn"
    assert decide_route(256, measure=fake(3.0, onednn_error=2e-3), env="onednn")[0] == "blas"
    assert decide_route(256, measure=lambda w: pytest.fail("measured"), env="blas") == ("blas", "NEURAL_BAKE_CPU_GEMM=blas")


def test_unknown_environment_value_is_one_line_naming_the_variable():
    with pytest.raises(NeuralBakeError, match=r"^NEURAL_BAKE_CPU_GEMM='fastest': must be one of auto, blas, onednn$"):
        decide_route(64, env="fastest")


@needs_setting
def test_measurement_reads_both_routes_against_float64():
    m = measure_route(32, repeats=2)
    assert m["speedup"] > 0
    assert 0 <= m["blas_error"] < 1e-5
    # oneDNN is float32-accurate, or (CPUs with bf16 matrix units) rounds the operands to bfloat16 on the
    # way: ~1e-3, which the decision refuses even when forced
    assert 0 <= m["onednn_error"] < 1e-2
    if m["onednn_error"] >= 1e-4:
        assert decide_route(32, measure=lambda w: m, env="onednn")[0] == "blas"


@needs_setting
def test_context_sets_and_restores_the_setting_even_on_error():
    before = torch.backends.mkldnn.matmul.fp32_precision
    with gemm_route(64, measure=fake(2.0)) as route:
        assert route == "onednn" and route_in_use() == "onednn"
    assert torch.backends.mkldnn.matmul.fp32_precision == before
    with pytest.raises(RuntimeError):
        with gemm_route(64, measure=fake(2.0)):
            raise RuntimeError("boom")
    assert torch.backends.mkldnn.matmul.fp32_precision == before
    with gemm_route(64, measure=fake(1.0)) as route:
        assert route == "blas" and route_in_use() == "blas"
    with gemm_route(None) as route:  # nothing to decide for
        assert route == "blas"


def test_model_width_reads_the_attribute_or_the_matrices():
    assert model_width(Siren(48, 1)) == 48
    assert model_width(torch.nn.Linear(5, 7)) == 7
    assert model_width(torch.nn.Module()) is None


@needs_setting
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("env", ["blas", "onednn"])
def test_gemm_kernels_on_either_route_match_the_float64_autograd_reference(monkeypatch, dtype, env):
    monkeypatch.setenv("NEURAL_BAKE_CPU_GEMM", env)
    model = Siren(96, 2, generator=torch.Generator().manual_seed(3))
    x = (torch.rand(900, 3, generator=torch.Generator().manual_seed(4), dtype=dtype) * 2 - 1) * 0.9
    ref_model = Siren(96, 2).double()
    ref_model.load_state_dict(model.state_dict())
    xr = x.double().requires_grad_(True)
    yr = ref_model(xr)
    (gr,) = torch.autograd.grad(yr.sum(), xr)
    v, g = gemm_gradient(model, x, chunk_size=256)
    with torch.no_grad():
        fwd = siren_forward_inference(model.affine_layers(dtype=dtype), x, chunk_size=256)
    tol = 2e-3 if dtype == torch.float32 else 1e-8  # gradients of a 96-wide ω0 = 30 SIREN are ~100
    assert torch.allclose(g.double(), gr, rtol=1e-5, atol=tol)
    assert torch.allclose(v.double(), yr.detach(), rtol=1e-5, atol=tol / 100)
    assert torch.allclose(fwd.double(), yr.detach(), rtol=1e-5, atol=tol / 100)


@needs_setting
def test_training_runs_on_the_decided_route_and_restores_it(monkeypatch):
    monkeypatch.setenv("NEURAL_BAKE_CPU_GEMM", "onednn")
    model = Siren(32, 1, generator=torch.Generator().manual_seed(0))
    seen = []
    x = torch.rand(64, 3, generator=torch.Generator().manual_seed(1))

    def step_fn(step, gen):
        seen.append(route_in_use())
        return {"loss": model(x).square().mean()}

    before = torch.backends.mkldnn.matmul.fp32_precision
    train(model, step_fn, LoopConfig(steps=3, lr=1e-4, seed=0, progress=False))
    # oneDNN when it passes the accuracy check on this CPU, else the BLAS (the measured decision)
    expected = decide_route(32, env="onednn")[0]
    assert seen == [expected] * 3
    assert torch.backends.mkldnn.matmul.fp32_precision == before


def test_a_measured_decision_is_kept_for_the_next_process(monkeypatch, tmp_path):
    import json

    from neural_bake.nets import cpu_gemm

    monkeypatch.setenv("NEURAL_BAKE_CACHE_DIR", str(tmp_path / "neural_bake"))
    monkeypatch.setattr(cpu_gemm, "_decided", {})
    route, why = decide_route(48, env="auto")  # measured (the real products), then written down
    kept = json.loads((tmp_path / "neural_bake" / "gemm-route.json").read_text())
    (key, value), = kept.items()
    assert value == [route, why] and "width 48" in key and torch.__version__ in key
    monkeypatch.setattr(cpu_gemm, "_decided", {})  # a new process: read, not measured
    monkeypatch.setattr(cpu_gemm, "measure_route", lambda w: pytest.fail("measured again"))
    again, why_again = decide_route(48, env="auto")
    assert again == route and why_again.startswith(why) and "measured on this machine before" in why_again
    # an injected measurement is neither read from nor written to the file
    assert decide_route(48, measure=lambda w: {"speedup": 1.0, "blas_error": 0.0, "onednn_error": 0.0},
                        env="auto")[0] == "blas"
    assert json.loads((tmp_path / "neural_bake" / "gemm-route.json").read_text()) == kept
    # an unreadable file is measured past (and mended)
    (tmp_path / "neural_bake" / "gemm-route.json").write_text("{not json")
    monkeypatch.setattr(cpu_gemm, "_decided", {})
    monkeypatch.undo()  # the real measurement again, in the same cache folder
    monkeypatch.setenv("NEURAL_BAKE_CACHE_DIR", str(tmp_path / "neural_bake"))
    monkeypatch.setattr(cpu_gemm, "_decided", {})
    route, why = decide_route(48, env="auto")
    assert json.loads((tmp_path / "neural_bake" / "gemm-route.json").read_text()) == {key: [route, why]}
