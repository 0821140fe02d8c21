"""Splatting samples into a map: the scatter of one sample per texel and the weighted sums of several agree
with a per-sample reference."""

import numpy as np
import pytest

from neural_bake.bake.maps import splat
from neural_bake.errors import NeuralBakeError


def _reference(values, pixel, weight, size, rows):
    a, b = rows
    acc = np.zeros((b - a, size[1], values.shape[1]))
    wsum = np.zeros((b - a, size[1]))
    for v, (r, c), wt in zip(values, pixel, weight):
        acc[r - a, c] += v * wt
        wsum[r - a, c] += wt
    return acc, wsum


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("unique", [True, False])
def test_splat_matches_the_per_sample_reference(rng, dtype, unique):
    size, rows = (12, 9), (3, 10)
    texels = rng.choice((rows[1] - rows[0]) * size[1], 40, replace=not unique)
    texels = np.sort(texels) if unique else texels  # sorted and distinct: the scatter path; else the sums
    pixel = np.stack([texels // size[1] + rows[0], texels % size[1]], axis=1)
    values = rng.normal(size=(len(texels), 3)).astype(dtype)
    weight = rng.uniform(0.1, 1.0, len(texels))
    ref_acc, ref_w = _reference(values.astype(np.float64), pixel, weight, size, rows)
    acc, wsum = splat(values, pixel, weight, size, rows=rows, average=False)
    np.testing.assert_allclose(acc, ref_acc, atol=1e-12)
    np.testing.assert_allclose(wsum, ref_w, atol=1e-12)
    avg, _ = splat(values, pixel, weight, size, rows=rows)
    hit = ref_w > 0
    np.testing.assert_allclose(avg[hit], ref_acc[hit] / ref_w[hit][:, None], atol=1e-12)
    assert (avg[~hit] == 0).all()


@pytest.mark.parametrize("unique", [True, False])
def test_splat_into_adds_the_same_sums_in_place(rng, unique):
    from neural_bake.bake.maps import splat_into

    size = (10, 7)
    texels = rng.choice(size[0] * size[1], 30, replace=not unique)
    texels = np.sort(texels) if unique else texels
    pixel = np.stack([texels // size[1], texels % size[1]], axis=1)
    values = rng.normal(size=(len(texels), 4))
    weight = rng.uniform(0.1, 1.0, len(texels))
    start = rng.normal(size=(*size, 4)).astype(np.float32)
    acc, wsum = start.copy(), np.ones(size, np.float32)
    splat_into(acc, wsum, values, pixel, weight)
    ref_acc, ref_w = _reference(values, pixel, weight, size, (0, size[0]))
    np.testing.assert_allclose(acc, start + ref_acc, atol=1e-5)
    np.testing.assert_allclose(wsum, 1 + ref_w, atol=1e-6)
    acc2 = start.copy()
    splat_into(acc2, None, values, pixel, weight)  # without weight sums
    np.testing.assert_array_equal(acc2, acc)


@pytest.mark.parametrize("unique", [True, False])
def test_splat_into_kernel_matches_the_numpy_path(rng, unique):
    # the C kernel adds sample by sample in double and stores float, as numpy's scatter does: the same bits
    # where each texel has one sample, within float32 rounding where several add up
    from neural_bake.bake.maps import KERNEL, _splat_into_numpy, splat_into

    from neural_bake.nets.native import compiler

    if compiler() is None:
        pytest.skip("no C compiler: the numpy path is the only one")
    assert KERNEL.lib() is not None, KERNEL.status()  # a compiler that cannot build the kernel is a failure
    size = (64, 48)
    texels = rng.choice(size[0] * size[1], 2000, replace=not unique)
    texels = np.sort(texels) if unique else texels
    pixel = np.stack([texels // size[1], texels % size[1]], axis=1)
    values = rng.normal(size=(len(texels), 3))
    for weight in (rng.uniform(0.1, 1.0, len(texels)), None):
        start = rng.normal(size=(*size, 3)).astype(np.float32)
        acc, wsum = start.copy(), np.ones(size, np.float32)
        ref, ref_w = start.copy(), np.ones(size, np.float32)
        splat_into(acc, wsum, values, pixel, weight)
        _splat_into_numpy(ref, ref_w, values, pixel, weight, texels.astype(np.int64))
        if unique:
            np.testing.assert_array_equal(acc, ref)
            np.testing.assert_array_equal(wsum, ref_w)
        else:
            np.testing.assert_allclose(acc, ref, atol=2e-6)
            np.testing.assert_allclose(wsum, ref_w, atol=2e-6)
    with pytest.raises(NeuralBakeError, match="outside"):
        splat_into(acc, wsum, values[:1], np.array([[size[0], 0]]), None)


def test_normal_map_kernel_matches_the_numpy_path(rng):
    # sums of unit vectors, some cancelling out, some tiny, the background zero: the same map within float32 rounding
    from neural_bake.bake.maps import KERNEL, _normal_map_numpy, normal_map_from_sums

    from neural_bake.nets.native import compiler

    if compiler() is None:
        pytest.skip("no C compiler: the numpy path is the only one")
    assert KERNEL.lib() is not None, KERNEL.status()  # a compiler that cannot build the kernel is a failure
    vec = rng.normal(size=(32, 40, 3)).astype(np.float32)
    vec[:4] = 0.0
    vec[4, :5] = (1e-12, 0.0, 0.0)
    vec[5, :5] = (-3.0, 0.0, 0.0)
    ref = _normal_map_numpy(vec.copy())
    out = normal_map_from_sums(vec)
    assert out is vec
    np.testing.assert_allclose(out, ref, atol=1e-7)
    assert (out[:4] == (0.5, 0.5, 1.0)).all() and (out[4, :5] == (0.5, 0.5, 1.0)).all()
    assert (out[5, :5] == (0.0, 0.5, 0.5)).all() and out.min() >= 0 and out.max() <= 1
    n = 2 * out[6:] - 1
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-6)


# ---- tangent-space encoding: the C kernel (maps.c) against the numpy path, and analytic oracles

from neural_bake.bake import maps as maps_module  # noqa: E402
from neural_bake.bake.maps import decode_tangent_space, encode_tangent_space  # noqa: E402


def _frames(rng, m, dtype):
    """Random non-orthogonal frames and unit normals, with singular, degenerate and non-finite rows."""
    t, b, g = (rng.normal(size=(m, 3)) for _ in range(3))
    n = rng.normal(size=(m, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    b[0] = t[0]  # singular: two equal columns
    g[1] = 0.0  # a zero normal
    n[2] = np.nan  # a non-finite input
    t[3] *= 1e-6  # a short (but regular) tangent: the relative threshold keeps it
    n[4] = 0.0  # a zero normal to encode: no direction
    return tuple(v.astype(dtype) for v in (n, t, b, g))


def _numpy_encode(monkeypatch, *args, **kw):
    with monkeypatch.context() as mp:
        mp.setattr(maps_module.KERNEL, "_state", {"lib": None, "status": "off (test)"})
        assert maps_module.kernel_status() == "numpy (off (test))"
        return encode_tangent_space(*args, **kw)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("convention", ["opengl", "directx"])
def test_encode_kernel_equals_the_numpy_path(monkeypatch, rng, dtype, convention):
    if maps_module._kernel() is None:
        pytest.skip(f"no C kernel here: {maps_module.kernel_status()}")
    n, t, b, g = _frames(rng, 2000, dtype)
    fast, fast_ok = encode_tangent_space(n, t, b, g, convention)
    slow, slow_ok = _numpy_encode(monkeypatch, n, t, b, g, convention)
    np.testing.assert_array_equal(fast_ok, slow_ok)
    assert not fast_ok[[0, 1, 2, 4]].any() and fast_ok[3]
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12)  # ill-conditioned random frames: more than ulps


@pytest.mark.parametrize("numpy_path", [False, True])
def test_encode_oracles_orthonormal_frame_round_trip_and_directx(monkeypatch, rng, numpy_path):
    encode = (lambda *a: _numpy_encode(monkeypatch, *a)) if numpy_path else encode_tangent_space
    # an orthonormal frame: the coordinates are the dot products with T, B, N
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    t, b, g = (np.tile(q[:, i], (500, 1)) for i in range(3))
    n = rng.normal(size=(500, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    x, ok = encode(n, t, b, g, "opengl")
    assert ok.all()
    np.testing.assert_allclose(x, n @ q, atol=1e-12)
    xd, _ = encode(n, t, b, g, "directx")
    np.testing.assert_allclose(xd, x * [1, -1, 1], atol=0)
    # a skewed frame: decoding what was encoded gives the normal back
    n2, t2, b2, g2 = _frames(rng, 500, np.float64)
    x2, ok2 = encode(n2, t2, b2, g2, "opengl")
    back = decode_tangent_space(x2[ok2], t2[ok2], b2[ok2], g2[ok2])
    np.testing.assert_allclose(back, n2[ok2], atol=1e-9)
    np.testing.assert_array_equal(x2[~ok2], np.tile([0.0, 0.0, 1.0], ((~ok2).sum(), 1)))


def test_encoding_and_normal_map_kernels_give_the_same_bits_on_any_thread_count(monkeypatch, rng):
    # enough samples and texels to be split over the team where the kernel shares torch's OpenMP
    if maps_module._kernel() is None:
        pytest.skip(f"no C kernel here: {maps_module.kernel_status()}")
    from neural_bake.bake.maps import normal_map_from_sums

    n, t, b, g = _frames(rng, 40_000, np.float64)
    vec = rng.normal(size=(150, 200, 3)).astype(np.float32)
    vec[:5] = 0.0
    out = {}
    for k in (1, 2):
        monkeypatch.setattr(maps_module, "threads", lambda k=k: k)
        out[k] = (*encode_tangent_space(n, t, b, g), normal_map_from_sums(vec.copy()))
    for a, c in zip(out[1], out[2]):
        np.testing.assert_array_equal(a, c)
