"""Chart padding: covered texels untouched, background near charts filled from the charts, limits, errors."""

import numpy as np
import pytest

from neural_bake.bake.padding import pad_charts
from neural_bake.errors import NeuralBakeError
from neural_bake.io.colour import sample_texture


def _two_charts(rng):
    img = np.zeros((40, 50, 3), dtype=np.float32)
    cov = np.zeros((40, 50), dtype=bool)
    cov[5:15, 5:20] = True
    cov[25:35, 30:45] = True
    img[5:15, 5:20] = (1.0, 0.0, 0.0)
    img[25:35, 30:45] = rng.uniform(0.2, 0.8, size=(10, 15, 3))
    return img, cov


@pytest.mark.parametrize("method", ["pull-push", "dilate"])
def test_covered_texels_unchanged_and_background_filled(method, rng):
    img, cov = _two_charts(rng)
    out = pad_charts(img, cov, method=method, pixels=4)
    assert out.dtype == img.dtype and out.shape == img.shape
    assert np.array_equal(out[cov], img[cov])
    # the ring of 1..4 texels around the constant red chart is red (its nearest chart)
    ring = np.zeros_like(cov)
    ring[1:19, 1:24] = True
    ring[5:15, 5:20] = False
    assert np.allclose(out[ring], (1.0, 0.0, 0.0), atol=1e-6)
    # beyond the limit: background left as it was
    assert np.array_equal(out[0:1, :], img[0:1, :]) and np.array_equal(out[:, 49], img[:, 49])
    # values stay within the covered range (no overshoot)
    assert out.min() >= 0.0 and out.max() <= 1.0


def test_pull_push_fills_everything_by_default(rng):
    img, cov = _two_charts(rng)
    out = pad_charts(img, cov)
    assert np.isfinite(out).all()
    far = ~cov
    assert (out[far].sum(axis=1) > 0).all()  # every background texel got some chart's colour


def test_bilinear_lookup_at_chart_border_does_not_see_background(rng):
    img, cov = _two_charts(rng)
    out = pad_charts(img, cov, method="dilate", pixels=2)
    # a UV exactly on the red chart's left edge (between texel 4 and 5 of row 10) reads pure red
    h, w = cov.shape
    uv = np.array([[5.0 / w, 1 - 10.5 / h]])
    assert np.allclose(sample_texture(out, uv, "clamp"), (1.0, 0.0, 0.0), atol=1e-6)
    assert not np.allclose(sample_texture(img, uv, "clamp"), (1.0, 0.0, 0.0), atol=1e-3)


def test_grey_image_and_edge_cases():
    img = np.zeros((8, 8), dtype=np.float64)
    cov = np.zeros((8, 8))
    cov[3, 3] = 0.5  # fractional coverage counts as covered
    img[3, 3] = 0.7
    out = pad_charts(img, cov)
    assert out.shape == (8, 8) and np.allclose(out, 0.7)
    empty = pad_charts(img, np.zeros((8, 8)))
    assert np.array_equal(empty, img)
    assert np.array_equal(pad_charts(img, cov, pixels=0), img)


def test_errors():
    img = np.zeros((4, 4, 3))
    with pytest.raises(NeuralBakeError, match="padding method must be one of"):
        pad_charts(img, np.ones((4, 4)), method="blur")
    with pytest.raises(NeuralBakeError, match="coverage shape"):
        pad_charts(img, np.ones((3, 4)))
    with pytest.raises(NeuralBakeError, match="padding pixels must be a non-negative integer"):
        pad_charts(img, np.ones((4, 4)), pixels=-1)
    with pytest.raises(NeuralBakeError, match="image must be"):
        pad_charts(np.zeros((4, 4, 3, 1)), np.ones((4, 4)))
