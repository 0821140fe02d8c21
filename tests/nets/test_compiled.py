"""neural_bake.nets.compiled: mode resolution, the eager fallback, and a real compile of a small function."""

import warnings

import pytest
import torch

from neural_bake.errors import NeuralBakeError, NeuralBakeWarning
from neural_bake.nets.compiled import ENV_SWITCH, CompiledFn, compiler_available, env_switch, long_run, should_compile


def test_long_run_rule():
    assert long_run(100_000, 5.0) and long_run(5, 10.0) and not long_run(100_000, 2.0)
    assert long_run(5000, None) and not long_run(4999, None)


def test_should_compile_modes(monkeypatch):
    monkeypatch.delenv(ENV_SWITCH, raising=False)
    assert not should_compile("off", "cpu", long_run=True)
    assert not should_compile("auto", "cpu", long_run=False)
    assert should_compile("auto", "cpu", long_run=True) == compiler_available("cpu")
    assert should_compile("on", "cpu", long_run=False) == compiler_available("cpu")
    assert not should_compile("on", "meta", long_run=True)  # no Inductor backend for it
    with pytest.raises(NeuralBakeError, match="compile must be one of auto, on, off, got 'yes'"):
        should_compile("yes", "cpu", long_run=True)


@pytest.mark.parametrize("value, expected", [("1", True), (" ON ", True), ("yes", True), ("0", False),
                                             ("false", False), ("Off", False), ("", None), ("maybe", None)])
def test_env_switch_values(monkeypatch, value, expected):
    monkeypatch.setenv("NEURAL_BAKE_TEST_SWITCH", value)
    assert env_switch("NEURAL_BAKE_TEST_SWITCH") is expected


def test_environment_switch_turns_compiling_off(monkeypatch):
    monkeypatch.setenv(ENV_SWITCH, "0")
    assert not compiler_available("cpu") and not should_compile("on", "cpu", long_run=True)


def test_no_compiler_means_no_compile(monkeypatch):
    monkeypatch.delenv(ENV_SWITCH, raising=False)
    monkeypatch.setenv("PATH", "/nonexistent")
    monkeypatch.delenv("CXX", raising=False)
    assert not compiler_available("cpu")


def test_disabled_is_the_plain_function():
    calls = []
    fn = CompiledFn(lambda x: calls.append(x) or x * 2, enabled=False, desc="t")
    assert fn(3) == 6 and calls == [3] and fn.compiled is False


def _broken_backend(graph_module, example_inputs):
    raise RuntimeError("the C++ compiler exited with status 1")  # what a broken toolchain does


def test_failed_compile_warns_once_and_runs_eagerly():
    fn = CompiledFn(lambda x: torch.sin(x) + 1, enabled=True, desc="fit sdf 8x1", backend=_broken_backend)
    x = torch.linspace(0, 1, 5)
    with pytest.warns(NeuralBakeWarning, match=r"fit sdf 8x1: torch.compile failed \(.*exited with status 1"):
        y = fn(x)
    assert torch.equal(y, torch.sin(x) + 1) and fn.compiled is False
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert torch.equal(fn(x), y)  # no second warning


def test_our_errors_pass_through():
    def bad(x):
        raise NeuralBakeError("points: expected (N, 3)")

    with pytest.raises(NeuralBakeError, match="expected"):
        CompiledFn(bad, enabled=True, desc="t")(torch.zeros(2))


@pytest.mark.skipif(not compiler_available("cpu"), reason="no C++ compiler for TorchInductor")
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_real_compile_matches_eager(dtype):
    def f(a, b):
        return torch.sin(a) * torch.cos(b) + (a - b).square().mean()

    fn = CompiledFn(f, enabled=True, desc="t")
    g = torch.Generator().manual_seed(0)
    a, b = torch.randn(64, 8, generator=g, dtype=dtype), torch.randn(64, 8, generator=g, dtype=dtype)
    out = fn(a, b)
    assert fn.compiled is True
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(out, f(a, b), rtol=tol, atol=tol)


def _sin_plus_one(x):  # module level: dynamo's compiled versions are kept per code object
    return torch.sin(x) + 1


def test_more_versions_than_torchs_default_limit_stay_compiled():
    # a time-budgeted (256, 3) fit compiles 8 shapes × variants; a process fitting several networks more:
    # past torch's default limit of 8, dynamo would run the function eagerly without a word
    from neural_bake.nets.compiled import RECOMPILE_LIMIT

    graphs = []

    def counting_backend(gm, example_inputs):
        graphs.append(tuple(example_inputs[0].shape))
        return gm.forward

    torch._dynamo.reset()
    fn = CompiledFn(_sin_plus_one, enabled=True, desc="t", backend=counting_backend)
    sizes = list(range(1, 15))
    assert len(sizes) > 8 and len(sizes) < RECOMPILE_LIMIT
    for n in sizes:
        x = torch.linspace(0, 1, n)
        assert torch.equal(fn(x), torch.sin(x) + 1)
    assert len(graphs) == len(sizes) and fn.compiled is True
    assert torch._dynamo.config.recompile_limit == 8  # torch's own setting is left as it was
    torch._dynamo.reset()


def test_the_float32_training_gradient_traces_in_one_graph():
    """The polish's float32 loss calls gemm_gradient inside the compiled step: its input checks must not read a
    tensor there (a graph break, and a warning on the user's console)."""
    from neural_bake.nets.gemm import gemm_gradient
    from neural_bake.nets.siren import Siren

    model = Siren(16, 1, generator=torch.Generator().manual_seed(0))
    torch._dynamo.reset()
    out = torch._dynamo.explain(lambda p: gemm_gradient(model, p, "reverse", differentiable=True)[1].sum())(
        torch.rand(64, 3))
    assert out.graph_break_count == 0 and out.graph_count == 1
