"""Range analysis: soundness fuzzing (as Spelunking §3.6), the sin rule against dense sampling, sharing in
difference_bound, and every error path."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neural_bake.errors import NeuralBakeError
from neural_bake.nets.range_analysis import (
    METHODS,
    affine_sin,
    difference_bound,
    interval_sin,
    range_bound,
)
from neural_bake.nets.siren import Siren

ARCHS = [(16, 1), (64, 1), (64, 2)]
OMEGAS = [1.0, 10.0, 30.0, 60.0]
DTYPES = [torch.float32, torch.float64]


def _siren(width, depth, omega, dtype=torch.float32, seed=0, in_dim=3):
    g = torch.Generator().manual_seed(seed)
    return Siren(width, depth, in_dim=in_dim, omega_0=omega, hidden_omega=30.0, generator=g).to(dtype)


def _boxes(n, s, d, dtype, g, log_size=(-6.0, 0.0)):
    """n random boxes: centres in [-1, 1]^d, s orthogonal half-axes of random orientation, sizes log-uniform."""
    c = torch.rand(n, d, generator=g, dtype=torch.float64) * 2 - 1
    size = 10 ** (log_size[0] + (log_size[1] - log_size[0]) * torch.rand(n, generator=g, dtype=torch.float64))
    q, _ = torch.linalg.qr(torch.randn(n, d, d, generator=g, dtype=torch.float64))
    axes = q.transpose(1, 2)[:, :s, :] * size[:, None, None]
    axes = axes * (0.2 + torch.rand(n, s, 1, generator=g, dtype=torch.float64))  # unequal side lengths
    return c.to(dtype), axes.to(dtype)


def _points(c, axes, n, g):
    """(B, n + 2^s, d) points of each box: n random ones plus all corners (endpoints for segments)."""
    b, s, _ = axes.shape
    t = torch.rand(b, n, s, generator=g, dtype=torch.float64).to(c.dtype) * 2 - 1
    corners = torch.tensor([[((i >> k) & 1) * 2.0 - 1.0 for k in range(s)] for i in range(2**s)], dtype=c.dtype)
    t = torch.cat([t, corners.expand(b, -1, -1)], dim=1)
    return c[:, None, :] + torch.einsum("bns,bsd->bnd", t, axes)


def _values(model, x):
    with torch.no_grad():
        return model(x.reshape(-1, x.shape[-1])).reshape(x.shape[:-1])


def _assert_contains(lo, hi, fx, what):
    below = fx < lo[:, None]
    above = fx > hi[:, None]
    bad = (below | above).any(1)
    assert not bool(bad.any()), (
        f"{what}: {int(bad.sum())} boxes violated, e.g. lo={lo[bad][0].item()!r} hi={hi[bad][0].item()!r} "
        f"values in [{fx[bad][0].min().item()!r}, {fx[bad][0].max().item()!r}]")


# ----------------------------------------------------------------------------------------------------------------
# soundness fuzzing: > 10^5 boxes in total
# ----------------------------------------------------------------------------------------------------------------

# boxes per (architecture, ω0, dtype, s) and method: 48 configurations × (2000 + 400 + 120 + 60) ≈ 1.2·10^5 boxes
FUZZ_BOXES = {"affine-fixed": 2000, "interval": 400, "affine-truncate": 120, "affine-full": 60}


@pytest.mark.parametrize("arch", ARCHS, ids=lambda a: f"{a[0]}x{a[1]}")
@pytest.mark.parametrize("dtype", DTYPES, ids=str)
def test_fuzz_soundness(arch, dtype):
    g = torch.Generator().manual_seed(1000 * arch[0] + 10 * arch[1] + (dtype == torch.float64))
    total = 0
    for omega in OMEGAS:
        model = _siren(*arch, omega, dtype, seed=int(omega))
        for s in (1, 3):
            for method, n in FUZZ_BOXES.items():
                c, axes = _boxes(n, s, 3, dtype, g)
                lo, hi = range_bound(model, c, axes, method, keep=16)
                assert lo.dtype == dtype and hi.dtype == dtype and lo.shape == (n,)
                assert bool(torch.isfinite(lo).all() and torch.isfinite(hi).all())
                fx = _values(model, _points(c, axes, 12, g))
                _assert_contains(lo, hi, fx, f"{arch} ω0={omega} {dtype} s={s} {method}")
                total += n
    assert total * len(ARCHS) * len(DTYPES) >= 100_000


@pytest.mark.parametrize("dtype", DTYPES, ids=str)
def test_fuzz_difference_soundness(dtype):
    g = torch.Generator().manual_seed(7)
    for arch_h, arch_f in [((16, 1), (64, 1)), ((64, 1), (64, 2))]:
        for omega in (10.0, 30.0):
            h = _siren(*arch_h, omega, dtype, seed=1)
            f = _siren(*arch_f, omega, dtype, seed=2)
            for s in (1, 3):
                for method, n in FUZZ_BOXES.items():
                    c, axes = _boxes(n // 4, s, 3, dtype, g)
                    lo, hi = difference_bound(h, f, c, axes, method, keep=16)
                    x = _points(c, axes, 12, g)
                    _assert_contains(lo, hi, _values(h, x) - _values(f, x), f"h-f {omega} s={s} {method}")


@pytest.mark.parametrize("dtype", DTYPES, ids=str)
def test_fuzz_float32_arithmetic_is_sound_too(dtype):
    """compute_dtype=float32: looser, but every allowance is then a float32 one (and float64 boxes are
    rounded into the arithmetic with their conversion error covered)."""
    g = torch.Generator().manual_seed(11)
    for arch, omega in (((64, 1), 30.0), ((16, 2), 60.0)):
        model = _siren(*arch, omega, dtype)
        for s in (1, 3):
            for method in METHODS:
                c, axes = _boxes(150, s, 3, dtype, g)
                lo, hi = range_bound(model, c, axes, method, keep=8, compute_dtype=torch.float32)
                assert lo.dtype == dtype
                _assert_contains(lo, hi, _values(model, _points(c, axes, 12, g)), f"float32 {method} s={s}")


def test_sound_on_wide_boxes_and_4d_inputs():
    """Boxes far larger than a period (every sin saturates) and a space-time network (d = 4)."""
    g = torch.Generator().manual_seed(3)
    model = _siren(32, 2, 30.0, torch.float32, in_dim=4)
    c, axes = _boxes(200, 4, 4, torch.float32, g, log_size=(-1.0, 1.0))
    for method in METHODS:
        lo, hi = range_bound(model, c, axes, method)
        _assert_contains(lo, hi, _values(model, _points(c, axes, 32, g)), method)


# ----------------------------------------------------------------------------------------------------------------
# the sin rules on their own
# ----------------------------------------------------------------------------------------------------------------


def _sin_cases(dtype):
    rng = np.random.default_rng(5)
    centers = np.concatenate([
        rng.uniform(-8, 8, 300),
        rng.uniform(-200, 200, 100),
        np.array([0.0, math.pi / 2, math.pi, -math.pi / 2, 2 * math.pi, 100 * math.pi]),
    ])
    radii = np.concatenate([
        10 ** rng.uniform(-9, 0.7, 300),
        rng.uniform(0, 4, 100),
        np.array([0.0, 1e-12, math.pi - 1e-9, math.pi, 2 * math.pi, 1e-3]),
    ])
    c = torch.tensor(centers, dtype=dtype)
    r = torch.tensor(radii, dtype=dtype)
    return c, r


def _sin_shifted(c, t):
    """sin(c + t) for exact c (B,) and t (B, n), to a few float64 ulps (no rounding of the sum c + t)."""
    c = c.double()[:, None]
    return torch.sin(c) * torch.cos(t) + torch.cos(c) * torch.sin(t)


@pytest.mark.parametrize("dtype", DTYPES, ids=str)
def test_affine_sin_against_dense_sampling(dtype):
    c, r = _sin_cases(dtype)
    mid, alpha, gamma = affine_sin(c, r)
    assert mid.dtype == dtype
    # the claim is about the exact sin of exact points c + t, |t| <= r: check it in float64
    t = torch.linspace(-1, 1, 20001, dtype=torch.float64)[None, :] * r.double()[:, None]
    dev = _sin_shifted(c, t) - mid.double()[:, None] - alpha.double()[:, None] * t
    assert bool((dev.abs() <= gamma.double()[:, None]).all())
    # tight: for the chosen slope, gamma is half the spread of sin(x) - alpha x (up to rounding and sampling)
    spread = 0.5 * (dev.amax(1) - dev.amin(1))
    u = torch.finfo(dtype).eps / 2
    slack = 16 * u * (1 + r.double() * (c.double().abs() + r.double() + 4)) + (r.double() / 1e4) ** 2
    narrow = r < math.pi
    assert bool((gamma.double()[narrow] <= spread[narrow] + slack[narrow] + 1e-12).all())
    # wide ranges: the constant 0 with error 1
    wide = ~narrow
    assert bool((mid[wide] == 0).all() and (alpha[wide] == 0).all() and (gamma[wide] == 1).all())
    # the slope is the mean of the extreme slopes of sin on the range
    cosv = torch.cos(c.double()[:, None]) * torch.cos(t) - torch.sin(c.double()[:, None]) * torch.sin(t)
    expect_alpha = 0.5 * (cosv.amax(1) + cosv.amin(1))
    assert torch.allclose(alpha.double()[narrow], expect_alpha[narrow], atol=1e-6)  # sampling misses peaks by <= (r/1e4)^2


def test_affine_sin_zero_width_is_exact_to_rounding():
    c = torch.linspace(-50, 50, 1001, dtype=torch.float64)
    mid, alpha, gamma = affine_sin(c, torch.zeros_like(c))
    assert torch.allclose(mid, torch.sin(c), atol=1e-14, rtol=0)
    assert torch.allclose(alpha, torch.cos(c), atol=1e-14, rtol=0)
    assert bool((gamma < 1e-13).all())


@pytest.mark.parametrize("dtype", DTYPES, ids=str)
def test_interval_sin_against_dense_sampling(dtype):
    c, r = _sin_cases(dtype)
    mid, rad = interval_sin(c, r)
    t = torch.linspace(-1, 1, 20001, dtype=torch.float64)[None, :] * r.double()[:, None]
    s = _sin_shifted(c, t)
    assert bool((s >= (mid - rad).double()[:, None]).all() and (s <= (mid + rad).double()[:, None]).all())
    u = torch.finfo(dtype).eps / 2
    slack = 16 * u * (1 + c.double().abs() + r.double()) + (r.double() / 1e4) ** 2
    assert bool((rad.double() <= 0.5 * (s.amax(1) - s.amin(1)) + slack + 1e-12).all())


def test_sin_rules_treat_non_finite_as_wide():
    c = torch.tensor([math.inf, -math.inf, math.nan, 0.0], dtype=torch.float64)
    r = torch.tensor([0.0, 0.0, 0.0, math.inf], dtype=torch.float64)
    mid, alpha, gamma = affine_sin(c, r)
    assert mid.tolist() == [0.0] * 4 and alpha.tolist() == [0.0] * 4 and gamma.tolist() == [1.0] * 4
    mid, rad = interval_sin(c, r)
    assert mid.tolist() == [0.0] * 4 and rad.tolist() == [1.0] * 4


# ----------------------------------------------------------------------------------------------------------------
# tightness facts that hold by construction
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
def test_zero_width_box_is_tight_around_f_center(method):
    model64 = _siren(64, 2, 30.0, torch.float64)
    model32 = _siren(64, 2, 30.0, torch.float32)
    c = torch.rand(50, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * 2 - 1
    axes = torch.zeros(50, 3, 3, dtype=torch.float64)
    lo, hi = range_bound(model64, c, axes, method)
    f = _values(model64, c[:, None, :])[:, 0]
    assert bool((lo <= f).all() and (f <= hi).all())
    assert float((hi - lo).max()) < 1e-11  # float64 end to end: only float64 rounding allowances
    lo, hi = range_bound(model32, c.float(), axes.float(), method)
    f = _values(model32, c.float()[:, None, :])[:, 0]
    assert bool((lo <= f).all() and (f <= hi).all())
    # float32: the evaluation allowance (~4e-6 here) plus the input-point rounding, which interval arithmetic
    # cannot keep correlated (it grows by the layers' row sums of |W|)
    assert float((hi - lo).max()) < (1e-3 if method == "interval" else 1e-5)


def test_interval_arithmetic_is_inclusion_monotone():
    """Interval arithmetic (exact hulls of each step) is inclusion-isotone: a box inside another gets a bound
    inside the other's, up to the (float64-sized) rounding allowances. Affine arithmetic is not, so only this."""
    model = _siren(64, 2, 30.0, torch.float64)
    g = torch.Generator().manual_seed(12)
    c, _ = _boxes(200, 3, 3, torch.float64, g)
    outer_half = 10 ** (-3 * torch.rand(200, 1, generator=g, dtype=torch.float64))
    inner_half = outer_half * torch.rand(200, 3, generator=g, dtype=torch.float64)
    shift = (outer_half - inner_half) * (torch.rand(200, 3, generator=g, dtype=torch.float64) * 2 - 1)
    lo_o, hi_o = range_bound(model, c, torch.diag_embed(outer_half.expand(-1, 3)), "interval")
    lo_i, hi_i = range_bound(model, c + shift, torch.diag_embed(inner_half), "interval")
    assert bool((lo_i >= lo_o - 1e-9).all() and (hi_i <= hi_o + 1e-9).all())


