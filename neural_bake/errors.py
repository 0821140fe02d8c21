"""The errors the toolkit raises for bad input.

Every user-facing problem is a :class:`NeuralBakeError` whose message is one line that names the file (or
parameter) and the problem, e.g. ``"bunny.obj: face index 812 out of range (mesh has 400 vertices)"``.
The library names its own parameters, never a CLI option: an error about a parameter's value starts with
the parameter's name and carries it (``parameter="coarse"``), and the CLI puts its option in its place.
The CLI prints it as ``neural-bake: error: <message>`` and exits with the error's ``exit_code``; library
callers catch it.

Exit codes (the CLI's contract):

- **2, user input**: the command line is wrong and another one would work — a bad option or number, an
  input file that is missing or invalid, an output path whose folder does not exist, that is a file where a
  folder is meant (or the reverse), or an output folder holding files neural-bake did not write.
- **1, environment or failed work**: the command line is fine but the machine refused — permission denied,
  read-only file system, disk full or over quota, an I/O error, another run writing the same output
  (:class:`OutputBusyError`) — or the work itself failed. Every ``OSError`` becomes one such line
  (:func:`os_error`), naming the user's path, never a staging path. A fit that diverged
  (:class:`TrainingDivergedError`) is failed work too.
- 130 interrupted (SIGINT), 143 terminated (SIGTERM): the run cleaned up and left the outputs as they were.
"""

from __future__ import annotations

__all__ = [
    "NeuralBakeError",
    "MeshError",
    "ImageError",
    "ModelFileError",
    "FitError",
    "TrainingDivergedError",
    "TimeRangeError",
    "NeuralBakeWarning",
    "OutputError",
    "WriteError",
    "OutputBusyError",
    "MissingExtraError",
    "USER_INPUT_ERRNOS",
    "os_error",
]

import errno as _errno
import os as _os


class NeuralBakeError(ValueError):
    """Base class: bad input or a run that cannot go on. The message is one line.

    Args:
        message: the problem, naming the file or parameter; whitespace runs are folded to one space.
        parameter: the library parameter whose value is wrong, when the message starts with its name.
    """

    exit_code = 2
    """The CLI's exit code for this error: 2 user input (see the module docstring)."""

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
    """Settings or data a fit cannot run with (a bad setting, a mesh with nothing to sample, a checkpoint of
    another run): exit code 2."""


class TrainingDivergedError(FitError):
    """Training diverged and learning-rate halvings did not cure it, or the trained network gives non-finite
    values: the work failed although the command line was fine, exit code 1."""

    exit_code = 1


class TimeRangeError(NeuralBakeError):
    """A time outside the range a space-time field was fitted over (no extrapolation)."""


class OutputError(NeuralBakeError):
    """An output path that cannot be used as given (its folder is missing, it is a file, it holds files that
    no neural-bake run wrote): exit code 2."""


class WriteError(NeuralBakeError):
    """The machine refused a read or write of a path the user named (permission, full disk, read-only file
    system, I/O error): exit code 1, or 2 when the path itself is wrong (``USER_INPUT_ERRNOS``)."""

    exit_code = 1

    def __init__(self, message: str, exit_code: int | None = None):
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


class OutputBusyError(WriteError):
    """Another process holds the lock of the output (one writer per output): exit code 1."""


class MissingExtraError(NeuralBakeError):
    """An optional dependency the asked output needs is not installed (the message says how to install it):
    exit code 1, the command line is fine but the machine lacks it."""

    exit_code = 1


#: errnos that say the path the user gave is wrong (exit 2); every other OSError is the environment (exit 1)
USER_INPUT_ERRNOS = frozenset({_errno.ENOENT, _errno.ENOTDIR, _errno.EISDIR, _errno.ENAMETOOLONG, _errno.ELOOP,
                               _errno.EEXIST})


def os_error(exc: OSError, path: str | _os.PathLike | None = None) -> WriteError:
    """One-line :class:`WriteError` for ``exc``: ``"<path>: <reason>"``, exit code by errno.

    ``path`` is the user's path to name (default: the error's own file name); callers writing through a
    staging path pass the user's path here so a hidden staging name never reaches the message.
    """
    where = path if path is not None else (exc.filename if exc.filename is not None else None)
    reason = exc.strerror or str(exc) or type(exc).__name__
    code = 2 if exc.errno in USER_INPUT_ERRNOS else 1
    return WriteError(f"{_os.fspath(where)}: {reason}" if where is not None else reason, exit_code=code)


class NeuralBakeWarning(UserWarning):
    """A problem in the input that the toolkit handles by a stated policy (open mesh, degenerate faces, …)."""
