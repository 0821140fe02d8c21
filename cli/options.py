"""What every writing verb checks before any work: numbers in range, outputs locked for this run alone."""

from __future__ import annotations

import math

import click

__all__ = ["refuse_nonpositive", "lock_outputs"]


def refuse_nonpositive(**options) -> None:
    """NeuralBakeError naming the first option (``max_boxes`` -> ``--max-boxes``) set to a non-positive or
    non-finite number; options left unset (None) are skipped."""
    from neural_bake.errors import NeuralBakeError

    for name, value in options.items():
        if value is not None and not (math.isfinite(value) and value > 0):
            raise NeuralBakeError(f"--{name.replace('_', '-')} {value}: must be a positive number")


def lock_outputs(*paths) -> None:
    """Lock the output files ``paths`` (None skipped) until the verb ends: a second run writing any of them
    fails at once naming this one, and temporary files of killed runs are removed (see neural_bake.io.outdir)."""
    from neural_bake.io.outdir import locked_outputs

    click.get_current_context().with_resource(locked_outputs(*paths))