def test_truncate_keeping_everything_equals_full():
    model = _siren(16, 2, 30.0, torch.float64)
    c, axes = _boxes(64, 3, 3, torch.float64, torch.Generator().manual_seed(2), log_size=(-3, -1))
    full = range_bound(model, c, axes, "affine-full")
    trunc = range_bound(model, c, axes, "affine-truncate", keep=3 * 16)
    assert torch.equal(full[0], trunc[0]) and torch.equal(full[1], trunc[1])
    small = range_bound(model, c, axes, "affine-truncate", keep=4)
    assert not torch.equal(full[1], small[1])  # truncation does change something


def test_chunking_does_not_change_the_result():
    model = _siren(64, 1, 30.0)
    c, axes = _boxes(50, 3, 3, torch.float32, torch.Generator().manual_seed(4), log_size=(-3, -1))
    for method in METHODS:
        a = range_bound(model, c, axes, method)
        b = range_bound(model, c, axes, method, chunk=7)
        assert torch.allclose(a[0], b[0], rtol=0, atol=1e-12) and torch.allclose(a[1], b[1], rtol=0, atol=1e-12)


def test_bounds_shrink_with_the_box_and_affine_beats_interval_on_small_boxes():
    model = _siren(64, 1, 30.0, torch.float64)
    c = torch.rand(20, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(5)) * 2 - 1
    widths = {m: [] for m in METHODS}
    for size in (1e-2, 1e-3, 1e-4):
        axes = torch.eye(3, dtype=torch.float64).expand(20, 3, 3) * size
        for m in METHODS:
            lo, hi = range_bound(model, c, axes, m)
            widths[m].append(float((hi - lo).median()))
    for m in METHODS:
        # first order: width ∝ size for small boxes
        assert widths[m][1] < widths[m][0] and widths[m][2] < 0.2 * widths[m][1]
    # the dependency problem: interval arithmetic is far looser than affine on the same small boxes
    assert widths["interval"][2] > 5 * widths["affine-fixed"][2]


