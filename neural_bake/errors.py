"""The errors the toolkit raises for bad input.

Every user-facing problem is a :class:`NeuralBakeError` whose message is one line that names the file (or
parameter) and the problem, e.g. ``"bunny.obj: face index 812 out of range (mesh has 400 vertices)"``.
The library names its own parameters, never a CLI option: an error about a parameter's value starts with
the parameter's name and carries it (``parameter="coarse"``), and the CLI puts its option in its place.
The CLI prints it as ``neural-bake: error: <message>`` and exits with code 2; library callers catch it.
"""

from __future__ import annotations

__all__ = [
    "NeuralBakeError",
    "MeshError",
    "ImageError",
    "ModelFileError",
    "FitError",
    "NeuralBakeWarning",
]


class NeuralBakeError(ValueError):
    """Base class: bad input or a run that cannot go on. The message is one line.

    Args:
        message: the problem, naming the file or parameter; whitespace runs are folded to one space.
        parameter: the library parameter whose value is wrong, when the message starts with its name.
    """

    def __init__(self, message: str, *, parameter: str | None = None):
        super().__init__(" ".join(str(message).split()))
        self.parameter = parameter


class MeshError(NeuralBakeError):
    """A mesh file that is missing, unreadable, of an unknown format or invalid."""


class ImageError(NeuralBakeError):
    """An image file that is missing, unreadable, of an unknown format or invalid."""


class ModelFileError(NeuralBakeError):
    """A model file that is missing, corrupt, truncated or of another architecture."""


class FitError(NeuralBakeError):
    """Training that cannot go on (divergence that a smaller learning rate did not cure, no samples)."""


class NeuralBakeWarning(UserWarning):
    """A problem in the input that the toolkit handles by a stated policy (open mesh, degenerate faces, …)."""
