"""SIREN weights trained elsewhere as a field file: a PyTorch state dict of the public SIREN code, or a
headerless float32 weight file of a stated (W, D).

Both describe the network our :class:`~neural_bake.nets.siren.Siren` computes: hidden layers
``sin(ω (W x + b))`` (ω0 on the first, the hidden ω after it) and a linear output layer, with ω *not* folded
into the weights; the weights are copied as they are and ω is recorded in the file. Reading never runs code
from a file (``torch.load(weights_only=True)``); anything that is not a plain SIREN of (x, y, z) with one
output is refused with one :class:`~neural_bake.errors.ModelFileError` line naming the file and the problem.

State dict layouts (a leading ``module.``, as DataParallel saves, is stripped):

- ``net.net.<i>.0.weight|bias``: ``SingleBVPNet`` (an ``FCBlock`` inside), the SIREN repository's SDF model;
- ``net.<i>.0.weight|bias``: a bare ``FCBlock``, or the i3d ``SIREN``;
- ``net.<i>.linear.weight|bias`` and a last ``net.<N>.weight|bias``: the ``Siren`` of the SIREN notebooks.

Raw files: little-endian float32, layer after layer from the input to the output, each as its weight
(out, in) row-major followed by its bias (out); the size must be exactly that of the stated architecture.
"""

from __future__ import annotations

import math
import os
import pickle
import re
from pathlib import Path

import numpy as np
import torch

from ..constants import MAX_NET_DEPTH, MAX_NET_WIDTH
from ..errors import ModelFileError, NeuralBakeError
from ..types import Frame

__all__ = ["import_siren", "siren_from_state_dict", "read_siren_state", "read_raw_siren", "raw_siren_size",
           "STATE_LAYOUTS"]

#: Name of each recognised state-dict layout -> the key pattern of its layers (group 1: layer index).
STATE_LAYOUTS = {
    "SingleBVPNet": re.compile(r"net\.net\.(\d+)\.0\.(weight|bias)"),
    "FCBlock": re.compile(r"net\.(\d+)\.0\.(weight|bias)"),
    "Siren": re.compile(r"net\.(\d+)\.(?:linear\.)?(weight|bias)"),
}
_SINE_LAYER = re.compile(r"net\.\d+\.linear\.")
_ENCODING_HINTS = ("encoding", "embed", "fourier", "freq", "gaussian")
_LAYOUT_HELP = "net.net.<i>.0.*, net.<i>.0.* or net.<i>.linear.* with a last net.<N>.*"
_SPATIAL_IN = 3


