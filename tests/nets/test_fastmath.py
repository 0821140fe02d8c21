"""neural_bake.nets.fastmath: the fused sin/cos kernel against float64 references, its fallbacks and its build."""

import math
import shutil

import pytest
import torch

from neural_bake.nets import fastmath
from neural_bake.nets.fastmath import kernel_available, sin_, sincos, sincos_

HAVE_CC = any(shutil.which(c) for c in ("cc", "gcc", "clang"))


TOL = 2e-7  # absolute, against float64 sin/cos (torch.sin's own error is 4e-8)


def _max_errors(x: torch.Tensor, s: torch.Tensor, c: torch.Tensor) -> tuple[float, float]:
    """Largest |s - sin x| and |c - cos x| against float64 references."""
    xd = x.double()
    return float((s.double() - torch.sin(xd)).abs().max()), float((c.double() - torch.cos(xd)).abs().max())


def test_kernel_is_built_where_a_compiler_is():
    # built wherever a compiler is; used where it measured faster than torch (on this project's 2-core CPU: 2x)
    assert ("fused C kernel" in fastmath.status()) == HAVE_CC
    if kernel_available():
        assert "µs vs torch's" in fastmath.status()


@pytest.mark.parametrize("n", [1, 7, 255, 257, 1000, 65539])
def test_accuracy_over_the_siren_range_and_sizes(n):
    g = torch.Generator().manual_seed(n)
    x = (torch.rand(n, generator=g) * 2 - 1) * 2000.0  # pre-activations reach hundreds; large ω0 thousands
    s, c = sincos(x)
    assert max(_max_errors(x, s, c)) <= TOL
    a = x.clone()
    out = torch.empty_like(a)
    sincos_(a, out)  # cos in place
    assert torch.equal(out, s) and torch.equal(a, c)


def test_quadrant_boundaries_and_special_values():
    k = torch.arange(-2000, 2001, dtype=torch.float64)
    edges = torch.cat([k * math.pi / 2, k * math.pi / 4]).float()
    near = torch.cat([edges, torch.nextafter(edges, edges + 1), torch.nextafter(edges, edges - 1)])
    tiny = torch.tensor([0.0, -0.0, 1e-30, -1e-30, 1e-8, 65535.9, -65536.0])
    x = torch.cat([near, tiny])
    s, c = sincos(x)
    assert max(_max_errors(x, s, c)) <= TOL
    # beyond the reduction's exact range, infinities and NaN: libm's answers, as torch gives
    wild = torch.tensor([65537.0, -1e5, 3e7, 1e38, -1e38, float("inf"), float("-inf"), float("nan"), 1.0])
    s, c = sincos(wild)
    torch.testing.assert_close(s, torch.sin(wild), rtol=0, atol=1e-6, equal_nan=True)
    torch.testing.assert_close(c, torch.cos(wild), rtol=0, atol=1e-6, equal_nan=True)
    assert s[-1] == pytest.approx(math.sin(1.0), abs=1e-7)  # a finite value in a "wild" block is still right


def test_2d_buffers_as_the_gemm_paths_use_them():
    x = torch.randn(4096, 64, generator=torch.Generator().manual_seed(0)) * 30
    a, h = x.clone(), torch.empty_like(x)
    sincos_(a, h)
    err_sin, err_cos = _max_errors(x, h, a)  # sin into the buffer, cos over the pre-activation in place
    assert err_sin <= TOL and err_cos <= TOL
    assert not torch.equal(a, x)


def test_other_tensors_take_torch_exactly():
    x64 = torch.linspace(-20, 20, 301, dtype=torch.float64)
    s, c = sincos(x64)
    assert torch.equal(s, torch.sin(x64)) and torch.equal(c, torch.cos(x64))
    strided = torch.linspace(-20, 20, 600)[::2]
    s, c = sincos(strided)
    assert torch.equal(s, torch.sin(strided)) and torch.equal(c, torch.cos(strided))
    grad = torch.linspace(-3, 3, 50, requires_grad=True)
    s, c = sincos(grad)
    assert torch.equal(s, torch.sin(grad.detach()))


def _use(monkeypatch, fn, status="test", sin_fn=None):
    monkeypatch.setitem(fastmath._state, "fn", fn)
    monkeypatch.setitem(fastmath._state, "status", status)
    monkeypatch.setitem(fastmath._state, "sin_fn", sin_fn)
    monkeypatch.setitem(fastmath._state, "sin_status", status)


@pytest.mark.skipif(not HAVE_CC, reason="no C compiler")
def test_forced_kernel_and_forced_torch_agree(monkeypatch):
    (fn, sin_fn), _ = fastmath._build()
    x = torch.randn(3000, 64, generator=torch.Generator().manual_seed(3)) * 50
    _use(monkeypatch, fn, sin_fn=sin_fn)
    s1, c1 = sincos(x)
    s1_only = sin_(x.clone())
    _use(monkeypatch, None)
    s2, c2 = sincos(x)
    assert torch.equal(s2, torch.sin(x)) and torch.equal(c2, torch.cos(x))
    assert torch.equal(sin_(x.clone()), torch.sin(x))
    torch.testing.assert_close(s1, s2, rtol=0, atol=2e-7)
    torch.testing.assert_close(c1, c2, rtol=0, atol=2e-7)
    assert torch.equal(s1_only, s1)  # the sin-only entry: the same reduction and polynomial