# ----------------------------------------------------------------------------------------------------------------
# difference_bound: shared symbols
# ----------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["affine-fixed", "affine-full", "affine-truncate"])
def test_difference_with_itself_shrinks_to_zero(method):
    f = _siren(64, 1, 30.0, torch.float64)
    c = torch.rand(20, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(6)) * 2 - 1
    ratios, self_widths = [], []
    for size in (1e-2, 1e-3, 1e-4, 1e-5):
        axes = torch.eye(3, dtype=torch.float64).expand(20, 3, 3) * size
        lo, hi = difference_bound(f, f, c, axes, method)
        rlo, rhi = range_bound(f, c, axes, method)
        assert bool((lo <= 0).all() and (hi >= 0).all())
        shared = float((hi - lo).median())
        unshared = float((2 * (rhi - rlo)).median())  # range(f) - range(f): no sharing
        assert shared < unshared
        ratios.append(shared / unshared)
        self_widths.append(shared)
    # with sharing, only second-order (nonlinearity) terms remain: width ∝ size², so the ratio falls ~10×/decade
    assert ratios[-1] < 1e-2 and ratios[-1] < ratios[0] * 1e-2
    for wide, narrow in zip(self_widths, self_widths[1:]):
        assert narrow < 0.02 * wide or narrow < 1e-7
    assert self_widths[-1] < 1e-7


