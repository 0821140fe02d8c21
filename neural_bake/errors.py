"""The errors the toolkit raises for bad input.

Every user-facing problem is a :class:`NeuralBakeError` whose message is one line that names the file (or
argument) and the problem, e.g. ``"bunny.obj: face index 812 out of range (mesh has 400 vertices)"``.
The CLI prints it as ``neural-bake: error: <message>`` and exits with code 2; library callers catch it.
"""

from __future__ import annotations

__all__ = [
    "NeuralBakeError",
    "MeshError",
    "ImageError",
    "ModelFileError",
    "FitError",
    "TimeRangeError",
    "NeuralBakeWarning",
]


class NeuralBakeError(ValueError):
    """Base class: bad input or a run that cannot go on. The message is one line."""

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))


class MeshError(NeuralBakeError):
    """A mesh file that is missing, unreadable, of an unknown format or invalid."""


class ImageError(NeuralBakeError):
    """An image file that is missing, unreadable, of an unknown format or invalid."""


class ModelFileError(NeuralBakeError):
    """A model file that is missing, corrupt, truncated or of another architecture."""


class FitError(NeuralBakeError):
    """Training that cannot go on (divergence that a smaller learning rate did not cure, no samples)."""


class TimeRangeError(NeuralBakeError):
    """A time outside the range a space-time field was fitted over (no extrapolation)."""


class NeuralBakeWarning(UserWarning):
    """A problem in the input that the toolkit handles by a stated policy (open mesh, degenerate faces, …)."""
