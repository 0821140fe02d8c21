"""Output paths named by input files (manifests, configs): a relative name can never leave its root folder.

:func:`inside` joins a root and a relative name and refuses, with one line naming the name, an absolute
path, a ``..`` component, an empty or hidden component (``.x`` names are the toolkit's staging, locks and
caches), and any path whose real location (symlinks resolved) is not under the root's real location.
"""

from __future__ import annotations

import os
from pathlib import Path, PurePosixPath

from ..errors import NeuralBakeError

__all__ = ["inside", "check_relative_name"]


def check_relative_name(name: str, *, what: str = "name") -> PurePosixPath:
    """The relative POSIX path ``name`` (``/`` separated, one or more components), or NeuralBakeError.

    Refuses: empty, absolute (``/x``, ``C:\\x``, ``\\\\host``), ``..`` or ``.`` components, components starting
    with ``.``, backslashes and control characters (a name must mean the same path on every system).
    """
    text = str(name)
    if not text.strip():
        raise NeuralBakeError(f"{what} {name!r}: empty")
    if "\\" in text or any(ord(c) < 32 for c in text):
        raise NeuralBakeError(f"{what} {name!r}: backslashes and control characters are not allowed "
                              f"(use / between folders)")
    if text.startswith("/") or (len(text) > 1 and text[1] == ":"):
        raise NeuralBakeError(f"{what} {name!r}: must be a relative path inside the output folder")
    parts = text.split("/")
    for part in parts:
        if part in ("", ".", ".."):
            raise NeuralBakeError(f"{what} {name!r}: must not contain empty, '.' or '..' components")
        if part.startswith("."):
            raise NeuralBakeError(f"{what} {name!r}: components must not start with '.' (reserved)")
    return PurePosixPath(*parts)


def inside(root: str | os.PathLike, name: str, *, what: str = "name") -> Path:
    """``root / name`` after :func:`check_relative_name`, refused if its real path (symlinks followed, as far
    as the path exists) is not inside the real path of ``root``."""
    rel = check_relative_name(name, what=what)
    root_real = Path(os.path.realpath(root))
    target = Path(root, *rel.parts)
    real = Path(os.path.realpath(target))
    if real != root_real and root_real not in real.parents:
        raise NeuralBakeError(f"{what} {name!r}: resolves to {real}, outside the output folder {root_real} "
                              f"(a symlink leaves it)")
    return target