@pytest.mark.parametrize("method", METHODS)
def test_difference_is_inside_the_difference_of_ranges(method):
    """The same propagation with the input symbols cancelled: never wider than range(h) - range(f)."""
    h = _siren(16, 1, 10.0, torch.float64, seed=1)
    f = _siren(64, 1, 30.0, torch.float64, seed=2)
    c, axes = _boxes(100, 3, 3, torch.float64, torch.Generator().manual_seed(8), log_size=(-4, -0.5))
    lo, hi = difference_bound(h, f, c, axes, method)
    hlo, hhi = range_bound(h, c, axes, method)
    flo, fhi = range_bound(f, c, axes, method)
    tol = 1e-12
    assert bool((lo >= hlo - fhi - tol).all() and (hi <= hhi - flo + tol).all())
    if method == "interval":
        assert torch.allclose(lo, hlo - fhi, atol=1e-12, rtol=0) and torch.allclose(hi, hhi - flo, atol=1e-12, rtol=0)


def test_difference_certifies_a_known_offset():
    """h = f + 0.01 exactly (output bias shifted): the certified |h - f| is 0.01 up to a tiny margin."""
    f = _siren(64, 1, 30.0, torch.float64)
    h = _siren(64, 1, 30.0, torch.float64)
    with torch.no_grad():
        h.layers[-1].bias += 0.01
    c, axes = _boxes(30, 3, 3, torch.float64, torch.Generator().manual_seed(9), log_size=(-4, -3))
    lo, hi = difference_bound(h, f, c, axes, "affine-full")
    assert bool((lo <= 0.01).all() and (hi >= 0.01).all())
    assert float(torch.maximum(-lo, hi).max()) < 0.0101


