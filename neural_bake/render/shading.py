"""Lights, materials and shading, shared by the neural preview renderer and the mesh turntables.

Shading runs in the source frame on torch tensors (device and dtype follow ``normals``), in linear RGB;
images are sRGB-encoded only when written. Blinn-Phong: ``ambient·albedo·ao + Σ_l vis_l·radiance_l·
(albedo·max(n·l, 0) + specular·max(n·h, 0)^shininess·[n·l > 0])``; matcap: the colour of a sphere image
looked up by the view-space normal. Invalid (zero) normals shade as ambient only, never NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..constants import GRAD_EPS
from ..errors import NeuralBakeError
from .checks import finite_numbers

__all__ = [
    "DirectionalLight", "PointLight", "Material", "ShadingError", "default_lights", "light_samples",
    "shade_blinn_phong", "shade_matcap", "builtin_matcap", "MATERIAL_KINDS",
]


class ShadingError(NeuralBakeError):
    """A light or material that cannot shade (non-finite values, unknown kind, zero direction)."""


def _finite_tuple(name: str, value, n: int) -> tuple[float, ...]:
    return finite_numbers(name, value, n, ShadingError)


def _non_negative(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ShadingError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0:
        raise ShadingError(f"{name}: expected a finite number ≥ 0, got {value!r}")
    return v


@dataclass(frozen=True)
class DirectionalLight:
    """Light from infinitely far away. ``direction`` is the way the light travels (from the light towards
    the scene), source frame; ``color`` linear RGB; ``intensity`` scales it."""

    direction: tuple[float, float, float] = (-0.4, -0.6, -0.7)
    """Travel direction of the light (need not be unit; not zero)."""
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Linear RGB."""
    intensity: float = 1.0
    """Radiance scale."""

    def __post_init__(self):
        d = _finite_tuple("directional light direction", self.direction, 3)
        if math.hypot(*d) <= 0:
            raise ShadingError("directional light direction: the zero vector has no direction")
        object.__setattr__(self, "direction", d)
        object.__setattr__(self, "color", _finite_tuple("light color", self.color, 3))
        object.__setattr__(self, "intensity", _non_negative("light intensity", self.intensity))


