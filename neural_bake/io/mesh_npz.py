"""A :class:`~neural_bake.types.Mesh` as one ``.npz`` file: every field (unit frame), a JSON ``meta`` entry with
the frame, the flags and the caller's extra entries (e.g. how the mesh was made), no pickles."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np

from ..errors import MeshError
from ..types import Frame, Mesh
from .atomic import atomic_write_bytes

__all__ = ["mesh_npz_bytes", "save_mesh_npz", "load_mesh_npz"]

#: The array fields of a Mesh kept in the file (the ones that are not None).
_ARRAYS = ("vertices", "faces", "uv", "texture", "vertex_normals", "corner_normals", "degenerate")


def mesh_npz_bytes(mesh: Mesh, extra: dict | None = None) -> bytes:
    """The ``.npz`` file of ``mesh`` (and ``extra``, JSON-serialisable, under ``meta["extra"]``) as bytes. An
    unwrapped mesh's ``source_vertex`` mapping (:func:`neural_bake.mesh.unwrap.unwrap`) is kept too."""
    arrays = {k: getattr(mesh, k) for k in _ARRAYS if getattr(mesh, k) is not None}
    source_vertex = getattr(mesh, "source_vertex", None)
    if source_vertex is not None:
        arrays["source_vertex"] = np.asarray(source_vertex, dtype=np.int64)
    meta = {"frame": mesh.frame.to_dict(), "uv_policy": mesh.uv_policy, "watertight": bool(mesh.watertight),
            "source": mesh.source, "warnings": list(mesh.warnings), "extra": extra or {}}
    buf = io.BytesIO()
    np.savez(buf, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
    return buf.getvalue()


def save_mesh_npz(mesh: Mesh, path: str | Path, extra: dict | None = None) -> None:
    """Write :func:`mesh_npz_bytes` to ``path`` atomically (beside, then renamed)."""
    atomic_write_bytes(Path(path), mesh_npz_bytes(mesh, extra))


def load_mesh_npz(path: str | Path) -> tuple[Mesh, dict]:
    """(Mesh, extra) of a file :func:`save_mesh_npz` wrote. MeshError (naming the file) for anything else or a
    damaged file."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            arrays = {k: z[k] for k in z.files if k != "meta"}
        source_vertex = arrays.pop("source_vertex", None)
        mesh = Mesh(frame=Frame.from_dict(meta["frame"]), uv_policy=meta["uv_policy"], watertight=meta["watertight"],
                    source=meta["source"], warnings=meta["warnings"], **arrays)
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as exc:
        raise MeshError(f"{path}: not a readable mesh file ({type(exc).__name__}: {exc})") from None
    if source_vertex is not None:
        mesh.source_vertex = source_vertex  # type: ignore[attr-defined]  # as unwrap() sets it
    return mesh, meta.get("extra", meta.get("info")) or {}  # "info": the batch's coarse files name it so
