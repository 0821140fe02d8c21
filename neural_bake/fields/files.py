"""One reader and one writer for every field file: ``load_field(path)`` returns the right type from the
file's header, ``save_field(field, path)`` writes any field atomically.

Two containers exist, both safetensors with a JSON header (no pickle; loading never runs code from a file):
``neural_bake.model`` (one network, :mod:`neural_bake.nets.model_io`; ``metadata.kind`` says what it is) and
``neural_bake.nested`` (a nested sequence, :mod:`neural_bake.fields.nested`). A reader is registered per
``kind`` (:func:`register_kind`): ``"sdf"`` → :class:`SdfField`, ``"texture"`` → :class:`TextureField`,
``"nested"`` → :class:`NestedSequence`. A kind fixes the networks' inputs, for every reader of the file: an
``"sdf"`` takes (x, y, z); a space-time SDF (x, y, z, t) is kind ``"spacetime_sdf"``
(:mod:`neural_bake.fields.spacetime`) with its time range, and a nested sequence of 4-input levels carries the
same time mapping. A field of another nature registers its own kind and callers of :func:`load_field` do not
change. Every header value is checked before anything is allocated: one-line :class:`ModelFileError` naming
the file and the field.

:func:`save_model` and :func:`load_model` write and read one network with its metadata as saved, whatever its
kind: ``load_model`` is for a reader that takes any network (range analysis) or checks the header itself (a
space-time fit's record); every other reader takes a field from :func:`load_field`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..errors import ModelFileError
from ..nets.model_io import load_model
from .header import check_delta, check_frame
from .nested import NESTED_FORMAT, NESTED_FORMAT_VERSION, NestedSequence, nested_tensors, read_nested
from .sdf import SdfField
from .texture import ENCODINGS, TextureField

__all__ = ["load_field", "save_field", "save_model", "load_model", "load_sdf_field", "to_sdf_field", "register_kind",
           "FieldKind", "KINDS", "BARE_NETWORK_HINT", "fit_records"]

#: What to do with a file holding a network without a kind (``save_model(model, path)`` with no metadata).
BARE_NETWORK_HINT = ("save a fitted SDF with SdfFit.save(path) (what `neural-bake fit sdf` writes), or a "
                     "network with the frame it was fitted in with "
                     "save_field(SdfField.from_model(model, frame=mesh.frame), path)")


@dataclass(frozen=True)
class FieldKind:
    """A registered kind of field file: its ``container`` format and the reader that builds the field from a
    checked header (``read(path, header, device=, dtype=)``)."""

    kind: str
    container: str
    read: Callable
    cls: type


KINDS: dict[str, FieldKind] = {}


def register_kind(kind: str, container: str, read: Callable, cls: type) -> None:
    """Register the reader of a ``kind`` of field file (e.g. a space-time SDF) so :func:`load_field` reads it."""
    KINDS[kind] = FieldKind(kind, container, read, cls)


def load_field(path: str | os.PathLike, *, device=None, dtype=None):
    """Read any field file: an :class:`SdfField`, a :class:`TextureField` or a :class:`NestedSequence`.

    Args:
        path: the file (``fit sdf``, ``fit texture`` or ``fit nested`` output, or :func:`save_field`'s).
        device, dtype: where and in which float dtype to put the networks (default CPU, the stored dtype).

    Raises:
        ModelFileError: missing, unreadable, corrupt or truncated file; a header with an unknown kind, an
            architecture beyond the caps, a non-finite or non-positive frame scale, a centre that is not a
            finite 3-vector, a negative or non-numeric δ, JSON nested too deep; a bare network without kind.
    """
    from ..nets.model_io import (MODEL_FORMAT, check_version, parse_header, read_model_metadata,
                                 read_raw_metadata)

    path = Path(path)
    raw = read_raw_metadata(path)
    fmt = raw.get("format")
    if fmt == MODEL_FORMAT:
        header = read_model_metadata(path)
        kind = header["metadata"].get("kind")
        if kind is None:
            raise ModelFileError(f"{path}: a bare network without kind or frame; {BARE_NETWORK_HINT}")
    elif fmt == NESTED_FORMAT and "neural_bake" in raw:
        header = parse_header(raw["neural_bake"], path)
        check_version(header, NESTED_FORMAT_VERSION, path)
        kind = header.get("kind", "nested")  # files of the first release have no kind
    else:
        raise ModelFileError(f"{path}: a safetensors file but not a neural_bake field (format {fmt!r:.40})")
    entry = KINDS.get(kind) if isinstance(kind, str) else None
    if entry is None or entry.container != fmt:
        known = ", ".join(sorted(KINDS))
        raise ModelFileError(f"{path}: unknown kind {kind!r:.40} (this neural_bake reads {known})")
    return entry.read(path, header, device=device, dtype=dtype)


def fit_records(path: str | os.PathLike) -> list[dict]:
    """The fits a field file records, from its header alone (no network is loaded): ``[{"fit": "fine" |
    "level" | "model", "level": i or None, "width", "depth", "training": its record (steps, seconds, history,
    budget, …)}]``: a nested sequence's fine fit (when it keeps one) and each level's distillation, or a model
    file's training. Raises :class:`ModelFileError` for a file that is not a field file."""
    from ..nets.model_io import MODEL_FORMAT, parse_header, read_model_metadata, read_raw_metadata

    path = Path(path)
    raw = read_raw_metadata(path)
    if raw.get("format") == NESTED_FORMAT and "neural_bake" in raw:
        header = parse_header(raw["neural_bake"], path)
        out = []
        fine = (header.get("metadata") or {}).get("fine_training")
        if isinstance(fine, dict):
            out.append({"fit": "fine", "level": None, "width": None, "depth": None, "training": fine})
        for i, info in enumerate(header.get("levels_info") or []):
            if isinstance(info, dict):
                out.append({"fit": "level", "level": i, "width": info.get("width"), "depth": info.get("depth"),
                            "training": info})
        return out
    if raw.get("format") != MODEL_FORMAT:
        raise ModelFileError(f"{path}: a safetensors file but not a neural_bake field")
    meta = read_model_metadata(path).get("metadata") or {}
    return [{"fit": "model", "level": None, "width": None, "depth": None, "training": meta.get("training") or {}}]


def to_sdf_field(field, *, band_level: int = 0) -> SdfField:
    """A static :class:`SdfField` to bake or fit a texture with: an SdfField itself, or a nested sequence's
    fine f with the band δ of ``band_level`` (:meth:`NestedSequence.band_field`)."""
    name = getattr(field, "name", type(field).__name__)
    if isinstance(field, (SdfField, NestedSequence)) and field.in_dim != 3:
        raise ModelFileError(f"{name}: a space-time SDF ({field.in_dim} inputs); a static one (x, y, z) is needed")
    if isinstance(field, NestedSequence):
        return field.band_field(band_level)
    if isinstance(field, SdfField):
        return field
    raise ModelFileError(f"{name}: a {type(field).__name__}, expected an SDF (kind 'sdf' or a nested sequence)")


def load_sdf_field(path: str | os.PathLike, *, band_level: int = 0, device=None, dtype=None) -> SdfField:
    """:func:`load_field` of an SDF or nested-sequence file as an :class:`SdfField` (:func:`to_sdf_field`)."""
    field = load_field(path, device=device, dtype=dtype)
    if not isinstance(field, (SdfField, NestedSequence)):
        raise ModelFileError(f"{path}: a {type(field).__name__} file, expected an SDF model file "
                             f"(kind 'sdf' or a nested sequence)")
    return to_sdf_field(field, band_level=band_level)


def save_model(model, path: str | os.PathLike, **metadata) -> Path:
    """Write a :class:`~neural_bake.nets.siren.Siren` (or a texture's :class:`~neural_bake.nets.grid.GridNet`, a
    tiled SDF's :class:`~neural_bake.nets.tiles.TiledSdf`) and JSON ``metadata`` to ``path`` atomically.

    A file :func:`load_field` reads needs ``kind`` ("sdf" or "texture") and ``frame`` in ``metadata``;
    :func:`save_field` and the fits' ``save`` methods write them. The folder must exist; an existing file is
    replaced only on success.

    Raises:
        ModelFileError: not a Siren or GridNet, metadata not JSON-serialisable (NaN included), or a missing
            folder.
    """
    from ..io.atomic import atomic_write_bytes
    from ..nets.model_io import encode_model

    path = Path(path)
    data = encode_model(model, path, **metadata)
    _check_folder(path)
    return atomic_write_bytes(path, data)


def save_field(field, path: str | os.PathLike) -> Path:
    """Write an :class:`SdfField` or :class:`TextureField` of a network (with its frame), or a
    :class:`NestedSequence`, to ``path`` atomically; :func:`load_field` reads it back as the same type.

    Raises:
        ModelFileError: an analytic field (no network), a network field without a frame, a missing folder,
            metadata that is not JSON-serialisable.
    """
    from ..io.atomic import atomic_write_bytes
    from ..nets.model_io import encode_file

    path = Path(path)
    if isinstance(field, NestedSequence):
        data = encode_file(nested_tensors(field), field.header(), NESTED_FORMAT, path)
        _check_folder(path)
        return atomic_write_bytes(path, data)
    from .spacetime import SpaceTimeField

    if isinstance(field, SpaceTimeField):
        return field.save(path)
    if not isinstance(field, (SdfField, TextureField)):
        raise ModelFileError(f"{path}: save_field expects an SdfField, TextureField or NestedSequence, got "
                             f"{type(field).__name__}")
    if field.model is None:
        raise ModelFileError(f"{path}: {field.name} is an analytic field; only fitted networks are saved")
    if field.frame is None:
        raise ModelFileError(f"{path}: {field.name} has no frame; give the frame the network was fitted in "
                             f"(from_model(model, frame=mesh.frame))")
    kind = "sdf" if isinstance(field, SdfField) else "texture"
    meta = {k: v for k, v in field.metadata.items() if k not in ("kind", "frame", "delta", "fitted_against",
                                                                   "encoding")}
    meta.update(kind=kind, frame=field.frame.to_dict(), delta=field.delta)
    if kind == "texture":
        meta["encoding"] = field.encoding
        if field.fitted_against is not None:
            meta["fitted_against"] = field.fitted_against
    return save_model(field.model, path, **meta)


def _check_folder(path: Path) -> None:
    if not path.parent.is_dir():
        raise ModelFileError(f"{path}: folder {path.parent} does not exist")


# ---------------------------------------------------------------------------------------------- the readers
def _read_network(path: Path, header: dict, device, dtype):
    from ..nets.model_io import build_network, expected_network_shapes, read_state

    arch = header["architecture"]
    return build_network(arch, read_state(path, expected_network_shapes(arch)), path, device=device, dtype=dtype)


def _read_sdf(path: Path, header: dict, *, device=None, dtype=None) -> SdfField:
    from ..nets.model_io import network_kind

    arch, meta = header["architecture"], header["metadata"]
    if network_kind(arch) not in ("siren", "tiles"):
        raise ModelFileError(f"{path}: kind 'sdf' is a SIREN or a tiled SDF (their normals are GEMM gradients), "
                             f"this file holds a {network_kind(arch)} network")
    # a tiled SDF maps R^3 to R by construction (its coarse SIREN's sizes are checked with the architecture)
    if network_kind(arch) == "siren" and (arch["in_dim"] != 3 or arch["out_dim"] != 1):
        st = " (a space-time SDF is kind 'spacetime_sdf', with its time range)" if arch["in_dim"] == 4 else ""
        raise ModelFileError(f"{path}: kind 'sdf' is a static SDF mapping R^3 (x, y, z) to R, this network maps "
                             f"R^{arch['in_dim']} to R^{arch['out_dim']}{st}")
    frame = check_frame(meta.get("frame"), path)
    delta = check_delta(meta.get("delta"), path)
    model = _read_network(path, header, device, dtype)
    return SdfField.from_model(model, frame=frame, delta=delta, name=path.name, metadata=meta)


def _read_texture(path: Path, header: dict, *, device=None, dtype=None) -> TextureField:
    arch, meta = header["architecture"], header["metadata"]
    sided = arch.get("network") == "grid" and arch["in_dim"] == 6  # points and surface normals
    if arch["in_dim"] != 3 and not sided or arch["out_dim"] not in (3, 4):
        raise ModelFileError(f"{path}: a texture maps R^3 (or a grid network's points and normals, R^6) to "
                             f"RGB(A), this network maps R^{arch['in_dim']} to R^{arch['out_dim']}")
    frame = check_frame(meta.get("frame"), path)
    delta = check_delta(meta.get("delta"), path)
    against = meta.get("fitted_against")
    if against is not None and not isinstance(against, dict):
        raise ModelFileError(f"{path}: fitted_against = {against!r:.40} is not an object")
    if against is not None and against.get("surface") is not None:
        _check_surface(against["surface"], path)
    encoding = meta.get("encoding", "linear")  # files written before the encoding was recorded: linear
    if encoding not in ENCODINGS:
        raise ModelFileError(f"{path}: encoding = {encoding!r:.40} is not one of {', '.join(ENCODINGS)}")
    model = _read_network(path, header, device, dtype)
    return TextureField.from_model(model, frame=frame, delta=delta, name=path.name, fitted_against=against,
                                   metadata=meta, encoding=encoding)


def _check_surface(surface, path: Path) -> None:
    """A texture's recorded surface points: a list of at most MAX_TEXTURE_SURFACE_POINTS finite 3-vectors."""
    import math

    from ..constants import MAX_TEXTURE_SURFACE_POINTS

    ok = isinstance(surface, list) and len(surface) <= MAX_TEXTURE_SURFACE_POINTS and all(
        isinstance(p, list) and len(p) == 3 and all(isinstance(c, (int, float)) and not isinstance(c, bool)
                                                    and math.isfinite(c) for c in p) for p in surface)
    if not ok:
        raise ModelFileError(f"{path}: fitted_against.surface is not a list of at most {MAX_TEXTURE_SURFACE_POINTS} "
                             f"finite points [x, y, z]")


def _register_defaults() -> None:
    from ..nets.model_io import MODEL_FORMAT

    register_kind("sdf", MODEL_FORMAT, _read_sdf, SdfField)
    register_kind("texture", MODEL_FORMAT, _read_texture, TextureField)
    register_kind("nested", NESTED_FORMAT, read_nested, NestedSequence)


_register_defaults()