@dataclass(frozen=True)
class PointLight:
    """A point light at ``position`` (source frame). Radiance falls off as ``intensity / distance²``."""

    position: tuple[float, float, float] = (2.0, 3.0, 3.0)
    """Source frame."""
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Linear RGB."""
    intensity: float = 10.0
    """Radiance at distance 1."""

    def __post_init__(self):
        object.__setattr__(self, "position", _finite_tuple("point light position", self.position, 3))
        object.__setattr__(self, "color", _finite_tuple("light color", self.color, 3))
        object.__setattr__(self, "intensity", _non_negative("light intensity", self.intensity))


MATERIAL_KINDS = ("blinn-phong", "matcap")


@dataclass(frozen=True)
class Material:
    """Surface appearance. ``albedo`` is used where no texture field or map gives a colour."""

    kind: str = "blinn-phong"
    """"blinn-phong" or "matcap"."""
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)
    """Linear RGB base colour without a texture."""
    ambient: float = 0.15
    """Ambient term (times albedo, times ambient occlusion when computed)."""
    specular: float = 0.2
    """Specular strength (white highlights)."""
    shininess: float = 32.0
    """Blinn-Phong exponent."""
    matcap: str | None = None
    """Image file of a lit sphere for ``kind="matcap"`` (None: a built-in two-tone sphere)."""

    def __post_init__(self):
        if self.kind not in MATERIAL_KINDS:
            raise ShadingError(f"material kind {self.kind!r}: expected one of {', '.join(MATERIAL_KINDS)}")
        object.__setattr__(self, "albedo", _finite_tuple("material albedo", self.albedo, 3))
        for name in ("ambient", "specular", "shininess"):
            object.__setattr__(self, name, _non_negative(f"material {name}", getattr(self, name)))


def default_lights(camera) -> list[DirectionalLight]:
    """One key light from above, left and behind the camera, as a studio preview would place it."""
    right, up, forward = camera.basis()
    travel = forward - 0.6 * up + 0.5 * right  # from upper left behind the eye towards the scene
    return [DirectionalLight(direction=tuple(travel.tolist()))]


def light_samples(lights, points: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """Per light: unit direction towards it (N, 3), radiance (N, 3), distance to it (N,) (inf for a
    directional light) at ``points`` (N, 3), source frame. Shadow rays start at the points along the
    direction and stop at the distance."""
    out = []
    n, like = points.shape[0], points
    for light in lights:
        color = torch.as_tensor(light.color, dtype=like.dtype, device=like.device) * light.intensity
        if isinstance(light, DirectionalLight):
            d = -torch.as_tensor(light.direction, dtype=like.dtype, device=like.device)
            d = (d / d.norm()).expand(n, 3)
            out.append((d, color.expand(n, 3), torch.full((n,), math.inf, dtype=like.dtype, device=like.device)))
        elif isinstance(light, PointLight):
            rel = torch.as_tensor(light.position, dtype=like.dtype, device=like.device) - points
            dist = rel.norm(dim=-1).clamp_min(GRAD_EPS)
            out.append((rel / dist[:, None], color / (dist * dist)[:, None], dist))
        else:
            raise ShadingError(f"light: expected a DirectionalLight or PointLight, got {type(light).__name__}")
    return out


def _unit(v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    norm = v.norm(dim=-1, keepdim=True)
    valid = (norm > GRAD_EPS) & torch.isfinite(norm)
    return torch.where(valid, v / norm.clamp_min(GRAD_EPS), torch.zeros_like(v)), valid.squeeze(-1)


def shade_blinn_phong(
    normals: torch.Tensor,
    points: torch.Tensor,
    view_dirs: torch.Tensor,
    albedo: torch.Tensor,
    lights,
    material: Material,
    *,
    visibility: list[torch.Tensor] | None = None,
    ambient_occlusion: torch.Tensor | None = None,
) -> torch.Tensor:
    """Linear RGB (N, 3) of surface points.

    - ``normals``: (N, 3) outward normals (normalised here; zero rows shade as ambient only).
    - ``points``: (N, 3) source-frame positions; ``view_dirs``: (N, 3) directions of the camera rays
      (from the eye towards the point).
    - ``albedo``: (N, 3) linear RGB; ``lights``: directional and point lights.
    - ``visibility``: per light an (N,) factor in [0, 1] (1 lit, 0 in shadow), or None (no shadows).
    - ``ambient_occlusion``: (N,) factor in [0, 1] on the ambient term, or None.
    """
    n, valid = _unit(normals)
    v, _ = _unit(-view_dirs)
    ambient = material.ambient
    if ambient_occlusion is not None:
        rgb = albedo * (ambient * ambient_occlusion)[:, None]
    else:
        rgb = albedo * ambient
    for k, (l_dir, radiance, _) in enumerate(light_samples(lights, points)):
        ndotl = (n * l_dir).sum(-1)
        lit = ndotl > 0
        h, _ = _unit(l_dir + v)
        spec = (n * h).sum(-1).clamp_min(0) ** material.shininess * lit
        term = radiance * (albedo * ndotl.clamp_min(0)[:, None] + material.specular * spec[:, None])
        if visibility is not None:
            term = term * visibility[k][:, None]
        rgb = rgb + term
    return torch.where(valid[:, None], rgb, albedo * ambient)


def builtin_matcap(size: int = 128) -> np.ndarray:
    """(size, size, 3) float32 linear RGB of a clay sphere lit from the upper left (row 0 at the top)."""
    y, x = np.mgrid[0:size, 0:size]
    u = (x + 0.5) / size * 2 - 1
    v = 1 - (y + 0.5) / size * 2
    z = np.sqrt(np.clip(1 - u * u - v * v, 0, None))
    light = np.array([-0.45, 0.55, 0.7])
    light /= np.linalg.norm(light)
    diffuse = np.clip(u * light[0] + v * light[1] + z * light[2], 0, None)
    base = np.array([0.60, 0.50, 0.42])
    img = 0.08 + base * diffuse[..., None] + 0.25 * diffuse[..., None] ** 24
    return img.astype(np.float32)


def shade_matcap(normals: torch.Tensor, camera, image: np.ndarray | None = None) -> torch.Tensor:
    """Linear RGB (N, 3): the matcap ``image`` (H, W, 3, row 0 at the top; default :func:`builtin_matcap`)
    looked up at the view-space normal (x right, y up) of ``camera``. Zero normals read the centre."""
    img = builtin_matcap() if image is None else np.asarray(image, dtype=np.float32)[..., :3]
    right, up, _ = camera.basis()
    n, _ = _unit(normals)
    r = torch.as_tensor(right, dtype=n.dtype, device=n.device)
    u = torch.as_tensor(up, dtype=n.dtype, device=n.device)
    x, y = n @ r, n @ u
    h, w = img.shape[:2]
    col = ((x * 0.5 + 0.5) * (w - 1)).round().long().clamp(0, w - 1)
    row = ((0.5 - y * 0.5) * (h - 1)).round().long().clamp(0, h - 1)
    table = torch.as_tensor(img, dtype=n.dtype, device=n.device)
    return table[row, col]

