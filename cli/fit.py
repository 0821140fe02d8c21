"""`neural-bake fit …`: train the neural fields (sdf, nested, texture)."""

from __future__ import annotations

import click

from .main import LazyGroup

FITS = {
    "sdf": ("neural_bake.cli.fit_sdf", "command"),
    "nested": ("neural_bake.cli.fit_nested", "command"),
    "texture": ("neural_bake.cli.fit_texture", "command"),
}


@click.group(cls=LazyGroup, lazy=FITS)
def group():
    """Fit neural fields to a mesh: a fine SDF, its nested coarse levels, a texture MLP."""
