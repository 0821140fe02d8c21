"""Animated samples: shapes that change over t ∈ [0, 1], with analytic ground truth at every t.

Each animation has a ``name``, default frame ``times``, ``mesh(t, resolution=None)`` returning a
:class:`FrameMesh` (geometry only: the dynamic fits use no texture) and analytic functions of points and a
time, in the animation's own frame (the coordinates written to its OBJ frames):

- ``sdf(points, t)``: signed distance, negative inside (``sdf_kind`` says "exact outside" or "first-order");
- ``normal(points, t)``: outward unit normal of the smooth surface at (or near) the points;
- ``splitting_sphere`` also has ``albedo(points, t)``: linear RGB carried with each ball (per-frame colours).

Points are (N, 3) float arrays, ``t`` a float; results float64: (N,) for ``sdf``, (N, 3) for ``normal``.

Animations: ``travelling_bumps`` (the bumpy sphere's bumps move over it: the phase of one factor advances
by half a period, so bumps at t = 0 are dents at t = 1), ``twisting_torus`` (the torus twisted about the x
axis by an angle growing with x and t), ``splitting_sphere`` (one sphere that splits into two: a topology
change; its frames have different vertex counts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .shapes import BumpySphere, Torus, _faces_for, _points, _smooth_colour, _unit

__all__ = ["FrameMesh", "TravellingBumps", "TwistingTorus", "SplittingSphere", "ANIMATED", "get_animation"]

#: Frame times written by default (five frames over [0, 1]).
DEFAULT_TIMES = (0.0, 0.25, 0.5, 0.75, 1.0)


class FrameMesh(NamedTuple):
    """One frame of an animation, in the animation's own frame."""

    vertices: np.ndarray
    """(V, 3) float64 positions."""
    faces: np.ndarray
    """(F, 3) int64, counter-clockwise seen from outside."""


def _time(t) -> float:
    t = float(t)
    if not math.isfinite(t):
        raise ValueError(f"t must be a finite number, got {t!r}")
    return t


# ------------------------------------------------------------------------------------------ travelling bumps


@dataclass(frozen=True)
class TravellingBumps:
    """The bumpy sphere with h(d, t) = sin(k d_x + π c t) sin(k d_y) sin(k d_z): the bumps travel along x over
    the sphere (``cycles`` c = 0.5: half a period by t = 1, where bumps became dents).

    At each t the shape is a :class:`~neural_bake.samples.shapes.BumpySphere` (:meth:`at`): the same
    first-order SDF and exact normals; its frames are lat-long meshes with the same vertex count.
    """

    name: str = "travelling_bumps"
    cycles: float = 0.5
    """Periods of the moving factor travelled over t ∈ [0, 1]."""
    base: BumpySphere = field(default_factory=BumpySphere)
    times: tuple[float, ...] = DEFAULT_TIMES
    faces: int = 16384
    sdf_kind: str = "first-order"

    def at(self, t) -> BumpySphere:
        """The static bumpy sphere of time ``t``."""
        phi = 2.0 * math.pi * self.cycles * _time(t)
        return BumpySphere(radius=self.base.radius, amplitude=self.base.amplitude, frequency=self.base.frequency,
                           phase=(phi, 0.0, 0.0))

    def mesh(self, t, resolution: int | None = None) -> FrameMesh:
        m = self.at(t).mesh(_faces_for(resolution, self.faces), 8)
        return FrameMesh(m.vertices, m.faces)

    def sdf(self, points, t) -> np.ndarray:
        return self.at(t).sdf(points)

    def normal(self, points, t) -> np.ndarray:
        return self.at(t).normal(points)


# ------------------------------------------------------------------------------------------- twisting torus


@dataclass(frozen=True)
class TwistingTorus:
    """The torus twisted about the x axis: T_t(q) = R_x(τ t q_x) q (a rotation of the (y, z) plane by an
    angle growing linearly with x), τ = ``twist`` radians per unit length at t = 1.

    T_t keeps x, so its inverse is R_x(-τ t p_x). With g the torus's exact SDF and F(p) = g(T_t⁻¹ p),
    ``sdf`` is F / |∇F| (first order: exact sign, accurate near the surface; T_t is not an isometry) and
    ``normal`` ∇F / |∇F| with ∇F = Jᵀ ∇g(q), J the Jacobian of T_t⁻¹. Frames are the torus mesh mapped by
    T_t (same vertices, same faces).
    """

    name: str = "twisting_torus"
    twist: float = 2.0
    """τ: twist rate (radians per unit of x) at t = 1."""
    base: Torus = field(default_factory=Torus)
    times: tuple[float, ...] = DEFAULT_TIMES
    faces: int = 8192
    sdf_kind: str = "first-order"

    def _rotate(self, p: np.ndarray, angle: np.ndarray) -> np.ndarray:
        c, s = np.cos(angle), np.sin(angle)
        return np.stack([p[:, 0], c * p[:, 1] - s * p[:, 2], s * p[:, 1] + c * p[:, 2]], 1)

    def mesh(self, t, resolution: int | None = None) -> FrameMesh:
        m = self.base.mesh(_faces_for(resolution, self.faces), 8)
        v = np.asarray(m.vertices, dtype=np.float64)
        return FrameMesh(self._rotate(v, self.twist * _time(t) * v[:, 0]), m.faces)

    def _grad(self, points, t) -> tuple[np.ndarray, np.ndarray]:
        """F(p) and ∇F(p) (see the class docstring)."""
        p = _points(points)
        tau = self.twist * _time(t)
        q = self._rotate(p, -tau * p[:, 0])
        g = self.base.normal(q)  # ∇ of the exact torus SDF (unit; zero on the core circle)
        a = tau * p[:, 0]
        c, s = np.cos(a), np.sin(a)
        # q_y = c p_y + s p_z, q_z = -s p_y + c p_z: ∂q/∂p_x = (1, τ q_z, -τ q_y)
        grad = np.stack([g[:, 0] + tau * (q[:, 2] * g[:, 1] - q[:, 1] * g[:, 2]),
                         c * g[:, 1] - s * g[:, 2],
                         s * g[:, 1] + c * g[:, 2]], 1)
        return self.base.sdf(q), grad

    def sdf(self, points, t) -> np.ndarray:
        """F / |∇F|: first-order signed distance (exact sign)."""
        f, grad = self._grad(points, t)
        return f / np.maximum(np.linalg.norm(grad, axis=1), 1e-12)

    def normal(self, points, t) -> np.ndarray:
        """∇F / |∇F| (zero on the twisted core circle)."""
        return _unit(self._grad(points, t)[1])


