"""Content hashes (SHA-256, hex) of files, arrays and JSON-able settings: the keys of stage caches."""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np

__all__ = ["file_digest", "arrays_digest", "json_digest"]

_CHUNK = 1 << 20


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of the file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def arrays_digest(*arrays) -> str:
    """SHA-256 of arrays' dtypes, shapes and bytes, in order; None entries count (as a marker)."""
    h = hashlib.sha256()
    for a in arrays:
        if a is None:
            h.update(b"none;")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape};".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def json_digest(obj) -> str:
    """SHA-256 of ``obj`` as canonical JSON (sorted keys, no spaces; tuples as lists)."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()
