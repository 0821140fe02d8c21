"""`neural-bake fit …`: train the neural fields (sdf, nested, texture; space-time: morph, sequence)."""

from __future__ import annotations

import click

from .main import LazyGroup

FITS = {
    "sdf": ("neural_bake.cli.fit_sdf", "command"),
    "nested": ("neural_bake.cli.fit_nested", "command"),
    "texture": ("neural_bake.cli.fit_texture", "command"),
    "morph": ("neural_bake.cli.fit_morph", "command"),
    "sequence": ("neural_bake.cli.fit_sequence", "command"),
}


@click.group(cls=LazyGroup, lazy=FITS)
def group():
    """Fit neural fields to a mesh: a fine SDF, its nested coarse levels, a texture MLP; space-time SDFs: a
    morph between two shapes, a sequence of mesh frames."""
