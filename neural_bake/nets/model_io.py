"""Model files: a SIREN's tensors in safetensors, its description as JSON in the same file.

One file per network. The tensors are the module's ``state_dict`` (``layers.<i>.weight`` (out, in),
``layers.<i>.bias`` (out,), ω *not* folded in) stored by :mod:`safetensors`; the safetensors header's
``__metadata__`` string map holds

- ``"format"``: ``"neural_bake.model"`` — what a reader checks first;
- ``"neural_bake"``: a JSON object ``{"format", "format_version", "package_version", "architecture",
  "metadata"}`` with ``architecture`` = :attr:`Siren.architecture` (width, depth, in_dim, out_dim, ω0,
  hidden ω) and ``metadata`` the caller's JSON-serialisable keywords (frame dict, kind, δ, training config…).

Loading parses the header and the raw tensor bytes only — no pickle, no code from the file is ever run —
and checks everything (format, version, architecture values, tensor names, shapes, dtypes, finiteness):
any problem is a one-line :class:`ModelFileError` naming the file.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path

import torch

from .. import __version__
from ..errors import ModelFileError
from ..io.atomic import atomic_path
from .siren import Siren

__all__ = ["save_model", "load_model", "read_model_metadata", "MODEL_FORMAT", "MODEL_FORMAT_VERSION"]

#: The ``format`` value of every model file.
MODEL_FORMAT = "neural_bake.model"
#: Version of the layout described above; files of a newer version are refused.
MODEL_FORMAT_VERSION = 1

_ARCH_INT = ("width", "depth", "in_dim", "out_dim")
_ARCH_FLOAT = ("omega_0", "hidden_omega")


def save_model(model: Siren, path: str | os.PathLike, **metadata) -> Path:
    """Write ``model`` and ``metadata`` to ``path`` atomically (a ``.safetensors`` file; any suffix works).

    Args:
        model: a :class:`Siren` on any device and dtype (tensors are stored as they are, moved to CPU).
        path: destination file; its folder must exist. An existing file is replaced only on success.
        **metadata: JSON-serialisable values (dicts, lists, str, numbers, bool, None); objects with a
            ``to_dict()`` (e.g. :class:`~neural_bake.types.Frame`), dataclasses (training configs), numpy
            arrays and scalars, tensors, tuples/sets and paths are converted. Non-finite floats are refused (JSON has no NaN).

    Returns:
        The path written.

    Raises:
        ModelFileError: ``model`` is not a Siren, a metadata value is not serialisable, or the folder is
            missing.
    """
    from safetensors.torch import save_file

    path = Path(path)
    if not isinstance(model, Siren):
        raise ModelFileError(f"{path}: save_model expects a Siren, got {type(model).__name__}")
    try:
        meta_json = json.dumps(metadata, default=_to_json, allow_nan=False, sort_keys=True)
    except TypeError as exc:
        raise ModelFileError(f"{path}: metadata is not JSON-serialisable ({exc})") from None
    except ValueError:  # allow_nan=False (circular references are refused as ValueError too)
        raise ModelFileError(
            f"{path}: metadata is not JSON-serialisable (a NaN or infinite number, or a circular reference)"
        ) from None
    header = {
        "format": MODEL_FORMAT,
        "format_version": MODEL_FORMAT_VERSION,
        "package_version": __version__,
        "architecture": model.architecture,
        "metadata": json.loads(meta_json),
    }
    tensors = {name: t.detach().to("cpu").contiguous() for name, t in model.state_dict().items()}
    if not path.parent.is_dir():
        raise ModelFileError(f"{path}: folder {path.parent} does not exist")
    with atomic_path(path) as tmp:
        save_file(tensors, str(tmp), metadata={"format": MODEL_FORMAT, "neural_bake": json.dumps(header)})
    return path


def load_model(
    path: str | os.PathLike, *, device: str | torch.device | None = None, dtype: torch.dtype | None = None
) -> tuple[Siren, dict]:
    """Read a model file written by :func:`save_model`.

    Args:
        path: the model file.
        device: where to put the network (default CPU).
        dtype: floating dtype of the network (default: the stored one, float32 for trained models).

    Returns:
        ``(model, metadata)``: the :class:`Siren` in eval mode with the stored weights, and the caller's
        metadata dict as saved (plain JSON values). The full header (format, versions, architecture) is
        given by :func:`read_model_metadata`.

    Raises:
        ModelFileError: the file is missing, unreadable, corrupt or truncated, not a neural_bake model, of
            a newer format version, or its tensors do not match its architecture.
    """
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    header = read_model_metadata(path)
    arch = header["architecture"]
    expected = _expected_shapes(arch)
    state = {}
    try:
        with safe_open(str(path), framework="pt", device="cpu") as fh:
            names = set(fh.keys())
            missing, extra = sorted(set(expected) - names), sorted(names - set(expected))
            if missing or extra:
                raise ModelFileError(
                    f"{path}: tensors do not match the architecture "
                    f"(missing {missing or 'none'}, unexpected {extra or 'none'})"
                )
            for name, shape in expected.items():  # shapes from the header first: nothing big is allocated
                got = tuple(fh.get_slice(name).get_shape())
                if got != shape:
                    raise ModelFileError(
                        f"{path}: tensor {name} has shape {got}, the architecture needs {shape}"
                    )
            for name in expected:
                t = fh.get_tensor(name)
                if not t.is_floating_point():
                    raise ModelFileError(f"{path}: tensor {name} has dtype {t.dtype}, expected a float type")
                if not torch.isfinite(t).all():
                    raise ModelFileError(f"{path}: tensor {name} holds NaN or infinite values")
                state[name] = t
    except ModelFileError:
        raise
    except (SafetensorError, OSError, RuntimeError, ValueError) as exc:
        raise ModelFileError(f"{path}: corrupt or truncated model file ({_one_line(exc)})") from None
    try:
        model = Siren(**arch)
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f"{path}: invalid architecture {arch} ({exc})") from None
    stored_dtype = state["layers.0.weight"].dtype
    model = model.to(dtype=dtype or stored_dtype)
    with torch.no_grad():
        for name, p in model.state_dict().items():
            p.copy_(state[name])
    model = model.to(device=device or "cpu")
    model.eval()
    return model, header["metadata"]


def read_model_metadata(path: str | os.PathLike) -> dict:
    """The validated JSON header of a model file, without reading its tensors.

    Returns ``{"format", "format_version", "package_version", "architecture", "metadata"}``.

    Raises:
        ModelFileError: as :func:`load_model` for a missing, corrupt or non-model file.
    """
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    if not path.exists():
        raise ModelFileError(f"{path}: no such model file")
    if not path.is_file():
        raise ModelFileError(f"{path}: not a file")
    try:
        with safe_open(str(path), framework="pt", device="cpu") as fh:
            raw = fh.metadata() or {}
    except (SafetensorError, OSError, RuntimeError, ValueError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"{path}: not a readable model file ({_one_line(exc)})") from None
    if raw.get("format") != MODEL_FORMAT or "neural_bake" not in raw:
        raise ModelFileError(f"{path}: a safetensors file but not a neural_bake model (no '{MODEL_FORMAT}' header)")
    try:
        header = json.loads(raw["neural_bake"])
    except ValueError as exc:
        raise ModelFileError(f"{path}: corrupt model header ({_one_line(exc)})") from None
    if not isinstance(header, dict):
        raise ModelFileError(f"{path}: corrupt model header (not a JSON object)")
    version = header.get("format_version")
    if not isinstance(version, int) or isinstance(version, bool):
        raise ModelFileError(f"{path}: corrupt model header (format_version {version!r})")
    if version > MODEL_FORMAT_VERSION:
        raise ModelFileError(
            f"{path}: model format version {version} is newer than this neural_bake reads "
            f"({MODEL_FORMAT_VERSION}); upgrade neural_bake"
        )
    arch = header.get("architecture")
    if not isinstance(arch, dict) or set(arch) != set(_ARCH_INT + _ARCH_FLOAT):
        raise ModelFileError(f"{path}: corrupt model header (architecture {arch!r})")
    for key in _ARCH_INT:
        v = arch[key]
        if not isinstance(v, int) or isinstance(v, bool) or v < (0 if key == "depth" else 1):
            raise ModelFileError(f"{path}: corrupt model header ({key} = {v!r} is not a valid size)")
    for key in _ARCH_FLOAT:
        v = arch[key]
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or v <= 0:
            raise ModelFileError(f"{path}: corrupt model header ({key} = {v!r} is not a positive number)")
    if not isinstance(header.get("metadata"), dict):
        raise ModelFileError(f"{path}: corrupt model header (metadata is not a JSON object)")
    return header


def _expected_shapes(arch: dict) -> dict[str, tuple[int, ...]]:
    """The state_dict names and shapes of ``Siren(**arch)``, without building it."""
    dims = [arch["in_dim"]] + [arch["width"]] * (arch["depth"] + 1) + [arch["out_dim"]]
    shapes = {}
    for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
        shapes[f"layers.{i}.weight"] = (b, a)
        shapes[f"layers.{i}.bias"] = (b,)
    return shapes


def _to_json(obj):
    if hasattr(obj, "to_dict"):
        return obj.to_dict()
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu().tolist()
    if hasattr(obj, "tolist"):  # numpy arrays and scalars
        return obj.tolist()
    if isinstance(obj, (set, frozenset, tuple)):
        return list(obj)
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"{type(obj).__name__} value {obj!r:.60} is not JSON-serialisable")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200] or type(exc).__name__