@pytest.mark.skipif(not HAVE_CC, reason="no C compiler")
def test_sin_only_entry_accuracy_in_place_and_special_values(monkeypatch):
    (_, sin_fn), _ = fastmath._build()
    _use(monkeypatch, None, sin_fn=sin_fn)
    for n in (1, 255, 257, 65539):
        x = (torch.rand(n, generator=torch.Generator().manual_seed(n)) * 2 - 1) * 2000.0
        a = x.clone()
        assert sin_(a) is a  # in place
        assert float((a.double() - torch.sin(x.double())).abs().max()) <= TOL
    wild = torch.tensor([65537.0, -1e5, 1e38, float("inf"), float("-inf"), float("nan"), 1.0])
    torch.testing.assert_close(sin_(wild.clone()), torch.sin(wild), rtol=0, atol=1e-6, equal_nan=True)
    x64 = torch.linspace(-20, 20, 301, dtype=torch.float64)  # other tensors: torch exactly
    assert torch.equal(sin_(x64.clone()), torch.sin(x64))
    strided = torch.linspace(-20, 20, 600)
    view = strided[::2]
    expected = torch.sin(view)
    sin_(view)
    assert torch.equal(view, expected)


def test_sin_status_says_which_sine():
    msg = fastmath.sin_status()
    assert ("fused C kernel" in msg) or ("torch.sin" in msg)
    assert fastmath.sin_kernel_available() == (not msg.endswith("torch.sin"))  # fallbacks end ": torch.sin"


def test_calibration_times_both():
    if not HAVE_CC:
        pytest.skip("no C compiler")
    (fn, sin_fn), _ = fastmath._build()
    t_kernel, t_torch = fastmath._calibrate(
        lambda a, s: fn(a.data_ptr(), s.data_ptr(), a.data_ptr(), a.numel()), lambda a, s: (torch.sin(a, out=s), a.cos_()))
    assert 0 < t_kernel < 1 and 0 < t_torch < 1
    t_kernel, t_torch = fastmath._calibrate(lambda a, s: sin_fn(a.data_ptr(), a.data_ptr(), a.numel()),
                                            lambda a, s: a.sin_())
    assert 0 < t_kernel < 1 and 0 < t_torch < 1


def test_a_failed_build_falls_back_for_both_entries(monkeypatch):
    monkeypatch.setitem(fastmath._state, "built", (None, "no C compiler found"))
    for key in ("fn", "status", "sin_fn", "sin_status"):
        monkeypatch.setitem(fastmath._state, key, None)
    assert not kernel_available()
    assert fastmath.sin_status() == "no C compiler found: torch.sin"
    assert not fastmath.sin_kernel_available()
    x = torch.linspace(-9, 9, 100)
    assert torch.equal(sin_(x.clone()), torch.sin(x))


def test_switch_off_no_compiler_and_failed_build(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv(fastmath.ENV_SWITCH, "0")
    fn, msg = fastmath._build()
    assert fn is None and "off" in msg
    monkeypatch.delenv(fastmath.ENV_SWITCH)
    monkeypatch.setenv("PATH", str(tmp_path / "nothing"))
    monkeypatch.delenv("CC", raising=False)
    fn, msg = fastmath._build()
    assert fn is None and msg.startswith("no C compiler found")
    monkeypatch.setenv("CC", "/bin/false")  # a compiler that fails
    fn, msg = fastmath._build()
    assert fn is None and msg.startswith("the C kernel did not build")
    assert not list((tmp_path / "neural_bake").glob("*"))  # nothing half-written left in the cache


@pytest.mark.skipif(not HAVE_CC, reason="no C compiler")
def test_fresh_build_into_an_empty_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    fns, msg = fastmath._build()
    assert fns is not None and "fused C kernel" in msg
    assert len(list((tmp_path / "neural_bake").glob("sincos-*.so"))) == 1
    x = torch.linspace(-7, 7, 1001)
    s, c = torch.empty_like(x), torch.empty_like(x)
    fns[0](x.data_ptr(), s.data_ptr(), c.data_ptr(), x.numel())
    assert max(_max_errors(x, s, c)) <= TOL
    fns[1](x.data_ptr(), c.data_ptr(), x.numel())
    assert torch.equal(c, s)


@pytest.mark.skipif(not HAVE_CC, reason="no C compiler")
def test_threaded_calls_give_the_bits_of_one_thread(monkeypatch):
    # over a team (where the kernel shares torch's OpenMP) each whole block is computed as on one thread: the same
    # bits, also for a block that takes libm's path (a huge value, an infinity, a NaN)
    fns, msg = fastmath._build()
    assert fns is not None, msg
    x = torch.linspace(-300, 300, 5 * 16384 + 123)
    x[70000], x[70001], x[3] = 1e9, float("inf"), float("nan")
    out = {}
    for n in (1, 2):
        monkeypatch.setattr(fastmath, "threads", lambda n=n: n)
        s, c, s_only = torch.empty_like(x), torch.empty_like(x), torch.empty_like(x)
        fns[0](x.data_ptr(), s.data_ptr(), c.data_ptr(), x.numel())
        fns[1](x.data_ptr(), s_only.data_ptr(), x.numel())
        out[n] = (s, c, s_only)
    for a, b in zip(out[1], out[2]):
        assert torch.equal(a.nan_to_num(7.0), b.nan_to_num(7.0)) and torch.equal(a.isnan(), b.isnan())
    assert torch.equal(out[1][0].nan_to_num(7.0), out[1][2].nan_to_num(7.0))  # the sin-only entry: the same sines
