"""Model files to render assets: an SDF field or a nested sequence (+ an optional texture field), static or
space-time (networks of 4 inputs (x, y, z, t) render frame by frame), read through the field layer."""

from __future__ import annotations

from pathlib import Path

from ..errors import ModelFileError
from ..nets.siren import Siren
from ..types import Frame
from .asset import (RenderAsset, RenderError, SpaceTimeAsset, as_texture, as_render_asset, level_names, siren_level,
                    siren_texture)

__all__ = ["load_asset", "read_field"]


def read_field(path, *, argument: str = "MODEL", device=None):
    """The field a file holds (:func:`neural_bake.fields.load_field`); ModelFileError naming ``argument``
    for a missing file."""
    from ..fields import load_field

    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"{argument} {path}: no such model file")
    return load_field(path, device=device)


def _is_texture(field) -> bool:
    from ..fields import TextureField

    return isinstance(field, TextureField)


def _networks(field) -> list:
    if hasattr(field, "levels"):
        return list(field.levels)
    model = getattr(field, "model", None)
    if not isinstance(model, Siren) and not getattr(model, "composite", False):  # a SIREN or a tiled SDF
        raise RenderError(f"{getattr(field, 'name', 'model')}: not a network-backed SDF field")
    return [model]


def load_asset(path, *, texture=None, deltas=None, device=None, precision: str = "fp32", force: bool = False,
               force_option: str = "force=True") -> RenderAsset | SpaceTimeAsset:
    """A RenderAsset (or a SpaceTimeAsset for 4-input networks) from a model file, with the texture file
    ``texture`` and δ overrides ``deltas`` (coarse to fine; the file's otherwise). ``precision``: "fp32",
    "bf16" or "auto" for the networks' hidden GEMMs (:func:`~neural_bake.nets.precision.resolve_precision`).

    Raises ModelFileError for unreadable files, RenderError for a texture given as MODEL or a texture file
    that is an SDF, NeuralBakeError for a texture fitted in another frame or on another surface than the
    model's (:func:`~neural_bake.fields.check_texture_matches_sdf`; ``force`` renders it anyway with a
    warning, ``force_option`` is how the message names that).
    """
    field = read_field(path, device=device)
    if _is_texture(field):
        raise RenderError(f"{path}: a texture field; give an SDF or nested sequence (and the texture as the "
                          "texture model)")
    tex = None
    if texture is not None:
        tex = read_field(texture, argument="texture", device=device)
        if not _is_texture(tex):
            raise RenderError(f"texture {texture}: not a texture field (3 or 4 outputs)")
        from ..fields import check_texture_matches_sdf

        check_texture_matches_sdf(tex, field, force=force, option=force_option, sdf_name=Path(path).name)
    nets = _networks(field)
    frame = getattr(field, "frame", None)
    ds = list(deltas) if deltas is not None else list(getattr(field, "deltas", None) or [0.0] * len(nets))
    if len(ds) != len(nets):
        raise RenderError(f"deltas: {len(ds)} values for the {len(nets)} levels of {path}")
    in_dims = {int(m.in_dim) for m in nets}
    if in_dims == {3}:
        return as_render_asset(nets, deltas=ds, texture=tex, frame=frame, precision=precision)
    if in_dims != {4}:
        raise RenderError(f"MODEL {path}: networks take {sorted(in_dims)} inputs; expected 3 (x, y, z) or 4 "
                          "(x, y, z, t)")
    names = level_names(nets)
    tex_model = tex.model if tex is not None else None
    from ..fields.spacetime import time_mapping

    # the file's time range and t ↦ the networks' time input (TimeRangeError outside the range)
    time_range, time_input = (time_mapping(field) or (None, None))
    time_range = tuple(time_range or getattr(field, "time_range", None) or (0.0, 1.0))
    time_input = time_input or getattr(field, "time_input", None) or float

    # a texture network that is not a SIREN (a feature grid) is static: read through its field's colours
    static_tx = None if tex is None or isinstance(tex_model, Siren) else as_texture(tex, precision)

    def at(t: float) -> RenderAsset:
        levels = [siren_level(m, 0.0 if i == len(nets) - 1 else float(d), name=n, time=time_input(t),
                              precision=precision)
                  for i, (m, d, n) in enumerate(zip(nets, ds, names))]
        tx = static_tx
        if tex_model is not None and static_tx is None:
            tx = siren_texture(tex_model, time=t if int(tex_model.in_dim) == 4 else None, precision=precision,
                               encoding=getattr(tex, "encoding", "linear"))
        return RenderAsset(levels, frame or Frame(), tx)

    return SpaceTimeAsset(at, time_range)
