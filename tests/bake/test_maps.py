"""Splatting samples into a map: the scatter of one sample per texel and the weighted sums of several agree
with a per-sample reference."""

import numpy as np
import pytest

from neural_bake.bake.maps import splat


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
