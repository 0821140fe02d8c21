"""Model files: a SIREN's tensors in safetensors, its description as JSON in the same file.

One file per network. The tensors are the module's ``state_dict`` (``layers.<i>.weight`` (out, in),
``layers.<i>.bias`` (out,), ω *not* folded in) stored by :mod:`safetensors`; the safetensors header's
``__metadata__`` string map holds

- ``"format"``: ``"neural_bake.model"`` — what a reader checks first;
- ``"neural_bake"``: a JSON object ``{"format", "format_version", "package_version", "architecture",
  "metadata"}`` with ``architecture`` = :attr:`Siren.architecture` (width, depth, in_dim, out_dim, ω0,
  hidden ω) and ``metadata`` the caller's JSON-serialisable keywords (frame dict, kind, δ, training config…).

A network other than a SIREN says which in its architecture: ``"network": "grid"`` is a
:class:`~neural_bake.nets.grid.GridNet` (its :attr:`~neural_bake.nets.grid.GridNet.architecture`; tensors
``table`` and ``layers.<i>.*``); ``"network": "tiles"`` a :class:`~neural_bake.nets.tiles.TiledSdf` (``coarse``,
a SIREN's architecture, and ``tiles``: the tiles' width, depth, ω and grid — origin, cell, cells per axis,
margin, active cells; tensors ``coarse.layers.<i>.*`` and ``tiles.weights.<i>`` (K, out, in),
``tiles.biases.<i>`` (K, out)). Both are written as format version 2 so that readers that know only SIRENs refuse it
with "upgrade" instead of misreading it. An architecture without ``"network"`` is a SIREN (every file of
version 1).

This module encodes (:func:`encode_model`, bytes; writing them atomically is the field layer's job,
:func:`neural_bake.fields.save_model`) and reads. Reading parses the header and the raw tensor bytes only —
no pickle, no code from the file is ever run — and checks everything before allocating: the JSON nesting
depth, the format and version, the architecture (sizes capped by ``constants.MAX_NET_*``), tensor names and
shapes from the header, then dtypes and finiteness. Any problem is a one-line :class:`ModelFileError` naming
the file and the field.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..constants import (MAX_HEADER_DEPTH, MAX_NET_DEPTH, MAX_NET_IN_DIM, MAX_NET_OUT_DIM, MAX_NET_WIDTH, MAX_TILE_GRID,
                         MAX_TILES)
from ..errors import ModelFileError
from .grid import IN_DIMS, GridNet, check_grid_settings, valid_normal_scale
from .siren import Siren
from .tiles import TiledSdf

__all__ = ["encode_model", "encode_file", "load_model", "read_model_metadata", "read_raw_metadata",
           "parse_header", "check_architecture", "check_network_architecture", "expected_shapes",
           "expected_network_shapes", "read_state", "build_siren", "build_network", "network_kind",
           "MODEL_FORMAT", "MODEL_FORMAT_VERSION"]

#: The ``format`` value of every model file.
MODEL_FORMAT = "neural_bake.model"
#: Version of the layout described above; files of a newer version are refused. A SIREN's file is written as
#: version 1 (what every reader reads), another network's as :data:`NETWORK_FORMAT_VERSION`.
MODEL_FORMAT_VERSION = 2
#: The version a file holding a network other than a SIREN (``"network"`` in its architecture) is written as.
NETWORK_FORMAT_VERSION = 2
#: The networks a model file may hold besides SIRENs, by their architecture's ``"network"``.
NETWORKS = ("grid", "tiles")

_ARCH_INT = ("width", "depth", "in_dim", "out_dim")
_ARCH_FLOAT = ("omega_0", "hidden_omega")
#: (smallest, largest) value of each architecture size a file may declare.
_ARCH_LIMITS = {"width": (1, MAX_NET_WIDTH), "depth": (0, MAX_NET_DEPTH), "in_dim": (1, MAX_NET_IN_DIM),
                "out_dim": (1, MAX_NET_OUT_DIM)}


def encode_model(model: Siren, path: str | os.PathLike = "<model>", **metadata) -> bytes:
    """The bytes of a model file holding ``model`` and ``metadata`` (see the module docstring).

    Args:
        model: a :class:`Siren`, :class:`~neural_bake.nets.grid.GridNet` or :class:`~neural_bake.nets.tiles.TiledSdf`
            on any device and dtype (tensors are
            stored as they are, moved to CPU).
        path: only named in error messages.
        **metadata: JSON-serialisable values (dicts, lists, str, numbers, bool, None); objects with a
            ``to_dict()`` (e.g. :class:`~neural_bake.types.Frame`), dataclasses (training configs), numpy
            arrays and scalars, tensors, tuples/sets and paths are converted. Non-finite floats are refused
            (JSON has no NaN).

    Raises:
        ModelFileError: ``model`` is not a Siren or a metadata value is not serialisable.
    """
    if not isinstance(model, (Siren, GridNet, TiledSdf)):
        raise ModelFileError(f"{path}: save_model expects a Siren, a GridNet or a TiledSdf, got "
                             f"{type(model).__name__}")
    header = {
        "format": MODEL_FORMAT,
        "format_version": 1 if isinstance(model, Siren) else NETWORK_FORMAT_VERSION,
        "package_version": __version__,
        "architecture": model.architecture,
        "metadata": metadata,
    }
    tensors = {name: t.detach().to("cpu").contiguous() for name, t in model.state_dict().items()}
    return encode_file(tensors, header, MODEL_FORMAT, path)


def encode_file(tensors: dict[str, torch.Tensor], header: dict, fmt: str, path: str | os.PathLike = "<model>") -> bytes:
    """safetensors bytes of ``tensors`` with ``{"format": fmt, "neural_bake": JSON of header}`` as metadata.

    Raises ModelFileError naming ``path`` when ``header`` is not JSON-serialisable (NaN, infinity, objects).
    """
    from safetensors.torch import save

    try:
        text = json.dumps(header, default=_to_json, allow_nan=False, sort_keys=True)
    except TypeError as exc:
        raise ModelFileError(f"{path}: metadata is not JSON-serialisable ({exc})") from None
    except ValueError:  # allow_nan=False (circular references are refused as ValueError too)
        raise ModelFileError(
            f"{path}: metadata is not JSON-serialisable (a NaN or infinite number, or a circular reference)"
        ) from None
    return save(tensors, metadata={"format": fmt, "neural_bake": text})


def load_model(
    path: str | os.PathLike, *, device: str | torch.device | None = None, dtype: torch.dtype | None = None
) -> tuple[Siren | GridNet | TiledSdf, dict]:
    """Read a model file (see the module docstring).

    Args:
        path: the model file.
        device: where to put the network (default CPU).
        dtype: floating dtype of the network (default: the stored one, float32 for trained models).

    Returns:
        ``(model, metadata)``: the network (a :class:`Siren`, or the network its architecture names) in eval
        mode with the stored weights, and the caller's
        metadata dict as saved (plain JSON values, not checked here: :mod:`neural_bake.fields` checks the
        frame, δ and kind). The full header (format, versions, architecture) is given by
        :func:`read_model_metadata`.

    Raises:
        ModelFileError: the file is missing, unreadable, corrupt or truncated, not a neural_bake model, of
            a newer format version, of an architecture beyond the caps, or its tensors do not match it.
    """
    path = Path(path)
    header = read_model_metadata(path)
    arch = header["architecture"]
    state = read_state(path, expected_network_shapes(arch))
    return build_network(arch, state, path, device=device, dtype=dtype), header["metadata"]


def read_model_metadata(path: str | os.PathLike) -> dict:
    """The validated JSON header of a model file, without reading its tensors.

    Returns ``{"format", "format_version", "package_version", "architecture", "metadata"}``.

    Raises:
        ModelFileError: as :func:`load_model` for a missing, corrupt or non-model file.
    """
    path = Path(path)
    raw = read_raw_metadata(path)
    if raw.get("format") != MODEL_FORMAT or "neural_bake" not in raw:
        raise ModelFileError(f"{path}: a safetensors file but not a neural_bake model (no '{MODEL_FORMAT}' header)")
    header = parse_header(raw["neural_bake"], path)
    check_version(header, MODEL_FORMAT_VERSION, path)
    header["architecture"] = check_network_architecture(header.get("architecture"), path)
    if not isinstance(header.get("metadata"), dict):
        raise ModelFileError(f"{path}: corrupt model header (metadata is not a JSON object)")
    return header


def read_raw_metadata(path: str | os.PathLike) -> dict[str, str]:
    """The safetensors ``__metadata__`` string map of ``path`` (empty if none); ModelFileError if the file is
    missing, a folder or not a readable safetensors file."""
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    if not path.exists():
        raise ModelFileError(f"{path}: no such model file")
    if not path.is_file():
        raise ModelFileError(f"{path}: not a file")
    try:
        with safe_open(str(path), framework="pt", device="cpu") as fh:
            return dict(fh.metadata() or {})
    except (SafetensorError, OSError, RuntimeError, ValueError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"{path}: not a readable model file ({_one_line(exc)})") from None


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)


def json_depth(text: str) -> int:
    """Deepest nesting of ``[``/``{`` in JSON ``text`` (brackets inside strings do not count), without parsing."""
    skeleton = _JSON_STRING.sub("", text).encode("utf-8", "replace")
    if not skeleton:
        return 0
    b = np.frombuffer(skeleton, dtype=np.uint8)
    step = ((b == ord("[")) | (b == ord("{"))).astype(np.int64) - ((b == ord("]")) | (b == ord("}")))
    return int(np.cumsum(step).max(initial=0))


def parse_header(text: str, path: str | os.PathLike) -> dict:
    """The JSON object ``text`` of a file's header: its nesting depth is checked first (at most
    ``MAX_HEADER_DEPTH``), so a hostile header cannot exhaust the parser's recursion."""
    if not isinstance(text, str):
        raise ModelFileError(f"{path}: corrupt model header (not a JSON string)")
    depth = json_depth(text)
    if depth > MAX_HEADER_DEPTH:
        raise ModelFileError(f"{path}: corrupt model header (JSON nested {depth} deep, at most {MAX_HEADER_DEPTH})")
    try:
        header = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise ModelFileError(f"{path}: corrupt model header ({_one_line(exc)})") from None
    if not isinstance(header, dict):
        raise ModelFileError(f"{path}: corrupt model header (not a JSON object)")
    return header


def check_version(header: dict, newest: int, path) -> int:
    """``header["format_version"]``, an int not newer than ``newest``; ModelFileError otherwise."""
    version = header.get("format_version")
    if not isinstance(version, int) or isinstance(version, bool):
        raise ModelFileError(f"{path}: corrupt model header (format_version {version!r:.40})")
    if version > newest:
        raise ModelFileError(
            f"{path}: model format version {version} is newer than this neural_bake reads ({newest}); "
            f"upgrade neural_bake"
        )
    return version


def check_architecture(arch, path, where: str = "") -> dict:
    """``arch`` checked as a :attr:`Siren.architecture` dict within the caps of ``constants.MAX_NET_*``.

    ``where`` (e.g. ``"level 2 "``) prefixes the field in the message. Returns a copy with float ω values.
    """
    if not isinstance(arch, dict) or set(arch) != set(_ARCH_INT + _ARCH_FLOAT):
        raise ModelFileError(f"{path}: corrupt model header ({where}architecture {arch!r:.120})")
    for key in _ARCH_INT:
        v, (lo, hi) = arch[key], _ARCH_LIMITS[key]
        if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
            raise ModelFileError(f"{path}: corrupt model header ({where}{key} = {v!r:.40} is not a size in "
                                 f"[{lo}, {hi}])")
    for key in _ARCH_FLOAT:
        v = arch[key]
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or v <= 0:
            raise ModelFileError(f"{path}: corrupt model header ({where}{key} = {v!r:.40} is not a finite "
                                 f"positive number)")
    return {**{k: arch[k] for k in _ARCH_INT}, **{k: float(arch[k]) for k in _ARCH_FLOAT}}


def network_kind(arch: dict) -> str:
    """What network an architecture dict describes: ``"siren"`` (no ``"network"`` key) or its ``"network"``."""
    return str(arch.get("network", "siren")) if isinstance(arch, dict) else "siren"


#: The keys of a grid network's architecture, ints and strings/floats apart.
_GRID_INT = ("levels", "features", "log2_table", "base_resolution", "max_resolution", "width", "depth", "in_dim",
             "out_dim")


def check_network_architecture(arch, path, where: str = "") -> dict:
    """``arch`` checked as the architecture of any network a model file may hold: a SIREN's
    (:func:`check_architecture`) or, with ``"network"``, one of :data:`NETWORKS` (a grid network's:
    :attr:`~neural_bake.nets.grid.GridNet.architecture`, its sizes within the caps). Returns a checked copy."""
    if not isinstance(arch, dict) or "network" not in arch:
        return check_architecture(arch, path, where)
    if arch["network"] not in NETWORKS:
        raise ModelFileError(f"{path}: corrupt model header ({where}network = {arch['network']!r:.40} is not one of "
                             f"siren, {', '.join(NETWORKS)})")
    if arch["network"] == "tiles":
        return _check_tiles_architecture(arch, path, where)
    keys = {"network", "activation", "omega", *_GRID_INT}
    if set(arch) != keys and set(arch) != keys | {"normal_scale"}:
        raise ModelFileError(f"{path}: corrupt model header ({where}architecture {arch!r:.120})")
    for key in _GRID_INT:
        v = arch[key]
        if not isinstance(v, int) or isinstance(v, bool):
            raise ModelFileError(f"{path}: corrupt model header ({where}{key} = {v!r:.40} is not an integer)")
    if arch["in_dim"] not in IN_DIMS or not 1 <= arch["out_dim"] <= MAX_NET_OUT_DIM:
        raise ModelFileError(f"{path}: corrupt model header ({where}a grid network maps R^3 (or R^6 with surface "
                             f"normals) to R^1..R^{MAX_NET_OUT_DIM}, this one R^{arch['in_dim']} to "
                             f"R^{arch['out_dim']})")
    scale = arch.get("normal_scale")
    if (arch["in_dim"] == 6) != (scale is not None) or scale is not None and not valid_normal_scale(scale):
        raise ModelFileError(f"{path}: corrupt model header ({where}normal_scale = {scale!r:.40} with in_dim "
                             f"{arch['in_dim']}: a number in (0, 100] with in_dim 6, absent with 3)")
    try:
        check_grid_settings(**{k: arch[k] for k in ("levels", "features", "log2_table", "base_resolution",
                                                     "max_resolution", "width", "depth", "activation", "omega")},
                            error=ModelFileError)
    except ModelFileError as exc:
        raise ModelFileError(f"{path}: corrupt model header ({where}{exc})") from None
    out = {**arch, "omega": float(arch["omega"])}
    if scale is not None:
        out["normal_scale"] = float(scale)
    return out


def _check_tiles_architecture(arch: dict, path, where: str) -> dict:
    """A tiled SDF's architecture (``network``, ``coarse``, ``tiles``) checked: the coarse level a scalar SIREN
    of 3-D points, the tiles' sizes and ω within the caps, their grid's origin, cell, cells per axis (at most
    ``MAX_TILE_GRID``), margin and active cells (distinct, inside the grid, at most ``MAX_TILES``)."""
    def bad(what: str) -> ModelFileError:
        return ModelFileError(f"{path}: corrupt model header ({where}{what})")

    if set(arch) != {"network", "coarse", "tiles"}:
        raise bad(f"architecture {arch!r:.120}")
    coarse = check_architecture(arch["coarse"], path, f"{where}coarse ")
    if (coarse["in_dim"], coarse["out_dim"]) != (3, 1):
        raise bad(f"the coarse level maps R^{coarse['in_dim']} to R^{coarse['out_dim']}, a tiled SDF's R^3 to R")
    t = arch["tiles"]
    if not isinstance(t, dict) or set(t) != {"width", "depth", "omega_0", "hidden_omega", "grid"}:
        raise bad(f"tiles {t!r:.120}")
    checked = check_architecture({**{k: t[k] for k in ("width", "depth", "omega_0", "hidden_omega")},
                                  "in_dim": 3, "out_dim": 1}, path, f"{where}tiles ")
    g = t["grid"]
    if not isinstance(g, dict) or set(g) != {"origin", "cell", "grid", "margin", "active"}:
        raise bad(f"tiles grid {g!r:.120}")
    n, active, origin = g["grid"], g["active"], g["origin"]
    if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= MAX_TILE_GRID:
        raise bad(f"tiles grid = {n!r:.40} is not a size in [1, {MAX_TILE_GRID}]")
    if not (isinstance(origin, list) and len(origin) == 3 and all(_finite(v) for v in origin)):
        raise bad(f"tiles origin = {origin!r:.60} is not 3 finite numbers")
    if not (_finite(g["cell"]) and g["cell"] > 0):
        raise bad(f"tiles cell = {g['cell']!r:.40} is not a positive length")
    if not (_finite(g["margin"]) and 0 < g["margin"] <= 0.25):
        raise bad(f"tiles margin = {g['margin']!r:.40} is not in (0, 0.25] cells")
    if not (isinstance(active, list) and 1 <= len(active) <= MAX_TILES
            and all(isinstance(c, int) and not isinstance(c, bool) and 0 <= c < n ** 3 for c in active)
            and len(set(active)) == len(active)):
        raise bad(f"tiles active = {active!r:.60}: 1 to {MAX_TILES} distinct cells in [0, {n ** 3})")
    tiles = {k: checked[k] for k in ("width", "depth", "omega_0", "hidden_omega")}
    grid = {"origin": [float(v) for v in origin], "cell": float(g["cell"]), "grid": n,
            "margin": float(g["margin"]), "active": list(active)}
    return {"network": "tiles", "coarse": coarse, "tiles": {**tiles, "grid": grid}}


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def expected_network_shapes(arch: dict, prefix: str = "") -> dict[str, tuple[int, ...]]:
    """The state_dict names (with ``prefix``) and shapes of the network ``arch`` describes (any of them)."""
    if network_kind(arch) == "siren":
        return expected_shapes(arch, prefix)
    if network_kind(arch) == "tiles":
        shapes = expected_shapes(arch["coarse"], f"{prefix}coarse.")
        t = arch["tiles"]
        k = len(t["grid"]["active"])
        dims = [3] + [t["width"]] * (t["depth"] + 1) + [1]
        for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
            shapes[f"{prefix}tiles.weights.{i}"] = (k, b, a)
            shapes[f"{prefix}tiles.biases.{i}"] = (k, b)
        return shapes
    from .grid import grid_layer_dims, grid_resolutions, grid_table_sizes

    rows = sum(grid_table_sizes(grid_resolutions(arch["levels"], arch["base_resolution"], arch["max_resolution"]),
                                arch["log2_table"]))
    shapes = {f"{prefix}table": (rows, arch["features"])}
    dims = grid_layer_dims(arch["levels"], arch["features"], arch["width"], arch["depth"], arch["out_dim"],
                           arch["in_dim"])
    for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
        shapes[f"{prefix}layers.{i}.weight"] = (b, a)
        shapes[f"{prefix}layers.{i}.bias"] = (b,)
    return shapes


def expected_shapes(arch: dict, prefix: str = "") -> dict[str, tuple[int, ...]]:
    """The state_dict names (with ``prefix``) and shapes of ``Siren(**arch)``, without building it."""
    dims = [arch["in_dim"]] + [arch["width"]] * (arch["depth"] + 1) + [arch["out_dim"]]
    shapes = {}
    for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
        shapes[f"{prefix}layers.{i}.weight"] = (b, a)
        shapes[f"{prefix}layers.{i}.bias"] = (b,)
    return shapes


def read_state(path, expected: dict[str, tuple[int, ...]], *, exact: bool = True) -> dict[str, torch.Tensor]:
    """The tensors ``expected`` (name -> shape) of a safetensors file, checked: names (no extra ones when
    ``exact``) and shapes from the header before any tensor is read, then float dtype and finiteness."""
    from safetensors import SafetensorError, safe_open

    state = {}
    try:
        with safe_open(str(path), framework="pt", device="cpu") as fh:
            names = set(fh.keys())
            missing = sorted(set(expected) - names)
            extra = sorted(names - set(expected)) if exact else []
            if missing or extra:
                raise ModelFileError(
                    f"{path}: tensors do not match the architecture "
                    f"(missing {missing[:4] or 'none'}, unexpected {extra[:4] or 'none'})"
                )
            for name, shape in expected.items():  # shapes from the header first: nothing big is allocated
                got = tuple(fh.get_slice(name).get_shape())
                if got != shape:
                    raise ModelFileError(f"{path}: tensor {name} has shape {got}, the architecture needs {shape}")
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
    return state


def build_siren(arch: dict, state: dict[str, torch.Tensor], path, *, prefix: str = "",
                device: str | torch.device | None = None, dtype: torch.dtype | None = None) -> Siren:
    """A :class:`Siren` of ``arch`` (checked) holding ``state[prefix + name]``, in eval mode on ``device``."""
    try:
        model = Siren(**arch)
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f"{path}: invalid architecture {arch} ({exc})") from None
    return _holding(model, state, prefix, "layers.0.weight", device, dtype)


