"""Moved to :mod:`neural_bake.fields` (one field layer below fit, bake and render); this re-export stays for
one release so that code importing ``neural_bake.bake.fields`` keeps working. New code imports
``neural_bake.fields``."""

from ..fields import ColorField, SdfField, TextureField, load_field

__all__ = ["SdfField", "ColorField", "TextureField", "load_field"]