# ------------------------------------------------------------------------------------------ splitting sphere


@dataclass(frozen=True)
class SplittingSphere:
    """One sphere that splits into two: the union of two balls of radius r(t) centred at ±c(t)·x̂, with r and
    c linear in t (r: ``r0`` → ``r1``, c: 0 → ``c1``). At t = 0 the balls coincide (one sphere); they part when
    c(t) > r(t) (t > 6/7 with the defaults), so the last frame has two components.

    The SDF of a union is the minimum of the balls' exact SDFs: exact outside, a bound inside (``sdf_kind``
    "exact outside"); ``normal`` is the nearer ball's radial direction (exact except on the crease where the
    balls meet). Frames come from marching cubes of the SDF with vertices projected onto the surface, so
    their vertex counts differ from frame to frame.
    """

    name: str = "splitting_sphere"
    r0: float = 0.6
    r1: float = 0.4
    c1: float = 0.5
    times: tuple[float, ...] = DEFAULT_TIMES
    faces: int = 8000
    sdf_kind: str = "exact outside"

    def centres_radius(self, t) -> tuple[np.ndarray, float]:
        """The two ball centres (2, 3) and their radius at time ``t``."""
        t = _time(t)
        c = self.c1 * t
        return np.array([[c, 0.0, 0.0], [-c, 0.0, 0.0]]), self.r0 + (self.r1 - self.r0) * t

    def _parts(self, points, t):
        p = _points(points)
        centres, r = self.centres_radius(t)
        rel = p[:, None, :] - centres[None]
        return np.linalg.norm(rel, axis=-1) - r, rel

    def sdf(self, points, t) -> np.ndarray:
        return self._parts(points, t)[0].min(1)

    def normal(self, points, t) -> np.ndarray:
        d, rel = self._parts(points, t)
        return _unit(rel[np.arange(len(d)), d.argmin(1)])

    def albedo(self, points, t) -> np.ndarray:
        """Linear RGB (N, 3) painted on each ball and carried with it: the colour of the direction from the
        nearer ball's centre (a space-time colour field g(x, t) with analytic truth)."""
        d, rel = self._parts(points, t)
        return _smooth_colour(_unit(rel[np.arange(len(d)), d.argmin(1)]))

    def mesh(self, t, resolution: int | None = None) -> FrameMesh:
        from skimage.measure import marching_cubes

        target = _faces_for(resolution, self.faces)
        centres, r = self.centres_radius(t)
        n = max(12, int(round(96 * math.sqrt(target / 8000))))
        ext = float(np.abs(centres[:, 0]).max() + r + 0.05)
        xs = np.linspace(-ext, ext, n)
        grid = np.stack(np.meshgrid(xs, xs, xs, indexing="ij"), -1).reshape(-1, 3)
        vol = self.sdf(grid, t).reshape(n, n, n)
        verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(xs[1] - xs[0],) * 3)
        verts = verts.astype(np.float64) - ext
        faces = faces.astype(np.int64)
        for _ in range(3):  # exact outside: a step along the normal lands on the surface
            verts = verts - self.sdf(verts, t)[:, None] * self.normal(verts, t)
        tri = verts[faces]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        if (fn * self.normal(tri.mean(1), t)).sum() < 0:
            faces = faces[:, ::-1].copy()
        tri = verts[faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        return FrameMesh(verts, faces[area > 1e-10])


#: The animations by name, in the order ``generate`` writes them.
ANIMATED = {s.name: s for s in (TravellingBumps(), TwistingTorus(), SplittingSphere())}


def get_animation(name: str):
    """The animation called ``name``; :class:`~neural_bake.errors.NeuralBakeError` naming the known ones."""
    from neural_bake.errors import NeuralBakeError

    try:
        return ANIMATED[name]
    except KeyError:
        raise NeuralBakeError(f"unknown animation {name!r} (known: {', '.join(ANIMATED)})") from None
