"""What a fitted asset is: SDF field, nested sequence, texture field; one load/save, headers validated.

Everything above (fit, bake, render, the CLI) reaches model files only through this layer.
"""

from .files import (BARE_NETWORK_HINT, KINDS, FieldKind, fit_records, load_field, load_model, load_sdf_field,
                    register_kind, save_field, save_model, to_sdf_field)
from .imported import import_siren
from .nested import NESTED_FORMAT, NestedSequence
from .sdf import SdfField, closest_surface_points, unit_normals
from .spacetime import SPACETIME_KIND, SpaceTimeField, time_mapping, time_to_tau
from .texture import (ENCODINGS, ColorField, TextureField, check_texture_matches_sdf, decode_colors,
                      texture_agreement)

__all__ = [
    "SdfField",
    "TextureField",
    "ColorField",
    "ENCODINGS",
    "decode_colors",
    "texture_agreement",
    "check_texture_matches_sdf",
    "NestedSequence",
    "load_field",
    "fit_records",
    "save_field",
    "save_model",
    "load_model",
    "load_sdf_field",
    "to_sdf_field",
    "register_kind",
    "FieldKind",
    "KINDS",
    "BARE_NETWORK_HINT",
    "import_siren",
    "NESTED_FORMAT",
    "closest_surface_points",
    "unit_normals",
    "SpaceTimeField",
    "SPACETIME_KIND",
    "time_mapping",
    "time_to_tau",
]
