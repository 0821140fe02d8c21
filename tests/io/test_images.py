"""read_image / write_image: round trips per format and bit depth, colour handling, errors."""

import numpy as np
import pytest

from neural_bake.errors import ImageError
from neural_bake.io.colour import linear_to_srgb, srgb_to_linear
from neural_bake.io.images import read_image, write_image


def _ramp(h=6, w=7, c=3, rng=None):
    rng = rng or np.random.default_rng(0)
    return rng.random((h, w, c)).astype(np.float32)


@pytest.mark.parametrize(
    "ext,bits,tol",
    [
        (".png", 8, 0.5 / 255),
        (".png", 16, 0.5 / 65535),
        (".tif", 8, 0.5 / 255),
        (".tif", 16, 0.5 / 65535),
        (".tiff", 32, 0.0),
        (".exr", 16, 1e-3),
        (".exr", 32, 0.0),
    ],
)
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_round_trip_data(tmp_path, ext, bits, tol, channels):
    a = _ramp(c=channels)
    p = write_image(tmp_path / f"a{ext}", a, colour="data", bits=bits)
    b = read_image(p, colour="data")
    assert b.dtype == np.float32 and b.shape == a.shape
    # stored values (before any decoding) are within half a quantisation step
    assert np.abs(b - a).max() <= tol + 1e-7


def test_jpeg_round_trip_is_close(tmp_path):
    # smooth image: JPEG is lossy, but a gentle gradient survives within a few levels
    y, x = np.mgrid[0:32, 0:32] / 31.0
    a = np.stack([x, y, 0.5 * (x + y)], axis=-1).astype(np.float32)
    write_image(tmp_path / "a.jpg", a, colour="data")
    b = read_image(tmp_path / "a.jpg", colour="data")
    assert b.shape == (32, 32, 3)
    assert np.abs(b - a).mean() < 0.01


def test_row_zero_is_top_and_channel_order(tmp_path):
    a = np.zeros((4, 3, 3), np.float32)
    a[0, :, 0] = 1.0  # top row red
    a[-1, :, 2] = 1.0  # bottom row blue
    write_image(tmp_path / "t.png", a, colour="data")
    b = read_image(tmp_path / "t.png", colour="data")
    np.testing.assert_array_equal(b, a)


def test_auto_png_is_srgb_both_ways(tmp_path):
    lin = np.full((2, 2, 3), srgb_to_linear(np.float32(128 / 255)), np.float32)  # 8-bit sRGB level 128
    write_image(tmp_path / "c.png", lin)  # auto: encode
    raw = read_image(tmp_path / "c.png", colour="data")
    np.testing.assert_allclose(raw, np.round(linear_to_srgb(lin) * 255) / 255, atol=1e-6)
    assert abs(float(raw[0, 0, 0]) - 128 / 255) < 1e-6
    back = read_image(tmp_path / "c.png")  # auto: decode
    np.testing.assert_allclose(back, srgb_to_linear(raw), atol=1e-6)
    np.testing.assert_allclose(back, lin, atol=1e-6)


def test_auto_exr_is_linear(tmp_path):
    hdr = np.array([[[0.2, 1.5, 4.0]]], np.float32)  # values above 1 survive in float files
    write_image(tmp_path / "h.exr", hdr, bits=32)
    np.testing.assert_array_equal(read_image(tmp_path / "h.exr"), hdr)
    np.testing.assert_array_equal(read_image(tmp_path / "h.exr", colour="linear"), hdr)


def test_srgb_leaves_alpha_alone(tmp_path):
    a = np.zeros((1, 2, 4), np.float32)
    a[..., :3] = 0.5
    a[..., 3] = [0.25, 0.75]
    write_image(tmp_path / "a.png", a, colour="srgb", bits=16)
    raw = read_image(tmp_path / "a.png", colour="data")
    np.testing.assert_allclose(raw[..., 3], [[0.25, 0.75]], atol=1e-4)
    np.testing.assert_allclose(raw[..., :3], linear_to_srgb(np.float32(0.5)), atol=1e-4)
    dec = read_image(tmp_path / "a.png", colour="srgb")
    np.testing.assert_allclose(dec, a, atol=1e-4)


def test_integer_write_clips(tmp_path):
    a = np.array([[[-0.5, 0.5, 2.0]]], np.float32)
    write_image(tmp_path / "c.png", a, colour="data")
    np.testing.assert_allclose(read_image(tmp_path / "c.png", colour="data"), [[[0.0, 128 / 255, 1.0]]], atol=1e-6)


def test_two_dimensional_array_is_grey(tmp_path):
    write_image(tmp_path / "g.png", np.eye(3, dtype=np.float32), colour="data")
    b = read_image(tmp_path / "g.png", colour="data")
    assert b.shape == (3, 3, 1)
    np.testing.assert_array_equal(b[..., 0], np.eye(3))


def test_overwrite_keeps_no_temporaries(tmp_path):
    write_image(tmp_path / "x.png", np.zeros((2, 2, 3)))
    write_image(tmp_path / "x.png", np.ones((2, 2, 3)))
    assert sorted(q.name for q in tmp_path.iterdir()) == ["x.png"]
    assert read_image(tmp_path / "x.png").min() == 1.0