# ----------------------------------------------------------------------------------------------------------------
# conventions: dtype, device, degenerate input, errors
# ----------------------------------------------------------------------------------------------------------------


def test_dtype_follows_inputs_and_outward_rounding():
    model = _siren(16, 1, 30.0)  # float32 weights
    c = torch.zeros(2, 3, dtype=torch.float64)
    axes = torch.full((2, 1, 3), 1e-3, dtype=torch.float64)
    lo, hi = range_bound(model, c, axes)
    assert lo.dtype == torch.float64 and hi.dtype == torch.float64
    lo32, hi32 = range_bound(model, c.float(), axes.float())
    assert lo32.dtype == torch.float32
    assert bool((lo32.double() <= lo).all() and (hi32.double() >= hi).all())


def test_point_and_empty_batches():
    model = _siren(16, 1, 30.0)
    c = torch.tensor([[0.1, 0.2, 0.3]])
    lo, hi = range_bound(model, c, torch.zeros(1, 0, 3))
    f = _values(model, c[:, None, :])[:, 0]
    assert bool(lo <= f) and bool(f <= hi) and float(hi - lo) < 1e-5
    lo, hi = range_bound(model, torch.zeros(0, 3), torch.zeros(0, 3, 3))
    assert lo.shape == (0,) and hi.shape == (0,)
    lo, hi = difference_bound(model, model, torch.zeros(0, 3), torch.zeros(0, 1, 3))
    assert lo.shape == (0,)


