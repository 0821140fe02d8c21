"""Atomic writes: every file the project writes goes through here.

The content is written to a temporary file in the destination's folder, flushed and fsynced, then renamed
over the destination (``os.replace``, atomic on POSIX and Windows). If anything fails before the rename,
the temporary file is removed and the destination — an earlier good file, if any — is untouched.
The temporary file is named ``.<name>.<pid>.<random>.tmp<suffix>``: a run killed before its rename leaves it,
and the next run that locks the output (:mod:`neural_bake.io.outdir`) removes it once its pid is gone.
An OSError (or a safetensors I/O error) names the destination, never the temporary file.
A destination that is a symlink is followed (:func:`link_target`): the new content is written at the file it
points to and the link stays a link.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import tempfile
from pathlib import Path
from typing import Iterator

from ..errors import OutputError
from .faults import fault_point

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "link_target", "replacement_mode"]


def link_target(path: str | os.PathLike) -> Path:
    """Where a write to ``path`` goes: ``path`` itself, or for a symlink the path its chain of links ends at.

    Writers commit at the target so that a link stays a link to the new content, and never replace or delete
    the link itself. A dangling link's target may be created (its folder must exist). Raises
    :class:`~neural_bake.errors.OutputError` (naming ``path``) for a symlink loop or a link whose target's
    folder does not exist.
    """
    p = Path(path)
    if not os.path.islink(p):
        return p
    try:
        os.stat(p)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OutputError(f"{p}: a symlink loop (the link never reaches a file or folder)") from None
        if exc.errno not in (errno.ENOENT, errno.ENOTDIR):
            raise OSError(exc.errno, exc.strerror, str(p)) from None
    target = Path(os.path.realpath(p))
    if not target.parent.is_dir():
        raise OutputError(f"{p}: a symlink to {target}, whose folder does not exist")
    return target


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    Use for writers that want a file name (OpenImageIO, trimesh, safetensors)::

        with atomic_path("out/map.png") as tmp:
            write_png(tmp)

    ``suffix`` defaults to the destination's own suffix, so writers that pick a format by extension work.
    The destination's folder must exist. On an exception the temporary file is deleted and re-raised.
    """
    dest = Path(path)
    target = link_target(dest)  # a symlink stays one: the content goes where it points
    folder = target.parent if str(target.parent) else Path(".")
    if suffix is None:
        suffix = "".join(dest.suffixes[-1:])
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.{os.getpid()}.", suffix=f".tmp{suffix}", dir=folder)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, str(dest)) from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if not tmp.exists() or tmp.stat().st_size == 0 and not _allow_empty(dest):
            raise OSError(f"{dest}: writer produced no data")
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        # mkstemp makes the file private (0600): give it the replaced file's mode, else the umask default
        os.chmod(tmp, replacement_mode(target))
        fault_point("file-temp")
        os.replace(tmp, target)
        fault_point("file-renamed")
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError) and exc.errno is not None and exc.filename in (None, tmp_name, tmp):
            raise OSError(exc.errno, exc.strerror, str(dest)) from exc
        if type(exc).__name__ == "SafetensorError":  # safetensors reports I/O failures as its own error type
            raise _safetensors_os_error(exc, dest) from exc
        raise


def _safetensors_os_error(exc: BaseException, dest: Path) -> OSError:
    """The OSError behind a safetensors I/O error (its message ends ``(os error N)``), naming ``dest``."""
    found = re.search(r"os error (\d+)|code: (\d+)", str(exc))
    code = int(found.group(1) or found.group(2)) if found else errno.EIO
    return OSError(code, os.strerror(code), str(dest))


def replacement_mode(dest: Path, default: int = 0o666) -> int:
    """Permission bits for what replaces ``dest``: those of ``dest``, else ``default`` minus the umask."""
    try:
        return dest.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return default & ~umask


def _allow_empty(dest: Path) -> bool:
    return dest.suffix in {".txt", ".log", ".json"}


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; return the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically; return the path."""
    return atomic_write_bytes(path, text.encode(encoding))
