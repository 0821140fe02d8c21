"""The nested sequence of neural SDFs h_1, …, h_k, f with thresholds δ (paper §3.2–3.3, Prop. 1): the asset
that bake, texture fitting and the renderer use.

File: ONE safetensors file, tensors ``levels.<i>.layers.<j>.{weight,bias}``, metadata ``{"format":
"neural_bake.nested", "neural_bake": JSON}`` with ``kind`` ("nested"), ``architectures`` (one per level),
``frame``, ``levels_info``, ``band``, ``eps``, ``stability`` and ``metadata``. How the sequence is fitted
(distillation, sampled and certified sup-norms) is :mod:`neural_bake.fit.nested`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import torch

from .. import __version__
from ..constants import MAX_NESTED_LEVELS
from ..errors import ModelFileError
from ..types import Frame
from .header import check_delta, check_frame, check_number
from .sdf import SdfField

__all__ = ["NestedSequence", "NESTED_FORMAT", "NESTED_FORMAT_VERSION"]

#: The ``format`` value of a nested-sequence file.
NESTED_FORMAT = "neural_bake.nested"
#: Version of the layout; a sequence whose fine level is a tiled SDF (an architecture with ``"network": "tiles"``)
#: is written as version 2, so that readers that know only SIRENs refuse it with "upgrade"; others as version 1.
NESTED_FORMAT_VERSION = 2


@dataclass
class NestedSequence:
    """Neural SDFs ``levels = [h_1, …, h_k, f]`` (coarse to fine) with their nesting thresholds.

    All networks map unit-frame points (N, 3) to (N, 1) signed distances; ``frame`` maps back to the
    source frame. ``levels_info[i]`` describes level i: ``{"width", "depth", "steps", "best_step", "seconds",
    "sup_estimated", "sup_certified", "delta_estimated", "delta_certified", "delta", "delta_source"
    ("estimated": a sampled estimate, "certified": a range-analysis bound, "eps": the fine level), "certify":
    {...}}``; the fine level's δ is ``eps``. By Prop. 1 the bands nest, [|h_{i+1}| ≤ δ_{i+1}] ⊂ [|h_i| ≤ δ_i],
    so level i's zero set lies in f's band |f| ≤ δ_i: ``deltas[0]`` is the widest band.
    """

    levels: list
    """Networks coarse to fine (SIRENs); the last one is the fine SDF f (a SIREN or a
    :class:`~neural_bake.nets.tiles.TiledSdf`)."""
    frame: Frame = field(default_factory=Frame)
    """Source ↔ unit frame transform."""
    levels_info: list[dict] = field(default_factory=list)
    """Per level: architecture, training iterations, sup-norms and δ (see the class docstring)."""
    band: float = 0.1
    """Δ: half-width of the band (unit frame) where the sup-norms are measured."""
    eps: float = 1e-3
    """ε of Prop. 1 added to the sup-norms (and the fine level's δ)."""
    stability: list[list[dict]] = field(default_factory=list)
    """Per coarse level: rows ``{"samples", "band", "sup"}`` of the estimate over sample sizes and Δ."""
    metadata: dict = field(default_factory=dict)
    """Free JSON metadata (source model, settings, package version)."""
    name: str = "nested"
    """What messages and reports call it (the file name for a loaded sequence)."""

    @property
    def deltas(self) -> list[float]:
        """δ per level (coarse to fine) to render with: ``levels_info[i]["delta"]``, built from the certified
        sup-norm of each level whose certification met its target (within ``certify_rel_tol`` of the
        estimate) and from the estimate elsewhere (``"delta_source"`` says which)."""
        return [float(info["delta"]) for info in self.levels_info]

    @property
    def deltas_estimated(self) -> list[float]:
        """δ per level from the sampled sup-norms."""
        return [float(i["delta_estimated"]) for i in self.levels_info]

    @property
    def deltas_certified(self) -> list[float | None]:
        """δ per level from the certified sup-norms (None where certification was not run)."""
        return [None if i.get("delta_certified") is None else float(i["delta_certified"]) for i in self.levels_info]

    @property
    def iterations(self) -> list[int]:
        """Training steps of each level (0 for the fine level, trained elsewhere)."""
        return [int(i.get("steps", 0)) for i in self.levels_info]

    @property
    def in_dim(self) -> int:
        """Input dimension of the levels: 3 (space); a space-time sequence has 4."""
        return int(self.levels[-1].in_dim)

    def _index(self, i: int) -> int:
        n = len(self.levels)
        if isinstance(i, bool) or int(i) != i or not -n <= i < n:
            raise ModelFileError(f"{self.name}: no level {i!r} (the sequence has levels 0..{n - 1})")
        return int(i) % n

    def level(self, i: int) -> SdfField:
        """Level ``i`` (0 = coarsest, −1 = f) as an :class:`SdfField` with its own δ_i."""
        i = self._index(i)
        return SdfField.from_model(self.levels[i], frame=self.frame, delta=self.deltas[i],
                                   name=f"{self.name} level {i}",
                                   metadata={"kind": "nested", "level": i, **self.levels_info[i]})

    @property
    def finest(self) -> SdfField:
        """The fine SDF f as an :class:`SdfField` with its own δ (ε)."""
        return self.level(-1)

    def band_field(self, level: int = 0) -> SdfField:
        """The fine SDF f with the band δ of ``level``: what a bake onto (or a texture fit for) surfaces up to
        that level uses — normals and colours from f, the miss map and band from δ_level (level 0, the
        default, is the widest band, which holds every level's zero set)."""
        i = self._index(level)
        return SdfField.from_model(self.levels[-1], frame=self.frame, delta=self.deltas[i],
                                   name=f"{self.name} (f, band of level {i})",
                                   metadata={"kind": "nested", "band_level": i,
                                             "delta_source": self.levels_info[i].get("delta_source")})

    def header(self) -> dict:
        """The JSON header of the file (see the module docstring)."""
        return {
            "format": NESTED_FORMAT, "package_version": __version__,
            "format_version": 2 if any(getattr(m, "composite", False) for m in self.levels) else 1,
            "kind": "nested", "architectures": [m.architecture for m in self.levels], "frame": self.frame.to_dict(),
            "levels_info": self.levels_info, "band": self.band, "eps": self.eps, "stability": self.stability,
            "metadata": self.metadata,
        }

    def save(self, path) -> Path:
        """Write ONE safetensors file atomically (:func:`neural_bake.fields.save_field`)."""
        from .files import save_field

        return save_field(self, path)

    @classmethod
    def load(cls, path, *, device=None) -> "NestedSequence":
        """Read a nested-sequence file; ModelFileError (one line) for anything wrong with it or another kind."""
        from .files import load_field

        out = load_field(path, device=device)
        if not isinstance(out, cls):
            raise ModelFileError(f"{path}: not a nested-sequence file (a {type(out).__name__})")
        return out


def read_nested(path: Path, header: dict, *, device=None, dtype=None) -> NestedSequence:
    """A :class:`NestedSequence` from a file whose JSON ``header`` was parsed (depth-checked, version
    checked); every value is checked here before any network is built."""
    from ..nets.model_io import (build_network, check_architecture, check_network_architecture,
                                 expected_network_shapes, read_state)

    archs = header.get("architectures")
    if not isinstance(archs, list) or not 1 <= len(archs) <= MAX_NESTED_LEVELS:
        raise ModelFileError(f"{path}: architectures is not a list of 1 to {MAX_NESTED_LEVELS} levels")
    # every level a SIREN; the fine one may be a tiled SDF (a coarse SIREN and its tiles, R^3 to R)
    fine_tiled = isinstance(archs[-1], dict) and archs[-1].get("network") == "tiles"
    archs = [check_network_architecture(a, path, f"level {i} ") if fine_tiled and i == len(archs) - 1
             else check_architecture(a, path, f"level {i} ") for i, a in enumerate(archs)]
    dims = [(3, 1) if a.get("network") == "tiles" else (a["in_dim"], a["out_dim"]) for a in archs]
    for i, (d_in, d_out) in enumerate(dims):
        if d_out != 1 or d_in != dims[-1][0]:
            raise ModelFileError(f"{path}: level {i} maps R^{d_in} to R^{d_out}; every level of a "
                                 f"nested sequence is an SDF of the same input")
    frame = check_frame(header.get("frame"), path, required=True)
    infos = header.get("levels_info")
    if not isinstance(infos, list) or len(infos) != len(archs) or not all(isinstance(i, dict) for i in infos):
        raise ModelFileError(f"{path}: levels_info is not one object per level ({len(archs)})")
    for i, info in enumerate(infos):
        info["delta"] = check_delta(info.get("delta"), path, f"levels_info[{i}].delta") or 0.0
        for key in ("delta_estimated", "delta_certified", "sup_estimated", "sup_certified"):
            if key in info:
                info[key] = check_number(info[key], path, f"levels_info[{i}].{key}", allow_none=True)
    band = check_number(header.get("band"), path, "band", positive=True)
    eps = check_number(header.get("eps"), path, "eps")
    stability = header.get("stability", [])
    metadata = header.get("metadata", {})
    if not isinstance(stability, list) or not isinstance(metadata, dict):
        raise ModelFileError(f"{path}: stability must be a list and metadata an object")
    if dims[-1][0] == 4:  # space-time levels: the file must say how t maps onto their time input
        from .spacetime import check_time_mapping

        st = metadata.get("spacetime")
        if not isinstance(st, dict):
            raise ModelFileError(f"{path}: levels of 4 inputs (x, y, z, t) but no time mapping "
                                 f"(metadata.spacetime with time_range and time_extent)")
        check_time_mapping(st, f"{path}: metadata.spacetime")
    elif dims[-1][0] != 3:
        raise ModelFileError(f"{path}: levels of {dims[-1][0]} inputs; a nested sequence's levels take "
                             f"3 (x, y, z) or 4 (x, y, z, t)")
    expected = {}
    for i, a in enumerate(archs):
        expected.update(expected_network_shapes(a, f"levels.{i}."))
    state = read_state(path, expected)
    levels = [build_network(a, state, path, prefix=f"levels.{i}.", device=device, dtype=dtype)
              for i, a in enumerate(archs)]
    return NestedSequence(levels=levels, frame=frame, levels_info=infos, band=band, eps=eps, stability=stability,
                          metadata=metadata, name=Path(path).name)


def nested_tensors(seq: NestedSequence) -> dict[str, torch.Tensor]:
    """The tensors of ``seq``'s file: ``levels.<i>.<state_dict name>``."""
    return {f"levels.{i}.{k}": v.detach().to("cpu").contiguous()
            for i, m in enumerate(seq.levels) for k, v in m.state_dict().items()}