def _holding(model, state: dict[str, torch.Tensor], prefix: str, dtype_key: str, device, dtype):
    """``model`` in the dtype of ``state[prefix + dtype_key]`` (unless ``dtype``) holding ``state``'s tensors,
    in eval mode on ``device``."""
    model = model.to(dtype=dtype or state[prefix + dtype_key].dtype)
    with torch.no_grad():
        for name, p in model.state_dict().items():
            p.copy_(state[prefix + name])
    model = model.to(device=device or "cpu")
    model.eval()
    return model


def build_network(arch: dict, state: dict[str, torch.Tensor], path, *, prefix: str = "",
                  device: str | torch.device | None = None, dtype: torch.dtype | None = None
                  ) -> Siren | GridNet | TiledSdf:
    """The network ``arch`` describes (a SIREN: :func:`build_siren`; a grid network) holding
    ``state[prefix + name]``, in eval mode on ``device``."""
    if network_kind(arch) == "siren":
        return build_siren(arch, state, path, prefix=prefix, device=device, dtype=dtype)
    if network_kind(arch) == "tiles":
        from .tiles import TileGrid, TiledSiren

        t = arch["tiles"]
        try:
            tiled = TiledSdf(Siren(**arch["coarse"]),
                             TiledSiren(TileGrid.from_dict(t["grid"]), t["width"], t["depth"], t["omega_0"],
                                        t["hidden_omega"]))
        except (TypeError, ValueError) as exc:
            raise ModelFileError(f"{path}: invalid architecture ({_one_line(exc)})") from None
        return _holding(tiled, state, prefix, "coarse.layers.0.weight", device, dtype)
    kwargs = {k: v for k, v in arch.items() if k != "network"}
    try:
        model = GridNet(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f"{path}: invalid architecture {arch} ({exc})") from None
    return _holding(model, state, prefix, "table", device, dtype)


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
