"""Plain data passed between the stages: the unit frame and the textured triangle mesh."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .constants import UNIT_FRAME_EXTENT

__all__ = ["Frame", "Mesh"]


@dataclass(frozen=True)
class Frame:
    """Similarity transform between a mesh's source frame and the unit frame.

    ``unit = (source - center) * scale`` and ``source = unit / scale + center``. Normals are unchanged
    (a uniform scale and a translation keep directions); distances scale by ``scale``.
    """

    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Centre of the source bounding box, in source units."""
    scale: float = 1.0
    """Unit-frame length of one source unit."""

    @classmethod
    def fit(cls, vertices: np.ndarray, extent: float = UNIT_FRAME_EXTENT) -> "Frame":
        """The frame that centres ``vertices`` (N, 3) and scales their longest side to ``extent``."""
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        side = float((hi - lo).max())
        scale = extent / side if side > 0 else 1.0
        return cls(tuple(float(c) for c in (lo + hi) / 2), scale)

    def to_unit(self, points: np.ndarray) -> np.ndarray:
        """Source-frame points (..., 3) to the unit frame."""
        return (np.asarray(points, dtype=np.float64) - np.asarray(self.center)) * self.scale

    def to_source(self, points: np.ndarray) -> np.ndarray:
        """Unit-frame points (..., 3) back to the source frame."""
        return np.asarray(points, dtype=np.float64) / self.scale + np.asarray(self.center)

    def distance_to_source(self, d):
        """A unit-frame distance (scalar or array) in source units."""
        return d / self.scale

    def to_dict(self) -> dict:
        return {"center": list(self.center), "scale": self.scale}

    @classmethod
    def from_dict(cls, d: dict) -> "Frame":
        return cls(tuple(float(c) for c in d["center"]), float(d["scale"]))


@dataclass
class Mesh:
    """A validated triangle mesh in the unit frame, with optional UVs and base-colour texture.

    Shapes (V vertices, F faces):
    - ``vertices``: (V, 3) float64, unit frame (see :class:`Frame`).
    - ``faces``: (F, 3) int64, counter-clockwise seen from outside (outward normals; fixed on load).
    - ``uv``: (F, 3, 2) float64 per face corner, or None. Origin at the image's bottom-left (OpenGL/glTF
      images are flipped on read so that v = 0 is the bottom row). May lie outside [0, 1].
    - ``texture``: (H, W, C) float32 linear RGB (C = 3) or RGBA (C = 4, alpha straight), or None.
      Row 0 is the *top* row of the image as stored in the file.
    - ``vertex_normals``: (V, 3) float64 unit, area-weighted, outward.
    - ``corner_normals``: (F, 3, 3) float64 unit normals per face corner as the source file gives them (a
      glTF's NORMAL attribute: its hard edges kept, the shading the asset is drawn with), or None (the file
      has none; a mesh made with other faces). Face-aligned with ``faces``.
    - ``frame``: the transform back to the source frame.
    - ``degenerate``: (F,) bool, faces of (near) zero area, excluded from sampling.
    - ``uv_policy``: "wrap" (repeat) or "clamp" for UVs outside [0, 1].
    - ``watertight``: every edge shared by exactly two faces with consistent winding.
    - ``source``: the file it was read from ("" for generated meshes); messages name it.
    - ``warnings``: the one-line warnings issued on load, kept for reports.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    texture: np.ndarray | None = None
    vertex_normals: np.ndarray | None = None
    corner_normals: np.ndarray | None = None
    frame: Frame = field(default_factory=Frame)
    degenerate: np.ndarray | None = None
    uv_policy: str = "wrap"
    watertight: bool = True
    source: str = ""
    warnings: list[str] = field(default_factory=list)

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float64 corner positions, unit frame."""
        return self.vertices[self.faces]

    @property
    def face_areas(self) -> np.ndarray:
        """(F,) float64 areas, unit frame."""
        t = self.triangles
        return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)

    @property
    def face_normals(self) -> np.ndarray:
        """(F, 3) float64 unit outward normals; zero rows for degenerate faces."""
        t = self.triangles
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)

    @property
    def name(self) -> str:
        """What messages call this mesh: its file, or "<generated mesh>"."""
        return self.source or "<generated mesh>"