@pytest.mark.parametrize("method", METHODS)
def test_overflow_gives_infinite_bounds_not_nan(method):
    model = _siren(16, 1, 30.0, torch.float64)
    with torch.no_grad():
        model.layers[0].weight.mul_(1e308)  # pre-activations overflow (inf, inf - inf = nan, 0 * inf = nan)
        model.layers[-1].weight.mul_(1e308)
    c = torch.rand(8, 3, dtype=torch.float64)
    axes = torch.eye(3, dtype=torch.float64).expand(8, 3, 3) * 0.5
    lo, hi = range_bound(model, c, axes, method)
    # every hidden sin saturates to [-1, 1], so a huge (possibly infinite) but never NaN bound
    assert not bool(torch.isnan(lo).any() or torch.isnan(hi).any())
    assert bool((lo <= -1e300).all() and (hi >= 1e300).all())
    lo, hi = difference_bound(model, model, c, axes, method)
    assert not bool(torch.isnan(lo).any() or torch.isnan(hi).any())
    assert bool((lo <= -1e300).all() and (hi >= 1e300).all())


def test_numpy_inputs_are_accepted():
    model = _siren(16, 1, 30.0)
    lo, hi = range_bound(model, np.zeros((2, 3), np.float32), np.full((2, 3, 3), 0.01, np.float32))
    assert isinstance(lo, torch.Tensor) and lo.shape == (2,)


@pytest.mark.parametrize(
    "center, axes, match",
    [
        (torch.zeros(4), torch.zeros(4, 1, 3), r"center must have shape \(B, 3\), got \(4,\)"),
        (torch.zeros(4, 2), torch.zeros(4, 1, 3), r"center must have shape \(B, 3\), got \(4, 2\)"),
        (torch.zeros(4, 3), torch.zeros(4, 3), r"axes must have shape \(4, s, 3\), got \(4, 3\)"),
        (torch.zeros(4, 3), torch.zeros(5, 1, 3), r"axes must have shape \(4, s, 3\), got \(5, 1, 3\)"),
        (torch.zeros(4, 3), torch.zeros(4, 1, 2), r"axes must have shape \(4, s, 3\), got \(4, 1, 2\)"),
        (torch.full((4, 3), math.nan), torch.zeros(4, 1, 3), r"center has non-finite values"),
        (torch.zeros(4, 3), torch.full((4, 1, 3), math.inf), r"axes has non-finite values"),
        (torch.zeros(4, 3, dtype=torch.int64), torch.zeros(4, 1, 3), r"center must be a floating-point tensor"),
    ],
)
def test_bad_boxes_raise(center, axes, match):
    model = _siren(16, 1, 30.0)
    with pytest.raises(ValueError, match=match):
        range_bound(model, center, axes)
    with pytest.raises(NeuralBakeError, match="difference_bound: " + match):
        difference_bound(model, model, center, axes)


