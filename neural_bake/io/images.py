"""Image files through OpenImageIO: PNG, JPEG, EXR and TIFF, 8-bit, 16-bit, half and float.

Arrays are (H, W, C) with row 0 the *top* row of the image as stored in the file, C = 1 (grey), 2 (grey +
alpha), 3 (RGB) or 4 (RGBA, straight alpha).

Colour handling (docs/design.md, "Colour"): the toolkit computes in linear RGB.

- ``colour="srgb"``: the colour channels are sRGB-encoded in the file; read decodes them to linear,
  write encodes linear values to sRGB. Alpha (channel 2 of 2, channel 4 of 4) is never converted.
- ``colour="linear"`` or ``"data"``: values are stored as they are (normal maps, masks, HDR colour).
- ``colour="auto"``: integer files (8/16-bit PNG, JPEG, TIFF) are sRGB colour, float files (half/float
  EXR or TIFF) are linear. This matches what image editors and glTF assume for base-colour textures.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import ImageError
from .atomic import atomic_path
from .colour import linear_to_srgb, srgb_to_linear

__all__ = ["read_image", "write_image", "READ_FORMATS", "WRITE_FORMATS"]

#: Extensions :func:`read_image` accepts (any case).
READ_FORMATS = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".tga", ".bmp", ".hdr")
#: Extension -> bit depths :func:`write_image` can write (16 for EXR is half float, 32 is float).
WRITE_FORMATS = {
    ".png": (8, 16),
    ".jpg": (8,),
    ".jpeg": (8,),
    ".tif": (8, 16, 32),
    ".tiff": (8, 16, 32),
    ".exr": (16, 32),
}
_COLOURS = ("auto", "srgb", "linear", "data")


def _check_colour(colour: str, func: str) -> None:
    if colour not in _COLOURS:
        raise ValueError(f"{func}: colour must be one of {_COLOURS}, got {colour!r}")


def _colour_channels(c: int) -> int:
    """How many leading channels carry colour (the rest is alpha): 1 of 1-2, 3 of 3-4."""
    return 1 if c <= 2 else 3


def read_image(path: str | os.PathLike, *, colour: str = "auto") -> np.ndarray:
    """Read an image file into a (H, W, C) float32 array, row 0 = top row.

    - ``path``: a PNG, JPEG, EXR, TIFF (also TGA, BMP, HDR) file; the first sub-image, full resolution.
    - ``colour``: "auto", "srgb", "linear" or "data" (see the module docstring). Integer formats are
      normalised to [0, 1] (8-bit v / 255, 16-bit v / 65535) before any decoding.

    Returns float32 (H, W, C), C the file's channel count. Raises :class:`ImageError` naming the file when
    it is missing, of an unknown format (extension) or unreadable.
    """
    _check_colour(colour, "read_image")
    p = Path(path)
    if not p.is_file():
        raise ImageError(f"{p}: no such image file" if not p.exists() else f"{p}: not a file")
    if p.suffix.lower() not in READ_FORMATS:
        raise ImageError(f"{p}: unknown image format {p.suffix!r} (expected one of {', '.join(READ_FORMATS)})")
    import OpenImageIO as oiio

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # straight alpha: no premultiplication on read
    inp = oiio.ImageInput.open(str(p), config)
    if inp is None:
        raise ImageError(f"{p}: unreadable image ({_oiio_error(oiio)})")
    try:
        spec = inp.spec()
        nch = int(spec.nchannels)
        is_float = spec.format.basetype in (oiio.HALF, oiio.FLOAT, oiio.DOUBLE)
        pixels = inp.read_image(0, 0, 0, nch, "float")
        if pixels is None or (isinstance(pixels, np.ndarray) and pixels.size == 0):
            raise ImageError(f"{p}: unreadable image ({_oiio_error(oiio)})")
    finally:
        inp.close()
    arr = np.asarray(pixels, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[0] != spec.height or arr.shape[1] != spec.width:
        raise ImageError(f"{p}: unreadable image (got pixel array of shape {arr.shape})")
    if colour == "srgb" or (colour == "auto" and not is_float):
        k = _colour_channels(arr.shape[2])
        arr = arr.copy()
        arr[..., :k] = srgb_to_linear(arr[..., :k])
    return np.ascontiguousarray(arr, dtype=np.float32)


def write_image(
    path: str | os.PathLike,
    array: np.ndarray,
    *,
    colour: str = "auto",
    bits: int | None = None,
    fast: bool = False,
) -> Path:
    """Write a (H, W) or (H, W, C) image atomically (through :func:`atomic_path`); return the path.

    - ``array``: float values, row 0 = top row, C in 1..4 (grey, grey+alpha, RGB, RGBA). All finite.
    - ``colour``: "srgb" encodes the colour channels from linear to sRGB; "linear"/"data" writes values as
      they are (normal maps: map to [0, 1] first); "auto" encodes sRGB for integer outputs and keeps float
      outputs linear, so ``read_image(write_image(p, a))`` gives back ``a`` up to quantisation.
    - ``bits``: 8 or 16 (integer PNG / TIFF; JPEG is 8 only), 16 (half) or 32 (float) for EXR, 32 for a
      float TIFF. Default: 8 for PNG, JPEG and TIFF, 16 (half) for EXR. Integer outputs are clipped to
      [0, 1] and rounded to the nearest level.
    - ``fast``: a PNG compressed for speed (zlib level 1, the "sub" row filter: several times faster to write,
      somewhat larger) — for images only a report reads; other formats ignore it. Other PNGs are written at
      zlib level 3 (:data:`_PNG_LEVEL`).

    Raises :class:`ImageError` naming the file for an unknown format, an unsupported bit depth, alpha in a
    JPEG or a missing folder, ``ValueError`` for a bad array shape or non-finite values, and an ``OSError``
    naming the file and its cause (no space left, a quota, a file-size limit) when the system refuses the
    write.
    """
    _check_colour(colour, "write_image")
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in WRITE_FORMATS:
        raise ImageError(f"{p}: unknown image format {p.suffix!r} (can write {', '.join(WRITE_FORMATS)})")
    if bits is None:
        bits = 16 if ext == ".exr" else 8
    if bits not in WRITE_FORMATS[ext]:
        raise ImageError(f"{p}: cannot write {bits}-bit {ext} (bits must be one of {WRITE_FORMATS[ext]})")
    arr = np.asarray(array)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or not 1 <= arr.shape[2] <= 4 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(
            f"write_image: array must be (H, W) or (H, W, C) with C in 1..4 and H, W > 0, got shape {np.shape(array)}"
        )
    if arr.dtype.kind not in "fiub":
        raise ValueError(f"write_image: array must be numeric, got dtype {arr.dtype}")
    arr = arr.astype(np.float32)
    if not np.isfinite(arr).all():
        raise ValueError(f"write_image: array has {int((~np.isfinite(arr)).sum())} non-finite values ({p.name})")
    if ext in (".jpg", ".jpeg") and arr.shape[2] in (2, 4):
        raise ImageError(f"{p}: JPEG has no alpha channel (write PNG, or drop the alpha channel)")
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.is_dir():
        raise ImageError(f"{p}: folder {folder} does not exist")
    is_float = bits == 32 or ext == ".exr"
    if colour == "srgb" or (colour == "auto" and not is_float):
        k = _colour_channels(arr.shape[2])
        arr = arr.copy()
        arr[..., :k] = linear_to_srgb(arr[..., :k])
    import OpenImageIO as oiio

    if is_float:
        fmt, data = ("half", arr.astype(np.float16)) if bits == 16 else ("float", arr)
    elif bits == 8:
        fmt, data = "uint8", np.round(np.clip(arr, 0.0, 1.0) * 255.0).astype(np.uint8)
    else:
        fmt, data = "uint16", np.round(np.clip(arr, 0.0, 1.0) * 65535.0).astype(np.uint16)
    h, w, c = data.shape
    if ext in (".jpg", ".jpeg"):
        # Pillow (which imageio brings): libjpeg under OpenImageIO ends the process on a failed write
        from PIL import Image

        with atomic_path(p) as tmp:
            Image.fromarray(data[..., 0] if c == 1 else data).save(tmp, format="JPEG", quality=95)
        return p
    with atomic_path(p) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise ImageError(f"{p}: cannot write image ({_oiio_error(oiio)})")
        spec = oiio.ImageSpec(w, h, c, fmt)
        spec.attribute("oiio:UnassociatedAlpha", 1)  # our alpha is straight: store it as is
        if ext == ".exr":
            spec.attribute("compression", "zip")
        if fast and ext == ".png":
            spec.attribute("png:compressionLevel", _FAST_PNG_LEVEL)
            spec.attribute("png:filter", _PNG_FILTER_SUB)
        elif ext == ".png":
            spec.attribute("png:compressionLevel", _PNG_LEVEL)
            spec.attribute("png:filter", _PNG_FILTER_PAETH)
        try:
            ok = out.open(str(tmp), spec) and out.write_image(np.ascontiguousarray(data))
            # some writers (PNG) report a short write only through geterror(), not through their return value;
            # read before close(), whose own messages (TIFF's Exif directory) are not failures
            reason = " ".join(str(out.geterror() or "").split())
        finally:
            closed = out.close()
        failed = not (ok and closed) or bool(reason) or tmp.stat().st_size == 0
        # a writer that flushes on close may lose its last bytes to a full disk and still report success
        if failed or _no_free_block(tmp.parent):
            cause = _write_failure_cause(tmp.parent)
            if cause is not None:
                raise OSError(cause, os.strerror(cause), str(p))
            if failed:
                raise ImageError(f"{p}: cannot write image ({reason or _oiio_error(oiio)})")
    return p


#: zlib level of every other PNG: a 2048² normal map writes in half the time of zlib's default level 6 (0.20 s
#: against 0.41 s) for a file about a fifth larger (Blender's default PNG compression, 15 %, is level 1).
_PNG_LEVEL = 3

#: libpng's row filter of every other PNG: Paeth alone (PNG_FILTER_PAETH) instead of libpng's choice among all
#: five per row. A baked 2048² normal map writes in 0.16 s against 0.27 s, the same 1.42 MB; the data folder's
#: colour, normal and ARM textures (1024², doubled to 2048²) 30–40 % faster, within 1 % of the size.
_PNG_FILTER_PAETH = 128

#: zlib level and libpng row filter (PNG_FILTER_SUB) of a ``fast`` PNG.
_FAST_PNG_LEVEL = 1
_PNG_FILTER_SUB = 16


def _oiio_error(oiio) -> str:
    msg = " ".join(str(oiio.geterror() or "").split())
    return msg or "OpenImageIO gave no reason"


#: Bytes the probe of :func:`_write_failure_cause` writes: more than a file system keeps in reserve per write.
_PROBE_BYTES = 1 << 16


def _no_free_block(folder: Path) -> bool:
    try:
        return os.statvfs(folder).f_bavail == 0
    except OSError:
        return False


def _write_failure_cause(folder: Path) -> int | None:
    """The errno behind a write OpenImageIO could not finish in ``folder`` (it reports none): the errno of a
    small probe write there (ENOSPC, EDQUOT, EFBIG, EIO…), else None (the writer failed for a reason of its
    own)."""
    import tempfile

    try:
        with tempfile.TemporaryFile(dir=folder) as fh:
            fh.write(b"\0" * _PROBE_BYTES)
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:
        return exc.errno
    return None