def _check_omegas(omega_0, hidden_omega) -> tuple[float, float]:
    """(ω0, hidden ω), each a finite positive number; the hidden ω defaults to ω0."""
    hidden_omega = omega_0 if hidden_omega is None else hidden_omega
    for name, v in (("omega_0", omega_0), ("hidden_omega", hidden_omega)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise NeuralBakeError(f"{name} = {v!r}: must be a finite positive number", parameter=name)
    return float(omega_0), float(hidden_omega)


def siren_from_state_dict(state, name: str | os.PathLike, *, omega_0: float, hidden_omega: float | None = None):
    """``(siren, layout)``: a :class:`~neural_bake.nets.siren.Siren` holding the weights of ``state``, a state
    dict in one of :data:`STATE_LAYOUTS`, and the layout's name.

    Args:
        state: mapping of key -> tensor, as ``torch.load`` returns a saved ``model.state_dict()``.
        name: what the messages call it (the file).
        omega_0, hidden_omega: ω of the first layer and of the hidden layers after it (default ``omega_0``).

    The network is float64 when any tensor is float64, float32 otherwise (half precision is widened).

    Raises:
        ModelFileError: not a mapping of tensors; unknown keys, a positional encoding, layouts mixed, a
            missing layer or bias, non-float or non-finite tensors, shapes that do not chain, an input other
            than (x, y, z), an output other than one value, unequal hidden widths, a sine output layer, sizes
            beyond the caps.
        NeuralBakeError: ``omega_0`` or ``hidden_omega`` not a finite positive number.
    """
    from ..nets.siren import Siren

    omega_0, hidden_omega = _check_omegas(omega_0, hidden_omega)
    if not isinstance(state, dict):
        raise ModelFileError(f"{name}: holds a {type(state).__name__}, not a state dict (save model.state_dict())")
    if not state:
        raise ModelFileError(f"{name}: an empty state dict")
    keys = {}
    for key in state:
        if not isinstance(key, str):
            raise ModelFileError(f"{name}: a state dict key {key!r:.40} is not a string")
        bare = key[len("module."):] if key.startswith("module.") else key
        if bare in keys:
            raise ModelFileError(f"{name}: both {keys[bare]} and {key} name one layer's tensor")
        keys[bare] = key
    layout, layers = _layers(keys, name)
    tensors = []
    for i, (wkey, bkey) in enumerate(layers):
        pair = []
        for k in (wkey, bkey):
            t = state[keys[k]]
            if not isinstance(t, torch.Tensor):
                raise ModelFileError(f"{name}: {k} is a {type(t).__name__}, not a tensor")
            if not t.is_floating_point():
                raise ModelFileError(f"{name}: {k} has dtype {t.dtype}, expected a float type")
            pair.append(t)
        w, b = pair
        if w.dim() != 2 or b.shape != (w.shape[0],):
            raise ModelFileError(f"{name}: layer {i} has weight {tuple(w.shape)} and bias {tuple(b.shape)}, "
                                 f"not a linear layer (out, in) and (out,)")
        tensors.append((w, b))
    arch = _architecture([tuple(w.shape) for w, _ in tensors], name)
    if _SINE_LAYER.match(layers[-1][0]):
        raise ModelFileError(f"{name}: the output layer {layers[-1][0].rsplit('.', 1)[0]} is a sine layer "
                             f"(outermost_linear=False); an SDF's output layer is linear")
    for (w, b), (wkey, bkey) in zip(tensors, layers):
        for t, k in ((w, wkey), (b, bkey)):
            if not torch.isfinite(t).all():
                raise ModelFileError(f"{name}: {k} holds NaN or infinite values")
    dtype = torch.float64 if any(t.dtype == torch.float64 for pair in tensors for t in pair) else torch.float32
    model = Siren(arch["width"], arch["depth"], omega_0=omega_0, hidden_omega=hidden_omega).to(dtype)
    with torch.no_grad():
        for layer, (w, b) in zip(model.layers, tensors):
            layer.weight.copy_(w.to(dtype))
            layer.bias.copy_(b.to(dtype))
    return model.eval(), layout


def _layers(keys: dict[str, str], name) -> tuple[str, list[tuple[str, str]]]:
    """The layout of ``keys`` (stripped key -> saved key) and its layers' (weight key, bias key), in order."""
    for hint in _ENCODING_HINTS:
        hits = [k for k in keys if hint in k.lower()]
        if hits:
            raise ModelFileError(f"{name}: {keys[hits[0]]} looks like a positional encoding; only a plain SIREN of "
                                 f"(x, y, z) is imported")
    layout = next((lay for lay, pat in STATE_LAYOUTS.items() if all(pat.fullmatch(k) for k in keys)), None)
    if layout is None:
        unknown = sorted(keys[k] for k in keys if not any(p.fullmatch(k) for p in STATE_LAYOUTS.values()))
        if not unknown:
            raise ModelFileError(f"{name}: keys of different SIREN layouts mixed (expected one of {_LAYOUT_HELP})")
        shown = ", ".join(unknown[:3]) + (f" and {len(unknown) - 3} more" if len(unknown) > 3 else "")
        raise ModelFileError(f"{name}: unknown keys {shown}; not a plain SIREN (expected {_LAYOUT_HELP})")
    pattern = STATE_LAYOUTS[layout]
    found: dict[int, dict[str, str]] = {}
    for k in keys:
        m = pattern.fullmatch(k)
        if m is None:  # every key matched above
            continue
        slot = found.setdefault(int(m.group(1)), {})
        if m.group(2) in slot:
            raise ModelFileError(f"{name}: layer {m.group(1)} has both {slot[m.group(2)]} and {k}")
        slot[m.group(2)] = k
    n = max(found) + 1
    missing = [i for i in range(n) if i not in found]
    if missing:
        raise ModelFileError(f"{name}: layer {missing[0]} is missing (layers 0 to {n - 1} expected)")
    out = []
    for i in range(n):
        for part in ("weight", "bias"):
            if part not in found[i]:
                other = found[i]["bias" if part == "weight" else "weight"]
                raise ModelFileError(f"{name}: layer {i} has no {part} (beside {other})")
        out.append((found[i]["weight"], found[i]["bias"]))
    if layout == "Siren":
        for wkey, _ in out[:-1]:
            if not _SINE_LAYER.match(wkey):
                raise ModelFileError(f"{name}: {wkey} is a linear layer before the output layer; a SIREN's "
                                     f"hidden layers are sine layers (net.<i>.linear.*)")
    if len(out) < 2:
        raise ModelFileError(f"{name}: a single layer; a SIREN has at least one hidden layer")
    return layout, out


def _architecture(shapes: list[tuple[int, int]], name) -> dict:
    """(width, depth) of a chain of weight shapes (out, in), checked: input (x, y, z), one output, equal
    hidden widths, sizes within the caps."""
    for i in range(1, len(shapes)):
        if shapes[i][1] != shapes[i - 1][0]:
            raise ModelFileError(f"{name}: shapes do not chain: layer {i} takes {shapes[i][1]} inputs, layer "
                                 f"{i - 1} gives {shapes[i - 1][0]}")
    n_in, n_out = shapes[0][1], shapes[-1][0]
    if n_in == _SPATIAL_IN + 1:
        raise ModelFileError(f"{name}: a network of 4 inputs (a space-time SDF?); only static SDFs of (x, y, z) "
                             f"are imported")
    if n_in != _SPATIAL_IN:
        raise ModelFileError(f"{name}: a network of {n_in} inputs (a positional encoding?); an SDF takes (x, y, z)")
    if n_out != 1:
        raise ModelFileError(f"{name}: a network of {n_out} outputs; an SDF has one")
    widths = sorted({s[0] for s in shapes[:-1]})
    if len(widths) > 1:
        raise ModelFileError(f"{name}: hidden layers of unequal widths {widths}; a (W, D) SIREN has one width")
    width, depth = widths[0], len(shapes) - 2
    if width > MAX_NET_WIDTH or depth > MAX_NET_DEPTH:
        raise ModelFileError(f"{name}: a {width}x{depth} network is beyond the caps (width {MAX_NET_WIDTH}, "
                             f"depth {MAX_NET_DEPTH})")
    return {"width": width, "depth": depth}


def read_siren_state(path: str | os.PathLike, *, omega_0: float, hidden_omega: float | None = None):
    """``(siren, layout)`` from a PyTorch file holding a SIREN's state dict (:func:`siren_from_state_dict`).

    The file is read with ``torch.load(map_location="cpu", weights_only=True)``: tensors and plain
    containers only, no code from the file runs.

    Raises:
        ModelFileError: a missing or unreadable file, a pickle of objects weights-only loading refuses (a
            whole model saved with ``torch.save(model)``), and what :func:`siren_from_state_dict` raises.
    """
    path = Path(path)
    _check_file(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        text = str(exc)
        found = re.search(r"Unsupported global: GLOBAL ([\w.]+)", text)
        if found:
            raise ModelFileError(f"{path}: holds pickled Python objects ({found.group(1)}) that weights-only "
                                 f"loading refuses; save the network's state_dict()") from None
        detail = re.search(r"WeightsUnpickler error:\s*(\S[^\n]*)", text)
        reason = f"unpickler: {detail.group(1).strip()[:120]}" if detail else _first_line(exc)
        raise ModelFileError(f"{path}: not a PyTorch file saved with torch.save ({reason})") from None
    except OSError:  # the machine refused the read: the caller's environment error, not the file's content
        raise
    except Exception as exc:  # whatever a foreign file makes the unpickler raise is one line about the file
        raise ModelFileError(f"{path}: not a PyTorch file saved with torch.save ({_first_line(exc)})") from None
    return siren_from_state_dict(state, path, omega_0=omega_0, hidden_omega=hidden_omega)


def raw_siren_size(width: int, depth: int, in_dim: int = _SPATIAL_IN, out_dim: int = 1) -> int:
    """Bytes of a raw float32 file of a (``width``, ``depth``) SIREN: every layer's weight and bias."""
    dims = [in_dim] + [width] * (depth + 1) + [out_dim]
    return 4 * sum((a + 1) * b for a, b in zip(dims[:-1], dims[1:]))


def read_raw_siren(path: str | os.PathLike, *, width: int, depth: int, omega_0: float,
                   hidden_omega: float | None = None):
    """A float32 :class:`~neural_bake.nets.siren.Siren` (x, y, z) -> f of (``width``, ``depth``) from a
    headerless little-endian float32 file, in the order of the module docstring.

    Raises:
        NeuralBakeError: ``width``, ``depth``, ``omega_0`` or ``hidden_omega`` out of range.
        ModelFileError: a missing file, a size other than :func:`raw_siren_size`, non-finite values.
    """
    from ..nets.siren import Siren

    omega_0, hidden_omega = _check_omegas(omega_0, hidden_omega)
    for pname, v, lo, hi in (("width", width, 1, MAX_NET_WIDTH), ("depth", depth, 0, MAX_NET_DEPTH)):
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise NeuralBakeError(f"{pname} = {v!r}: must be an integer from {lo} to {hi}", parameter=pname)
    path = Path(path)
    _check_file(path)
    need, size = raw_siren_size(width, depth), path.stat().st_size
    if size != need:
        raise ModelFileError(f"{path}: {size} bytes, a raw float32 {width}x{depth} SIREN of (x, y, z) -> f has "
                             f"{need} ({need // 4} values)")
    values = np.fromfile(path, dtype="<f4")
    if len(values) * 4 != need:
        raise ModelFileError(f"{path}: read {len(values) * 4} bytes of the {need} expected")
    if not np.isfinite(values).all():
        raise ModelFileError(f"{path}: holds NaN or infinite values (at value {int(np.argmin(np.isfinite(values)))})")
    model = Siren(width, depth, omega_0=omega_0, hidden_omega=hidden_omega)
    flat = torch.from_numpy(values.astype(np.float32))
    at = 0
    with torch.no_grad():
        for layer in model.layers:
            for p in (layer.weight, layer.bias):
                p.copy_(flat[at:at + p.numel()].view_as(p))
                at += p.numel()
    return model.eval()


def import_siren(weights: str | os.PathLike, output: str | os.PathLike, *, omega_0: float,
                 hidden_omega: float | None = None, frame: Frame | None = None, kind: str = "sdf",
                 raw: tuple[int, int] | None = None):
    """Convert SIREN weights from the reference implementations into a field file; returns the
    :class:`~neural_bake.fields.SdfField` it wrote (:func:`~neural_bake.fields.load_field` reads it back).

    Args:
        weights: a state dict file (:func:`read_siren_state`), or with ``raw`` a raw float32 file
            (:func:`read_raw_siren`).
        output: the field file to write (atomically; its folder must exist).
        omega_0, hidden_omega: ω of the first and of the hidden layers as trained (hidden default ``omega_0``);
            stored in the file.
        frame: the unit frame the network was trained in (``unit = (source - center) * scale``); default the
            identity (the network's input space is the source space).
        kind: what the network is; "sdf" (a static signed distance of (x, y, z)).
        raw: ``(width, depth)`` of a raw file; None reads a state dict.

    Raises:
        NeuralBakeError: a bad ``kind``, ω, width or depth; ModelFileError: what the readers raise, or an
            output folder that does not exist.
    """
    from .files import save_field
    from .sdf import SdfField

    if kind != "sdf":
        raise NeuralBakeError(f"kind = {kind!r}: only 'sdf' networks are imported", parameter="kind")
    weights = Path(weights)
    if raw is None:
        model, layout = read_siren_state(weights, omega_0=omega_0, hidden_omega=hidden_omega)
        source = {"file": weights.name, "format": "torch state dict", "layout": layout}
    else:
        model = read_raw_siren(weights, width=raw[0], depth=raw[1], omega_0=omega_0, hidden_omega=hidden_omega)
        source = {"file": weights.name, "format": "raw float32", "layout": "weight (out, in) row-major, bias"}
    field = SdfField.from_model(model, frame=frame or Frame(), name=Path(output).name,
                                metadata={"imported_from": source})
    save_field(field, output)
    return field


def _check_file(path: Path) -> None:
    if not path.exists():
        raise ModelFileError(f"{path}: no such weights file")
    if not path.is_file():
        raise ModelFileError(f"{path}: not a file")


def _first_line(exc: BaseException) -> str:
    lines = [s.strip() for s in str(exc).splitlines() if s.strip()]
    text = lines[0].split(". ")[0] if lines else ""
    return (text if isinstance(exc, RuntimeError) and text else f"{type(exc).__name__} {text}".strip())[:160]