def test_bad_options_raise():
    model = _siren(16, 1, 30.0)
    c, axes = torch.zeros(2, 3), torch.zeros(2, 1, 3)
    with pytest.raises(NeuralBakeError, match=r"range_bound: unknown method 'affine' \(expected one of interval"):
        range_bound(model, c, axes, "affine")
    with pytest.raises(NeuralBakeError, match="range_bound: keep must be a positive integer, got 0"):
        range_bound(model, c, axes, "affine-truncate", keep=0)
    with pytest.raises(NeuralBakeError, match="range_bound: chunk must be a positive integer or None, got 0"):
        range_bound(model, c, axes, chunk=0)
    two = Siren(16, 1, out_dim=2)
    with pytest.raises(NeuralBakeError, match=r"range_bound: model must have a scalar output \(out_dim 1\), got out_dim 2"):
        range_bound(two, c, axes)
    with pytest.raises(NeuralBakeError, match="range_bound: model must be a Siren .* got Linear"):
        range_bound(torch.nn.Linear(3, 1), c, axes)
    with pytest.raises(NeuralBakeError, match=r"difference_bound: f must have a scalar output"):
        difference_bound(model, two, c, axes)
    with pytest.raises(NeuralBakeError, match=r"difference_bound: h and f take inputs of different dimension \(3 and 4\)"):
        difference_bound(model, Siren(16, 1, in_dim=4), c, axes)


def test_exported_from_package():
    import neural_bake

    assert neural_bake.range_bound is range_bound
    assert neural_bake.difference_bound is difference_bound


# ----------------------------------------------------------------------------------------------------------------
# the benchmark (`neural-bake bench range`), shrunken: one small model file
# ----------------------------------------------------------------------------------------------------------------


def test_bench_range_cli_on_a_small_model(tmp_path, capsys):
    import json

    from neural_bake.cli.main import main
    from neural_bake.fields import save_model

    path = tmp_path / "small.sdf"
    save_model(_siren(16, 1, 30.0), path)
    out = tmp_path / "range.json"
    assert main(["bench", "range", "--quick", "--model", str(path), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "affine-full" in text and "dense 512 pts" in text
    result = json.loads(out.read_text())
    assert result["name"] == "range" and result["quick"] is True
    assert len(result["tables"]) == 2
    rows, diff_rows = result["tables"].values()
    assert [r["method"] for r in rows[:4]] == list(METHODS)
    assert {r["region"] for r in rows} == {"1d segment", "3d box"}
    for r in rows:
        assert r["time ×fwd"] > 0 and r["µs/box"] > 0
        if r["guarantee"] == "yes":  # a guaranteed bound is never narrower than the sampled range
            assert all(r[f"w/true h={h:g}"] >= 1.0 for h in (1e-3, 1e-2, 1e-1, 1.0))
        else:
            assert all(0.5 < r[f"w/true h={h:g}"] <= 1.0 for h in (1e-3, 1e-2, 1e-1, 1.0))
    # the small boxes are where affine arithmetic beats interval arithmetic
    by = {(r["region"], r["method"]): r for r in rows}
    assert by[("3d box", "affine-full")]["w/true h=0.001"] < by[("3d box", "interval")]["w/true h=0.001"]
    # difference table: certificates are never below the sampled maximum, and sharing never hurts
    assert {r["method"] for r in diff_rows} == {"interval", "affine-fixed", "affine-full"}
    for r in diff_rows:
        assert r["certified (shared)"] >= r["sampled max|h-f|"]
        assert r["certified (shared)"] <= r["certified (range h - range f)"] * (1 + 1e-5) + 1e-6  # allowances
        if r["method"] == "affine-full" and r["half-size"] == 1e-3:
            assert r["certified (shared)"] < 0.5 * r["certified (range h - range f)"]


def test_bench_range_cli_reports_a_missing_model(tmp_path, capsys):
    from neural_bake.cli.main import main

    assert main(["bench", "range", "--quick", "--model", str(tmp_path / "nope.sdf")]) == 2
    assert "nope.sdf" in capsys.readouterr().err
