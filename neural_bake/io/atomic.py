"""Atomic writes: every file the project writes goes through here.

The content is written to a temporary file in the destination's folder, flushed and fsynced, then renamed
over the destination (``os.replace``, atomic on POSIX and Windows). If anything fails before the rename,
the temporary file is removed and the destination — an earlier good file, if any — is untouched.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "atomic_folder"]


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
    folder = dest.parent if str(dest.parent) else Path(".")
    if suffix is None:
        suffix = "".join(dest.suffixes[-1:])
    fd, tmp_name = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=f".tmp{suffix}", dir=folder)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if not tmp.exists() or tmp.stat().st_size == 0 and not _allow_empty(dest):
            raise OSError(f"{dest}: writer produced no data")
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        # mkstemp makes the file private (0600): give it the replaced file's mode, else the umask default
        os.chmod(tmp, _target_mode(dest))
        os.replace(tmp, dest)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def _target_mode(dest: Path) -> int:
    """Permission bits for the written file: those of the file it replaces, else 0o666 minus the umask."""
    try:
        return dest.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


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


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike) -> Iterator[Path]:
    """A folder committed as a unit: yields a temporary folder beside ``path`` to fill; on success it replaces
    ``path`` (an existing folder is moved aside, the new one renamed into place, the old one deleted), so a
    reader sees the whole old set or the whole new set. On failure the temporary folder is removed and
    ``path`` is untouched. The parent folder must exist."""
    import shutil

    dest = Path(path)
    parent = dest.parent if str(dest.parent) else Path(".")
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=parent))
    try:
        yield tmp
        if dest.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{dest.name}.old.", dir=parent))
            dest.rename(old / dest.name)
            tmp.rename(dest)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
