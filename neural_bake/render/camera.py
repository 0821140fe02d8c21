"""Pinhole camera: one ray per pixel centre, image row 0 at the top, coordinates in the source frame.

A :class:`Camera` is plain data (position, look-at, up, vertical field of view, resolution). ``rays``
returns unit directions in the camera's frame of reference (the source mesh's frame); ``in_unit_frame``
moves the camera into a model's unit frame (a similarity: directions unchanged, distances scaled), which is
what the neural renderer traces in. The neural preview and the mesh turntables share this camera, so their
pictures of one view compare pixel by pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from ..constants import CAMERA_PARALLEL_EPS, MIN_SPAN
from ..errors import NeuralBakeError
from ..limits import check_image_size
from ..types import Frame
from .checks import finite_numbers

__all__ = ["Camera", "CameraError"]


class CameraError(NeuralBakeError):
    """A camera that cannot form an image (coincident eye and target, up along the view, bad size or fov)."""


def _vec3(name: str, value) -> tuple[float, float, float]:
    return finite_numbers(f"camera {name}", value, 3, CameraError)  # type: ignore[return-value]


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    - ``position``, ``look_at``: eye and target, source frame (the mesh's own units).
    - ``up``: the world direction that appears up in the image (default +Y); it need not be orthogonal
      to the view direction, only not parallel to it.
    - ``fov_deg``: vertical field of view in degrees, in (0, 180).
    - ``width``, ``height``: image size in pixels (1 to ``MAX_IMAGE_SIDE`` each, at most ``MAX_IMAGE_PIXELS``
      in all, :mod:`neural_bake.constants`). Pixels are square; the horizontal field of view
      follows from the aspect ratio.
    """

    position: tuple[float, float, float] = (0.0, 0.0, 3.0)
    """Eye position, source frame."""
    look_at: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """The point the camera looks at, source frame."""
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    """World up (+Y by default)."""
    fov_deg: float = 40.0
    """Vertical field of view, degrees."""
    width: int = 256
    """Image width, pixels."""
    height: int = 256
    """Image height, pixels."""

    def __post_init__(self):
        object.__setattr__(self, "position", _vec3("position", self.position))
        object.__setattr__(self, "look_at", _vec3("look_at", self.look_at))
        object.__setattr__(self, "up", _vec3("up", self.up))
        try:
            fov = float(self.fov_deg)
        except (TypeError, ValueError):
            raise CameraError(f"camera fov_deg: expected a number of degrees, got {self.fov_deg!r}") from None
        if not (0.0 < fov < 180.0):
            raise CameraError(f"camera fov_deg: must lie in (0, 180) degrees, got {self.fov_deg!r}")
        object.__setattr__(self, "fov_deg", fov)
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise CameraError(f"camera {name}: expected a whole number of pixels ≥ 1, got {value!r}")
            object.__setattr__(self, name, int(value))
        check_image_size(self.width, self.height, "camera", error=CameraError)
        self.basis()  # refuse a camera without a basis now, not at render time

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) float64 unit vectors, right-handed: right × up = −forward (OpenGL's camera
        looks down its −Z axis)."""
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (self.position, self.look_at, self.up))
        forward = target - eye
        dist = np.linalg.norm(forward)
        if dist <= 0:
            raise CameraError(f"camera: position and look_at coincide at {self.position}")
        forward = forward / dist
        up_norm = np.linalg.norm(up)
        if up_norm <= 0:
            raise CameraError("camera up: the zero vector has no direction")
        right = np.cross(forward, up / up_norm)
        if np.linalg.norm(right) <= CAMERA_PARALLEL_EPS:
            raise CameraError(f"camera up {self.up}: parallel to the view direction; choose another up")
        right /= np.linalg.norm(right)
        true_up = np.cross(right, forward)
        return right, true_up, forward

    @property
    def aspect(self) -> float:
        """Width over height."""
        return self.width / self.height

    def pixel_directions(self) -> np.ndarray:
        """(height, width, 3) float64 unit ray directions through the pixel centres; row 0 is the top row."""
        right, up, forward = self.basis()
        half_h = math.tan(math.radians(self.fov_deg) / 2)
        half_w = half_h * self.aspect
        # pixel centres in normalised device coordinates: x from -1 (left) to 1, y from 1 (top) to -1
        xs = ((np.arange(self.width) + 0.5) / self.width * 2 - 1) * half_w
        ys = (1 - (np.arange(self.height) + 0.5) / self.height * 2) * half_h
        d = forward + xs[None, :, None] * right + ys[:, None, None] * up
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def rays(self, *, device=None, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
        """Origins and unit directions, each (height·width, 3) in row-major pixel order, source frame."""
        d = torch.as_tensor(self.pixel_directions().reshape(-1, 3), dtype=dtype, device=device)
        o = torch.as_tensor(self.position, dtype=dtype, device=device).expand_as(d).contiguous()
        return o, d

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Source-frame points (N, 3) → continuous pixel coordinates (N, 2) as (column, row) with pixel
        centres at +0.5, and view depth along the forward axis (N,) (≤ 0 behind the camera)."""
        right, up, forward = self.basis()
        rel = np.asarray(points, dtype=np.float64) - np.asarray(self.position)
        z = rel @ forward
        half_h = math.tan(math.radians(self.fov_deg) / 2)
        half_w = half_h * self.aspect
        with np.errstate(divide="ignore", invalid="ignore"):
            x = (rel @ right) / z / half_w
            y = (rel @ up) / z / half_h
        col = (x + 1) / 2 * self.width
        row = (1 - y) / 2 * self.height
        return np.stack([col, row], axis=-1), z

    def in_unit_frame(self, frame: Frame) -> "Camera":
        """The same view in a model's unit frame (positions mapped by ``frame``; fov and size unchanged)."""
        pos, target = frame.to_unit(np.array([self.position, self.look_at]))
        return replace(self, position=tuple(pos), look_at=tuple(target))

    def orbit(self, degrees: float) -> "Camera":
        """This camera turned by ``degrees`` about the ``up`` axis through ``look_at`` (turntables)."""
        axis = np.asarray(self.up, dtype=np.float64)
        axis = axis / np.linalg.norm(axis)
        a = math.radians(float(degrees))
        rel = np.asarray(self.position) - np.asarray(self.look_at)
        # Rodrigues' rotation of the eye about the axis
        rot = rel * math.cos(a) + np.cross(axis, rel) * math.sin(a) + axis * (axis @ rel) * (1 - math.cos(a))
        return replace(self, position=tuple(np.asarray(self.look_at) + rot))

    @classmethod
    def framing(
        cls,
        lo,
        hi,
        *,
        direction=(0.0, 0.0, 1.0),
        up=(0.0, 1.0, 0.0),
        fov_deg: float = 40.0,
        width: int = 256,
        height: int = 256,
        margin: float = 1.1,
    ) -> "Camera":
        """A camera looking at the centre of the box [lo, hi] (source frame) from ``direction`` (from the
        target towards the eye), far enough that the box's bounding sphere, grown by ``margin``, fits the
        narrower field of view."""
        lo, hi = _vec3("framing lo", lo), _vec3("framing hi", hi)
        lo_a, hi_a = np.asarray(lo), np.asarray(hi)
        if np.any(hi_a < lo_a):
            raise CameraError(f"camera framing: box lower corner {lo} above its upper corner {hi}")
        center = (lo_a + hi_a) / 2
        radius = max(float(np.linalg.norm(hi_a - lo_a)) / 2, MIN_SPAN) * float(margin)
        d = np.asarray(_vec3("framing direction", direction))
        if np.linalg.norm(d) <= 0:
            raise CameraError("camera framing direction: the zero vector has no direction")
        d = d / np.linalg.norm(d)
        half_v = math.radians(float(fov_deg)) / 2
        half_h = math.atan(math.tan(half_v) * width / height)
        dist = radius / math.sin(min(half_v, half_h))
        return cls(tuple(center + d * dist), tuple(center), up, fov_deg, width, height)

    def to_dict(self) -> dict:
        return {
            "position": list(self.position), "look_at": list(self.look_at), "up": list(self.up),
            "fov_deg": self.fov_deg, "width": self.width, "height": self.height,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        known = {"position", "look_at", "up", "fov_deg", "width", "height"}
        unknown = sorted(set(d) - known)
        if unknown:
            raise CameraError(f"camera: unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})")
        return cls(**d)