# --- errors -------------------------------------------------------------------------------------------------


def test_read_missing(tmp_path):
    with pytest.raises(ImageError, match=r"nope\.png: no such image file"):
        read_image(tmp_path / "nope.png")


def test_read_unknown_format(tmp_path):
    (tmp_path / "a.xyz").write_bytes(b"123")
    with pytest.raises(ImageError, match=r"a\.xyz: unknown image format '\.xyz'"):
        read_image(tmp_path / "a.xyz")


def test_read_corrupt(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"this is not a png")
    with pytest.raises(ImageError, match=r"bad\.png: unreadable image"):
        read_image(tmp_path / "bad.png")


def test_read_directory(tmp_path):
    (tmp_path / "d.png").mkdir()
    with pytest.raises(ImageError, match=r"d\.png: not a file"):
        read_image(tmp_path / "d.png")


def test_bad_colour_argument(tmp_path):
    with pytest.raises(ValueError, match="colour must be one of"):
        read_image(tmp_path / "x.png", colour="rgb")
    with pytest.raises(ValueError, match="colour must be one of"):
        write_image(tmp_path / "x.png", np.zeros((2, 2, 3)), colour="rgb")


@pytest.mark.parametrize("shape", [(4,), (2, 2, 5), (0, 3, 3), (2, 2, 2, 2)])
def test_write_bad_shape(tmp_path, shape):
    with pytest.raises(ValueError, match=r"array must be \(H, W\) or \(H, W, C\) with C in 1\.\.4"):
        write_image(tmp_path / "x.png", np.zeros(shape))
    assert not list(tmp_path.iterdir())


def test_write_non_finite(tmp_path):
    a = np.zeros((2, 2, 3))
    a[0, 0, 1] = np.nan
    with pytest.raises(ValueError, match="1 non-finite values"):
        write_image(tmp_path / "x.exr", a)
    assert not list(tmp_path.iterdir())


def test_write_unknown_format_and_bits(tmp_path):
    with pytest.raises(ImageError, match=r"x\.gif: unknown image format '\.gif'"):
        write_image(tmp_path / "x.gif", np.zeros((2, 2, 3)))
    with pytest.raises(ImageError, match=r"x\.jpg: cannot write 16-bit \.jpg"):
        write_image(tmp_path / "x.jpg", np.zeros((2, 2, 3)), bits=16)
    with pytest.raises(ImageError, match=r"x\.exr: cannot write 8-bit \.exr"):
        write_image(tmp_path / "x.exr", np.zeros((2, 2, 3)), bits=8)
    with pytest.raises(ImageError, match=r"x\.jpg: JPEG has no alpha channel"):
        write_image(tmp_path / "x.jpg", np.zeros((2, 2, 4)))
    assert not list(tmp_path.iterdir())


def test_write_missing_folder(tmp_path):
    with pytest.raises(ImageError, match=r"folder .*nowhere does not exist"):
        write_image(tmp_path / "nowhere" / "x.png", np.zeros((2, 2, 3)))


@pytest.mark.parametrize("channels", [1, 3])
def test_fast_png_holds_the_same_pixels_with_faster_settings(tmp_path, channels):
    # a smooth image (as error maps are), where the compression level decides the size
    y, x = np.mgrid[0:256, 0:256] / 255.0
    a = np.stack([x, y, x * y][:channels], axis=-1).astype(np.float32)
    small = read_image(write_image(tmp_path / "small.png", a, colour="data"), colour="data")
    fast_path = write_image(tmp_path / "fast.png", a, colour="data", fast=True)
    np.testing.assert_array_equal(read_image(fast_path, colour="data"), small)
    # the settings reach the encoder: another compressed stream for the same pixels
    assert fast_path.read_bytes() != (tmp_path / "small.png").read_bytes()


def _png_row_filters(path) -> set[int]:
    """The filter type byte of every row of an 8-bit PNG (its IDAT stream inflated)."""
    import struct
    import zlib

    data = path.read_bytes()
    at, idat, width, channels = 8, b"", 0, 0
    while at < len(data):
        (length,), kind = struct.unpack(">I", data[at: at + 4]), data[at + 4: at + 8]
        body = data[at + 8: at + 8 + length]
        if kind == b"IHDR":
            width, colour_type = struct.unpack(">I", body[:4])[0], body[9]
            channels = {0: 1, 2: 3, 4: 2, 6: 4}[colour_type]
        elif kind == b"IDAT":
            idat += body
        at += 12 + length
    raw = zlib.decompress(idat)
    stride = 1 + width * channels
    return {raw[i] for i in range(0, len(raw), stride)}


@pytest.mark.parametrize("fast,filter_type", [(False, 4), (True, 1)])  # Paeth, or Sub for a fast PNG
def test_png_rows_take_one_filter(tmp_path, fast, filter_type):
    # libpng is told which row filter to use (module constants), not left to try all five per row
    a = _ramp(40, 50, 3)
    path = write_image(tmp_path / "f.png", a, colour="data", fast=fast)
    assert _png_row_filters(path) == {filter_type}
    np.testing.assert_allclose(read_image(path, colour="data"), a, atol=0.5 / 255)
