"""srgb_to_linear / linear_to_srgb and bilinear sample_texture against slow references."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neural_bake.io.colour import linear_to_srgb, sample_texture, srgb_to_linear


def test_srgb_known_values_and_inverse():
    np.testing.assert_allclose(srgb_to_linear(np.array([0.0, 0.04045, 0.5, 1.0])),
                               [0.0, 0.04045 / 12.92, 0.21404114, 1.0], rtol=1e-6)
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-12)
    assert srgb_to_linear(np.float32(0.5)).dtype == np.float32
    assert srgb_to_linear(np.array([128], np.uint8) / 255).dtype == np.float64
    np.testing.assert_allclose(linear_to_srgb(np.array([-1.0, 2.0])), [0.0, 1.0], atol=1e-15)


def test_srgb_is_continuous_at_the_knee():
    a, b = srgb_to_linear(np.array([0.04045 - 1e-9, 0.04045 + 1e-9]))
    assert abs(a - b) < 1e-6
    a, b = linear_to_srgb(np.array([0.0031308 - 1e-10, 0.0031308 + 1e-10]))
    assert abs(a - b) < 1e-6


def reference_bilinear(tex, u, v, policy):
    h, w, _ = tex.shape
    x, y = u * w - 0.5, (1 - v) * h - 0.5
    x0, y0 = int(np.floor(x)), int(np.floor(y))
    fx, fy = x - x0, y - y0
    out = 0
    for dx, dy, wt in [(0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)]:
        xi, yi = x0 + dx, y0 + dy
        if policy == "wrap":
            xi, yi = xi % w, yi % h
        else:
            xi, yi = min(max(xi, 0), w - 1), min(max(yi, 0), h - 1)
        out = out + wt * tex[yi, xi].astype(np.float64)
    return out


@settings(max_examples=60, deadline=None)
@given(h=st.integers(1, 5), w=st.integers(1, 5), policy=st.sampled_from(["wrap", "clamp"]),
       dtype=st.sampled_from([np.float32, np.float64]), seed=st.integers(0, 10_000))
def test_sample_matches_reference(h, w, policy, dtype, seed):
    rng = np.random.default_rng(seed)
    tex = rng.random((h, w, 3)).astype(dtype)
    uv = rng.uniform(-1.5, 2.5, (20, 2))
    got = sample_texture(tex, uv, policy)
    assert got.dtype == dtype and got.shape == (20, 3)
    want = np.array([reference_bilinear(tex, u, v, policy) for u, v in uv])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 if dtype == np.float32 else 1e-12)


def test_texel_centres_and_orientation():
    tex = np.arange(12, dtype=np.float64).reshape(3, 4, 1)  # row 0 = top
    for j in range(3):
        for i in range(4):
            uv = [[(i + 0.5) / 4, 1 - (j + 0.5) / 3]]
            assert sample_texture(tex, uv)[0, 0] == pytest.approx(tex[j, i, 0], abs=1e-12)
    # v near 1 reads the top row, v near 0 the bottom row
    assert sample_texture(tex, [[0.125, 0.99]], "clamp")[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert sample_texture(tex, [[0.125, 0.01]], "clamp")[0, 0] == pytest.approx(8.0, abs=1e-12)


def test_wrap_and_clamp():
    tex = np.random.default_rng(0).random((4, 4, 3))
    uv = np.array([[0.3, 0.6]])
    np.testing.assert_allclose(sample_texture(tex, uv + [1, -2]), sample_texture(tex, uv), atol=1e-12)
    np.testing.assert_allclose(sample_texture(tex, [[5.0, 0.5]], "clamp"), sample_texture(tex, [[0.999, 0.5]], "clamp"))


@pytest.mark.parametrize("policy", ["wrap", "clamp"])
def test_uv_far_outside_reads_a_texel_of_the_texture(policy):
    tex = np.random.default_rng(1).random((6, 5, 3)).astype(np.float32)
    uv = np.array([[1e30, -1e30], [-1e18, 0.5], [0.5, 3e9], [2.0**40 + 0.25, -7.75]])
    out = sample_texture(tex, uv, policy)
    assert np.isfinite(out).all() and (out >= tex.min() - 1e-6).all() and (out <= tex.max() + 1e-6).all()
    # within the exact integers of float64, wrapping still reads the texture repeated
    np.testing.assert_allclose(out[3], sample_texture(tex, [[0.25, 0.25]], policy)[0] if policy == "wrap" else
                               sample_texture(tex, [[1.0, 0.0]], policy)[0], atol=1e-6)


def test_half_float_texture_is_blended_in_float32_and_returned_as_half():
    tex = np.random.default_rng(2).random((4, 6, 3)).astype(np.float16)
    uv = np.random.default_rng(3).uniform(-0.5, 1.5, (50, 2))
    got = sample_texture(tex, uv)
    assert got.dtype == np.float16
    want = sample_texture(tex.astype(np.float32), uv).astype(np.float16)
    np.testing.assert_array_equal(got, want)


def test_non_finite_uv_gives_zeros_and_int_texture_gives_float64():
    tex = np.full((2, 2, 3), 7, np.uint8)
    out = sample_texture(tex, [[np.nan, 0.5], [0.5, np.inf], [0.5, 0.5]])
    assert out.dtype == np.float64 and np.isfinite(out).all()
    np.testing.assert_array_equal(out, [[0, 0, 0], [0, 0, 0], [7, 7, 7]])
    assert sample_texture(np.ones((2, 2)), [[0.5, 0.5]]).shape == (1, 1)


@pytest.mark.parametrize(
    "tex,uv,policy,match",
    [
        (np.ones((2, 2, 3)), [[0, 0]], "mirror", r"policy must be one of \('wrap', 'clamp'\), got 'mirror'"),
        (np.ones(4), [[0, 0]], "wrap", r"texture must be \(H, W, C\), got shape \(4,\)"),
        (np.ones((2, 2, 3)), [0, 0], "wrap", r"uv must be \(N, 2\), got shape \(2,\)"),
    ],
)
def test_errors(tex, uv, policy, match):
    with pytest.raises(ValueError, match=match):
        sample_texture(tex, uv, policy)
