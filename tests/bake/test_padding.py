"""Chart padding: covered texels untouched, background near charts filled from the charts, limits, errors."""

import numpy as np
import pytest

from neural_bake.bake import padding as padding_module
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


def _pull_push_reference(img, covered):
    """The pull-push pyramid written plainly in float64 numpy: 2×2 sums of (premultiplied colour, weight),
    weights clamped to 1; pushed down by bilinear ×2 upsampling with replicated borders."""
    levels = [(img.astype(np.float64) * covered[:, :, None], covered.astype(np.float64))]
    while max(levels[-1][1].shape) > 1:
        c, w = levels[-1]
        c = np.pad(c, ((0, c.shape[0] % 2), (0, c.shape[1] % 2), (0, 0)))
        w = np.pad(w, ((0, w.shape[0] % 2), (0, w.shape[1] % 2)))
        c2 = c[0::2, 0::2] + c[1::2, 0::2] + c[0::2, 1::2] + c[1::2, 1::2]
        w2 = w[0::2, 0::2] + w[1::2, 0::2] + w[0::2, 1::2] + w[1::2, 1::2]
        avg = np.divide(c2, w2[:, :, None], out=np.zeros_like(c2), where=w2[:, :, None] > 0)
        wn = np.minimum(w2, 1.0)
        levels.append((avg * wn[:, :, None], wn))

    def up(a, axis):
        a = np.moveaxis(a, axis, 0)
        p = np.concatenate([a[:1], a, a[-1:]], axis=0)
        out = np.empty((2 * a.shape[0], *a.shape[1:]))
        out[0::2] = 0.75 * p[1:-1] + 0.25 * p[:-2]
        out[1::2] = 0.75 * p[1:-1] + 0.25 * p[2:]
        return np.moveaxis(out, 0, axis)

    c, w = levels[-1]
    cur = np.divide(c, w[:, :, None], out=np.zeros_like(c), where=w[:, :, None] > 0)
    for c, w in reversed(levels[:-1]):
        h, wd = w.shape
        upsampled = up(up(cur, 0)[:h], 1)[:, :wd]
        own = np.divide(c, w[:, :, None], out=np.zeros_like(c), where=w[:, :, None] > 0)
        a = np.clip(w, 0.0, 1.0)[:, :, None]
        cur = a * own + (1 - a) * upsampled
    return cur


def _without_kernel(monkeypatch):
    monkeypatch.setattr(padding_module.KERNEL, "_state", {"lib": None, "status": "off (test)"})
    assert padding_module.kernel_status() == "numpy (off (test))"


def _need_kernel():
    from neural_bake.nets.native import compiler

    if compiler() is None:
        pytest.skip(f"no C kernel here: {padding_module.kernel_status()}")


@pytest.mark.parametrize("path", ["kernel", "torch"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(40, 50), (37, 23), (1, 9)])  # even, odd and one-row sizes
def test_pull_push_matches_the_plain_reference(monkeypatch, rng, path, dtype, shape):
    from neural_bake.bake.padding import _pull_push

    if path == "kernel":
        _need_kernel()
    else:
        _without_kernel(monkeypatch)
    img = rng.uniform(0, 1, size=(*shape, 3)).astype(dtype)
    cov = rng.uniform(size=shape) < 0.1
    cov[0, 0] = True
    out = _pull_push(img, cov)
    assert out.dtype == dtype and out.shape == img.shape
    tol = 1e-5 if dtype == np.float32 else 1e-12
    # where the pyramid filled, its values; the covered texels keep their own
    assert np.allclose(out[~cov], _pull_push_reference(img, cov)[~cov], atol=tol)
    np.testing.assert_array_equal(out[cov], img[cov])


def _charts(rng, shape, n):
    cov = np.zeros(shape, bool)
    for _ in range(n):
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        cov[r: r + rng.integers(1, 12), c: c + rng.integers(1, 12)] = True
    return cov


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(64, 48), (33, 71), (1, 1), (1, 17), (29, 1)])
def test_pull_push_kernel_equals_the_torch_path(monkeypatch, rng, dtype, shape):
    """The C pull-push against torch's at every texel: within a few ulps (the two sum and divide in
    different orders)."""
    from neural_bake.bake.padding import _pull_push_torch

    _need_kernel()
    img = rng.uniform(-1, 1, size=(*shape, 4)).astype(dtype)
    cov = _charts(rng, shape, 6)
    cov.reshape(-1)[0] = True
    fast = padding_module._pull_push(img, cov)
    slow = _pull_push_torch(img, cov)
    assert fast.dtype == slow.dtype == dtype and fast.shape == slow.shape
    np.testing.assert_allclose(fast[~cov], slow[~cov], rtol=0, atol=4 * np.finfo(dtype).eps)
    np.testing.assert_array_equal(fast[cov], img[cov])  # the covered texels keep their own values


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("steps", [1, 3, 40])  # 40: past the last empty texel
@pytest.mark.parametrize("shape", [(37, 53), (211, 190)])  # the second large enough for the first ring's team
def test_dilate_kernel_equals_the_numpy_path_bit_for_bit(rng, dtype, steps, shape):
    _need_kernel()
    img = rng.uniform(0, 1, size=(*shape, 3)).astype(dtype)
    cov = _charts(rng, img.shape[:2], 5 if shape[0] < 100 else 120)
    fast, slow = img.copy(), img.copy()
    padding_module._dilate(fast, cov, steps)
    padding_module._dilate_numpy(slow, cov, steps)
    np.testing.assert_array_equal(fast, slow)
    assert cov.sum() < cov.size and not np.array_equal(fast, img)  # a case with something to fill


@pytest.mark.parametrize("method,pixels", [("pull-push", None), ("pull-push", 3), ("dilate", None), ("dilate", 2)])
def test_pad_charts_the_same_with_and_without_the_kernel(monkeypatch, rng, method, pixels):
    """The whole padding by the C kernel and by torch and numpy: covered texels kept bit for bit, the rest
    within float32 ulps (pull-push) or equal (dilation)."""
    _need_kernel()
    img = rng.uniform(0, 1, size=(50, 61, 3)).astype(np.float32)
    cov = _charts(rng, img.shape[:2], 8)
    fast = pad_charts(img, cov, method=method, pixels=pixels)
    with monkeypatch.context() as mp:
        _without_kernel(mp)
        slow = pad_charts(img, cov, method=method, pixels=pixels)
    np.testing.assert_array_equal(fast[cov], img[cov])
    np.testing.assert_allclose(fast, slow, rtol=0, atol=4 * np.finfo(np.float32).eps)
    if method == "dilate":
        np.testing.assert_array_equal(fast, slow)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_pull_push_kernel_gives_the_same_bits_on_any_thread_count(monkeypatch, rng, dtype):
    # a map whose first levels are split over the team (where it shares torch's OpenMP): every texel as on one thread
    _need_kernel()
    img = rng.uniform(-1, 1, size=(301, 259, 4)).astype(dtype)
    cov = _charts(rng, (301, 259), 30)
    out = {}
    for n in (1, 2):
        monkeypatch.setattr(padding_module, "threads", lambda n=n: n)
        out[n] = padding_module._pull_push(img, cov)
    np.testing.assert_array_equal(out[1], out[2])
