"""Coarse meshes and UV layouts kept on disk between runs, keyed by the content they are made from.

A bake that repeats with the same source mesh and coarse spec (another map size, other maps, another model of
the same mesh) need not decimate again, and one onto the same coarse mesh at the same map size need not unwrap
again (:meth:`LayoutCache.unwrap`, which a :class:`~neural_bake.bake.baker.Baker` given the cache uses). Entries are ``.npz`` files (:mod:`neural_bake.io.mesh_npz`) in ``machine_cache_dir()/layouts``, named
by a BLAKE2 digest of every input array's bytes and shape, the settings, the versions of the library that
made them (pymeshlab, fast-simplification, xatlas) and :data:`LAYOUT_CACHE_VERSION`, so a changed input, setting or library makes
a new entry instead of reading an old one. Written atomically; an unreadable entry is made again and
replaced; the least recently used entries beyond :data:`LAYOUT_CACHE_ENTRIES` are deleted. What is cached is
only what the maker would have returned: a hit gives the same arrays.
"""

from __future__ import annotations

import functools
import hashlib
import os
import time
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import MeshError
from ..types import Mesh

__all__ = ["LayoutCache", "mesh_digest", "LAYOUT_CACHE_VERSION", "LAYOUT_CACHE_ENTRIES"]

#: Part of every key: raised when what an entry holds (or how it is made) changes.
LAYOUT_CACHE_VERSION = 3

#: Entries kept (least recently used deleted beyond it); a 2,000-face layout is about 150 KB.
LAYOUT_CACHE_ENTRIES = 64


@functools.lru_cache(maxsize=None)
def _library_version(name: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return "absent"


def mesh_digest(mesh: Mesh) -> str:
    """Hex digest of what a coarse mesh or layout is made from: the mesh's vertices, faces, UVs, vertex normals
    and degenerate-face flags (their bytes, dtypes and shapes) and its frame."""
    h = hashlib.blake2b(digest_size=20)
    for name in ("vertices", "faces", "uv", "vertex_normals", "degenerate"):
        a = getattr(mesh, name)
        if a is None:
            h.update(f"{name}:none;".encode())
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{name}:{a.dtype.str}:{a.shape};".encode())
        h.update(a.tobytes())
    h.update(repr(sorted(mesh.frame.to_dict().items())).encode())
    return h.hexdigest()


class LayoutCache:
    """The on-disk store (module docstring). ``folder``: default ``machine_cache_dir()/layouts``; ``clock``:
    seconds for the recency of entries (injectable in tests)."""

    def __init__(self, folder: str | os.PathLike | None = None, *, max_entries: int = LAYOUT_CACHE_ENTRIES,
                 clock: Callable[[], float] = time.time):
        if folder is None:
            from ..nets.machine import machine_cache_dir

            folder = machine_cache_dir() / "layouts"
        self.folder = Path(folder)
        self.max_entries = int(max_entries)
        self.clock = clock

    def key(self, kind: str, *parts: str) -> str:
        """The entry name of ``kind`` ("coarse", "unwrap") made from ``parts`` (digests and settings)."""
        libs = ",".join(f"{n}={_library_version(n)}" for n in ("pymeshlab", "fast-simplification", "xatlas"))
        h = hashlib.blake2b(f"v{LAYOUT_CACHE_VERSION};{kind};{libs};".encode(), digest_size=20)
        for p in parts:
            h.update(f"{p};".encode())
        return f"{kind}-{h.hexdigest()}"

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.npz"

    def get(self, key: str) -> tuple[Mesh, dict] | None:
        """(mesh, extra) of entry ``key``, or None when there is none or it cannot be read (it is then removed)."""
        from ..io.mesh_npz import load_mesh_npz

        p = self.path(key)
        if not p.is_file():
            return None
        try:
            found = load_mesh_npz(p)
        except MeshError:
            p.unlink(missing_ok=True)
            return None
        now = self.clock()
        try:
            os.utime(p, (now, now))  # recency for the pruning
        except OSError:
            pass
        return found

    def put(self, key: str, mesh: Mesh, extra: dict | None = None) -> None:
        """Store ``mesh`` (and JSON-serialisable ``extra``) as entry ``key``, then prune. A failure to write
        (read-only or full disk) only loses the entry."""
        from ..io.mesh_npz import save_mesh_npz

        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            save_mesh_npz(mesh, self.path(key), extra)
            now = self.clock()
            os.utime(self.path(key), (now, now))
            self._prune()
        except OSError:
            pass

    def get_or_make(self, key: str, make: Callable[[], tuple[Mesh, dict]]) -> tuple[Mesh, dict, bool]:
        """(mesh, extra, hit): entry ``key``, or ``make()`` stored as it."""
        found = self.get(key)
        if found is not None:
            return found[0], found[1], True
        mesh, extra = make()
        self.put(key, mesh, extra)
        return mesh, extra, False

    def unwrap(self, mesh: Mesh, **options) -> tuple[Mesh, bool]:
        """(:func:`neural_bake.mesh.unwrap.unwrap` of ``mesh`` with ``options``, whether it came from the
        cache): read when an earlier run unwrapped the same mesh with the same options, else made and stored."""
        from .unwrap import unwrap

        key = self.key("unwrap", mesh_digest(mesh), repr(sorted(options.items())))
        out, _, hit = self.get_or_make(key, lambda: (unwrap(mesh, **options), {}))
        return out, hit

    def _prune(self) -> None:
        entries = []
        for p in self.folder.glob("*.npz"):
            try:
                entries.append((p.stat().st_mtime, p))
            except OSError:
                continue
        entries.sort(reverse=True)
        for _, p in entries[self.max_entries:]:
            p.unlink(missing_ok=True)
