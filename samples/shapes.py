"""Small UV-textured shapes with analytic ground truth.

Every sample is a small dataclass with a ``name``, ``mesh(resolution=None, texture_size=None)`` returning a
:class:`SampleMesh` (vertices, faces, per-corner uv, linear texture) and analytic functions in the sample's
own frame — the coordinates written to its OBJ file (the *source* frame of the loaded mesh):

- ``sdf(points)``: signed distance, negative inside (``sdf_kind`` says "exact", "exact outside" or
  "first-order"),
- ``normal(points)``: outward unit normal of the smooth surface at (or near: see each class) the points,
- ``albedo(points)``: the procedural linear-RGB colour the texture was painted from, and ``albedo_uv(uv)``
  where the colour is a function of the texture coordinates.

Points are (N, 3) float arrays, results float64: (N,) for ``sdf``, (N, 3) for ``normal`` and ``albedo``.
To compare with a mesh loaded in the unit frame, map its points back with ``mesh.frame.to_source(p)`` and
unit-frame distances with ``d / mesh.frame.scale``.

Shapes: ``sphere`` (smooth colour field), ``torus`` (genus 1, checker texture), ``bumpy_sphere`` (radial
sinusoidal bumps a coarse mesh cannot hold: the baking case), ``jack`` (a ball with six thin spikes: thin,
non-convex parts, a hard fitting case), ``dots`` (the torus with a flat-colour texture of small sharp discs:
the hard texture case, with analytic edges).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["SampleMesh", "Sphere", "Torus", "BumpySphere", "Jack", "Dots", "SAMPLES", "get_sample"]


class SampleMesh(NamedTuple):
    """A generated mesh, in the sample's own frame."""

    vertices: np.ndarray
    """(V, 3) float64 positions."""
    faces: np.ndarray
    """(F, 3) int64, counter-clockwise seen from outside."""
    uv: np.ndarray
    """(F, 3, 2) float64 per-corner texture coordinates, v = 0 at the image's bottom row."""
    texture: np.ndarray
    """(H, W, 3) float32 linear RGB, row 0 the image's top row."""


def _points(points) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got shape {p.shape}")
    return p


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` normalised; zero rows stay zero (never NaN)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 1e-300)


def _texel_uv(width: int, height: int) -> np.ndarray:
    """(H, W, 2) uv of the texel centres, row 0 = top (v near 1)."""
    u = (np.arange(width) + 0.5) / width
    v = 1.0 - (np.arange(height) + 0.5) / height
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu, vv], axis=-1)


def _v_of_theta(theta, height: int):
    """Lat-long v of the polar angle θ for a texture ``height`` rows high: the poles sit on the centres of
    the top and bottom rows (v = 1 - 0.5/H and 0.5/H), so bilinear lookups never wrap across the poles."""
    return (0.5 + (1.0 - np.asarray(theta) / math.pi) * (height - 1)) / height


def _latlong_dirs(uv: np.ndarray, height: int) -> np.ndarray:
    """Directions (…, 3) of lat-long texture coordinates: φ = 2π u around +z, θ from v (:func:`_v_of_theta`)."""
    phi = 2 * math.pi * uv[..., 0]
    theta = np.clip(math.pi * (1.0 - (uv[..., 1] * height - 0.5) / (height - 1)), 0.0, math.pi)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


def _latlong_mesh(nlat: int, nlon: int, radius_fn, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A UV sphere (poles on ±z) with vertex radius ``radius_fn(dirs)``; lat-long per-corner uv for a
    texture ``height`` rows high (u = φ / 2π, v = :func:`_v_of_theta`)."""
    i = np.arange(1, nlat)
    j = np.arange(nlon)
    theta = math.pi * i / nlat
    phi = 2 * math.pi * j / nlon
    tt, pp = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], axis=-1).reshape(-1, 3)
    dirs = np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]])
    verts = dirs * radius_fn(dirs)[:, None]
    north, south = 0, len(dirs) - 1

    def vid(ii, jj):  # ring ii in 1..nlat-1, column jj (wrapped)
        return 1 + (ii - 1) * nlon + (jj % nlon)

    def uvc(ii, jj):
        jj = np.asarray(jj, dtype=np.float64)
        return np.stack([jj / nlon, np.broadcast_to(_v_of_theta(math.pi * ii / nlat, height), jj.shape)], axis=-1)

    faces, uvs = [], []
    jj = np.arange(nlon)
    # north cap: (N, (1, j), (1, j+1))
    faces.append(np.stack([np.full(nlon, north), vid(1, jj), vid(1, jj + 1)], axis=1))
    uvs.append(np.stack([np.stack([(jj + 0.5) / nlon, np.full(nlon, _v_of_theta(0.0, height))], -1), uvc(1, jj), uvc(1, jj + 1)], axis=1))
    for ii in range(1, nlat - 1):
        a, b, c, d = vid(ii, jj), vid(ii + 1, jj), vid(ii + 1, jj + 1), vid(ii, jj + 1)
        ua, ub, uc, ud = uvc(ii, jj), uvc(ii + 1, jj), uvc(ii + 1, jj + 1), uvc(ii, jj + 1)
        faces += [np.stack([a, b, c], 1), np.stack([a, c, d], 1)]
        uvs += [np.stack([ua, ub, uc], 1), np.stack([ua, uc, ud], 1)]
    # south cap: ((n-1, j), S, (n-1, j+1))
    ii = nlat - 1
    faces.append(np.stack([vid(ii, jj), np.full(nlon, south), vid(ii, jj + 1)], axis=1))
    uvs.append(np.stack([uvc(ii, jj), np.stack([(jj + 0.5) / nlon, np.full(nlon, _v_of_theta(math.pi, height))], -1), uvc(ii, jj + 1)], axis=1))
    return verts, np.concatenate(faces).astype(np.int64), np.concatenate(uvs).astype(np.float64)


def _smooth_colour(d: np.ndarray) -> np.ndarray:
    """A smooth, low-frequency linear-RGB field of unit directions (N, 3), values in [0.1, 0.8]."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    r = 0.45 + 0.35 * np.sin(3.0 * x + 1.0 * z)
    g = 0.45 + 0.35 * np.sin(3.0 * y - 2.0 * z + 0.5)
    b = 0.45 + 0.35 * np.cos(2.0 * z + 2.0 * x)
    return np.stack([r, g, b], axis=-1)


def _faces_for(resolution: int | None, default: int) -> int:
    r = default if resolution is None else int(resolution)
    if r < 32:
        raise ValueError(f"resolution must be an approximate face count >= 32, got {resolution!r}")
    return r


# -------------------------------------------------------------------------------------------------- sphere


@dataclass(frozen=True)
class Sphere:
    """A UV sphere of radius ``radius`` at the origin with a smooth lat-long colour texture.

    Exact SDF |p| - r and normal p/|p|; colour ``albedo(p)`` a smooth function of the direction, painted
    into the lat-long texture at the texel centres (bandlimited: a 30 dB PSNR target is reachable).
    """

    name: str = "sphere"
    radius: float = 0.9
    """Radius (the mesh's vertices lie on the sphere; flat faces lie inside it)."""
    faces: int = 8192
    """Default approximate face count (``4 nlat²``, nlon = 2 nlat)."""
    texture_size: int = 512
    """Default texture width (height is half of it)."""
    sdf_kind: str = "exact"

    def mesh(self, resolution: int | None = None, texture_size: int | None = None) -> SampleMesh:
        nlat = max(3, round(math.sqrt(_faces_for(resolution, self.faces) / 4)))
        w = int(texture_size or self.texture_size)
        v, f, uv = _latlong_mesh(nlat, 2 * nlat, lambda d: np.full(len(d), self.radius), w // 2)
        tex = self.albedo_uv(_texel_uv(w, w // 2).reshape(-1, 2), w).reshape(w // 2, w, 3)
        return SampleMesh(v, f, uv, tex.astype(np.float32))

    def sdf(self, points) -> np.ndarray:
        return np.linalg.norm(_points(points), axis=1) - self.radius

    def normal(self, points) -> np.ndarray:
        """p / |p| (zero at the centre)."""
        return _unit(_points(points))

    def albedo(self, points) -> np.ndarray:
        """Colour of the direction of ``points`` (any distance from the centre)."""
        return _smooth_colour(_unit(_points(points)))

    def albedo_uv(self, uv, texture_size: int | None = None) -> np.ndarray:
        """Colour at the lat-long texture coordinates (N, 2) of a mesh made with ``texture_size``.

        u = φ / 2π; v maps the poles to the centres of the top and bottom texel rows (so it depends on
        the texture's height, ``texture_size // 2``)."""
        h = int(texture_size or self.texture_size) // 2
        return _smooth_colour(_latlong_dirs(np.asarray(uv, dtype=np.float64), h))


# -------------------------------------------------------------------------------------------------- bumpy


@dataclass(frozen=True)
class BumpySphere:
    """A sphere displaced radially by smooth bumps: r(d) = R + a·h(d), h(d) = Π_j sin(k d_j + φ_j) (φ = 0 by default).

    h is a smooth function of the unit direction d (no pole singularities); a·k·|∇h| < R keeps the surface
    star-shaped, smooth and without overhangs. The implicit function is F(p) = |p| - r(p/|p|), with
    ∇F = d - (a/|p|)(I - d dᵀ)∇h(d). ``normal`` is exact (∇F/|∇F| at the surface point in the direction of
    p); ``sdf`` is F/|∇F|, a *first-order* approximation of the signed distance (exact sign, error
    O(F²·curvature) — small within a bump height of the surface, not a distance bound far away).
    The bumps (wavelength 2π/k ≈ 0.63 rad) are held by the default ~16k-face mesh (13 vertices per
    wavelength), not by a ~2k-face one (4).
    """

    name: str = "bumpy_sphere"
    radius: float = 0.8
    """Base radius R."""
    amplitude: float = 0.035
    """Bump amplitude a."""
    frequency: float = 10.0
    """Angular frequency k of the bumps."""
    phase: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Phases φ of the three factors, h(d) = Π_j sin(k d_j + φ_j): a changing phase moves the bumps over the
    sphere (the ``travelling_bumps`` animation)."""
    faces: int = 16384
    texture_size: int = 512
    sdf_kind: str = "first-order"

    def _h(self, d):
        k = self.frequency
        s = np.sin(k * d + np.asarray(self.phase))
        c = np.cos(k * d + np.asarray(self.phase))
        h = s[:, 0] * s[:, 1] * s[:, 2]
        grad = k * np.stack([c[:, 0] * s[:, 1] * s[:, 2], s[:, 0] * c[:, 1] * s[:, 2], s[:, 0] * s[:, 1] * c[:, 2]], 1)
        return h, grad

    def surface_radius(self, dirs) -> np.ndarray:
        """r(d) for unit directions (N, 3)."""
        return self.radius + self.amplitude * self._h(np.asarray(dirs, dtype=np.float64))[0]

    def mesh(self, resolution: int | None = None, texture_size: int | None = None) -> SampleMesh:
        nlat = max(3, round(math.sqrt(_faces_for(resolution, self.faces) / 4)))
        w = int(texture_size or self.texture_size)
        v, f, uv = _latlong_mesh(nlat, 2 * nlat, self.surface_radius, w // 2)
        tex = self.albedo_uv(_texel_uv(w, w // 2).reshape(-1, 2), w).reshape(w // 2, w, 3)
        return SampleMesh(v, f, uv, tex.astype(np.float32))

    def implicit(self, points) -> np.ndarray:
        """F(p) = |p| - r(p/|p|) (negative inside)."""
        p = _points(points)
        rho = np.linalg.norm(p, axis=1)
        return rho - self.surface_radius(_unit(p))

    def _grad(self, p: np.ndarray, rho: np.ndarray) -> np.ndarray:
        d = _unit(p)
        _, gh = self._h(d)
        tangential = gh - (gh * d).sum(1, keepdims=True) * d
        return d - self.amplitude * tangential / np.maximum(rho, 1e-12)[:, None]

    def sdf(self, points) -> np.ndarray:
        """F(p) / |∇F(p)|: first-order signed distance (exact sign)."""
        p = _points(points)
        rho = np.linalg.norm(p, axis=1)
        g = self._grad(p, rho)
        return (rho - self.surface_radius(_unit(p))) / np.linalg.norm(g, axis=1)

    def normal(self, points) -> np.ndarray:
        """Exact outward unit normal at the surface point r(d)·d, d = p/|p| (zero at the centre)."""
        p = _points(points)
        d = _unit(p)
        g = self._grad(d, self.surface_radius(d))
        return np.where((np.linalg.norm(p, axis=1) > 0)[:, None], _unit(g), 0.0)

    def albedo(self, points) -> np.ndarray:
        return _smooth_colour(_unit(_points(points)))

    def albedo_uv(self, uv, texture_size: int | None = None) -> np.ndarray:
        """As :meth:`Sphere.albedo_uv`."""
        h = int(texture_size or self.texture_size) // 2
        return _smooth_colour(_latlong_dirs(np.asarray(uv, dtype=np.float64), h))


# -------------------------------------------------------------------------------------------------- torus


@dataclass(frozen=True)
class Torus:
    """A torus around the z axis: tube radius ``minor`` at distance ``major`` from the axis, checker texture.

    uv = (φ / 2π, ψ / 2π), φ around z and ψ around the tube (ψ = 0 on the outer equator). Exact SDF
    |(|p_xy| - R, p_z)| - r; normal the unit vector from the tube's core circle to p (zero on the core).
    The checker (``checks`` × ``checks``/2 squares) has sharp edges: a hard texture to fit.
    """

    name: str = "torus"
    major: float = 0.65
    minor: float = 0.25
    checks: int = 12
    """Squares around the ring (half as many around the tube)."""
    faces: int = 8192
    texture_size: int = 512
    sdf_kind: str = "exact"
    colors: tuple = ((0.8, 0.35, 0.08), (0.06, 0.25, 0.6))

    def mesh(self, resolution: int | None = None, texture_size: int | None = None) -> SampleMesh:
        nv = max(3, round(math.sqrt(_faces_for(resolution, self.faces) / 4)))
        nu = 2 * nv
        i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
        phi, psi = 2 * math.pi * i / nu, 2 * math.pi * j / nv
        rr = self.major + self.minor * np.cos(psi)
        verts = np.stack([rr * np.cos(phi), rr * np.sin(phi), self.minor * np.sin(psi)], -1).reshape(-1, 3)
        i, j = i.ravel(), j.ravel()
        vid = lambda a, b: (a % nu) * nv + (b % nv)  # noqa: E731
        uvc = lambda a, b: np.stack([a / nu, b / nv], -1)  # noqa: E731
        a, b, c, d = vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)
        ua, ub, uc, ud = uvc(i, j), uvc(i + 1, j), uvc(i + 1, j + 1), uvc(i, j + 1)
        faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
        uv = np.concatenate([np.stack([ua, ub, uc], 1), np.stack([ua, uc, ud], 1)])
        w = int(texture_size or self.texture_size)
        tex = self.albedo_uv(_texel_uv(w, w // 2).reshape(-1, 2)).reshape(w // 2, w, 3)
        return SampleMesh(verts, faces, uv, tex.astype(np.float32))

    def _core(self, p):
        q = np.linalg.norm(p[:, :2], axis=1)
        ring = self.major * _unit(np.concatenate([p[:, :2], np.zeros((len(p), 1))], 1))
        return p - ring, q

    def sdf(self, points) -> np.ndarray:
        p = _points(points)
        q = np.linalg.norm(p[:, :2], axis=1)
        return np.hypot(q - self.major, p[:, 2]) - self.minor

    def normal(self, points) -> np.ndarray:
        p = _points(points)
        rel, _ = self._core(p)
        return _unit(rel)

    def uv_of(self, points) -> np.ndarray:
        """Texture coordinates (N, 2) of the surface point nearest to each point."""
        p = _points(points)
        rel, _ = self._core(p)
        phi = np.arctan2(p[:, 1], p[:, 0]) % (2 * math.pi)
        radial = (rel[:, :2] * _unit(p[:, :2])).sum(1)
        psi = np.arctan2(rel[:, 2], radial) % (2 * math.pi)
        return np.stack([phi, psi], 1) / (2 * math.pi)

    def albedo(self, points) -> np.ndarray:
        return self.albedo_uv(self.uv_of(points))

    def albedo_uv(self, uv, texture_size: int | None = None) -> np.ndarray:
        """Checker colour at texture coordinates (N, 2) (independent of the texture size)."""
        uv = np.asarray(uv, dtype=np.float64)
        iu = np.floor(uv[:, 0] * self.checks).astype(np.int64)
        iv = np.floor(uv[:, 1] * (self.checks // 2)).astype(np.int64)
        odd = ((iu + iv) % 2).astype(bool)
        return np.where(odd[:, None], np.asarray(self.colors[1]), np.asarray(self.colors[0]))


# -------------------------------------------------------------------------------------------------- dots


@dataclass(frozen=True)
class Dots(Torus):
    """The torus with a flat-colour texture of small sharp dots (discs) of a few sizes: the hard case of a
    colour network (a single SIREN blurs the dots and rings at their edges) and an analytic oracle of a bake's
    small features and their edges.

    Geometry, ``sdf``, ``normal`` and ``uv_of`` as :class:`Torus`; the texture is square (``texture_size``²).
    In texel coordinates of that default texture (x = u·T, y = (1 - v)·T, T = ``texture_size``, row 0 at the
    top), cell (row r, column k) of side ``spacing`` holds one disc centred in it, ``dot_texels[r % n]``
    texels across, of colour ``dot_colors[k % m]``; the rest is ``background``. The dots are fixed in uv: a
    texture of another size (``mesh(texture_size=…)``) scales them with it. Texels are painted at their
    centres without antialiasing, so every edge is sharp.
    """

    name: str = "dots"
    texture_size: int = 1024
    """Default texture side; ``dot_texels`` and ``spacing`` are in its texels."""
    dot_texels: tuple[float, ...] = (8.0, 12.0, 16.0, 24.0)
    """Disc diameters in texels, one per row of cells (cycled)."""
    spacing: int = 32
    """Side of a cell in texels (one disc per cell; only whole cells hold a disc)."""
    background: tuple[float, float, float] = (0.75, 0.62, 0.38)
    """Linear RGB of the flat background."""
    dot_colors: tuple = ((0.02, 0.02, 0.03), (0.7, 0.04, 0.03), (0.03, 0.12, 0.6), (0.9, 0.9, 0.85))
    """Linear RGB of the discs, one per column of cells (cycled)."""

    def mesh(self, resolution: int | None = None, texture_size: int | None = None) -> SampleMesh:
        m = Torus.mesh(self, resolution, 8)
        w = int(texture_size or self.texture_size)
        tex = self.albedo_uv(_texel_uv(w, w).reshape(-1, 2)).reshape(w, w, 3)
        return SampleMesh(m.vertices, m.faces, m.uv, tex.astype(np.float32))

    def cells(self) -> int:
        """Cells per side of the texture (each holds one disc)."""
        return int(self.texture_size) // int(self.spacing)

    def dots(self) -> list[dict]:
        """Every disc: ``{"row", "col", "centre": (x, y), "diameter", "color"}``, centre and diameter in
        texel units of the default texture (x to the right from the left edge, y down from the top edge)."""
        n, s = self.cells(), float(self.spacing)
        return [{"row": r, "col": k, "centre": ((k + 0.5) * s, (r + 0.5) * s),
                 "diameter": float(self.dot_texels[r % len(self.dot_texels)]),
                 "color": tuple(self.dot_colors[k % len(self.dot_colors)])} for r in range(n) for k in range(n)]

    def albedo_uv(self, uv, texture_size: int | None = None) -> np.ndarray:
        """Colour at texture coordinates (N, 2): the disc's inside a disc (its boundary excluded), else the
        background (independent of ``texture_size``: the dots are fixed in uv)."""
        uv = np.asarray(uv, dtype=np.float64)
        t, s, n = float(self.texture_size), float(self.spacing), self.cells()
        x, y = uv[:, 0] * t, (1.0 - uv[:, 1]) * t
        col, row = np.floor(x / s).astype(np.int64), np.floor(y / s).astype(np.int64)
        ok = (col >= 0) & (col < n) & (row >= 0) & (row < n)
        diam = np.asarray(self.dot_texels, dtype=np.float64)[np.where(ok, row, 0) % len(self.dot_texels)]
        dist = np.hypot(x - (col + 0.5) * s, y - (row + 0.5) * s)
        inside = ok & (dist < diam / 2.0)
        dot = np.asarray(self.dot_colors, dtype=np.float64)[np.where(ok, col, 0) % len(self.dot_colors)]
        return np.where(inside[:, None], dot, np.asarray(self.background, dtype=np.float64))


# -------------------------------------------------------------------------------------------------- jack


@dataclass(frozen=True)
class Jack:
    """A ball with six thin spikes along ±x, ±y, ±z: the union of a sphere and six capsules.

    The SDF of a union is the minimum of the parts' exact SDFs: exact outside, a bound inside
    (|sdf| ≤ true distance there). Normals are the gradient of the nearest part (exact except on the
    creases where a spike meets the ball, a set of measure zero). The mesh comes from marching cubes of
    the SDF with vertices projected onto the surface, UVs from xatlas, and a texture painted from
    ``albedo(p)`` (a smooth colour field of the position) by rasterising the UV charts.
    """

    name: str = "jack"
    ball: float = 0.32
    """Radius of the central ball."""
    spike_radius: float = 0.055
    """Radius of the spikes (thin: about 7 grid cells across at the default resolution)."""
    spike_length: float = 0.845
    """Distance from the centre to a spike's end-cap centre (extent = length + radius)."""
    faces: int = 11000
    texture_size: int = 512
    sdf_kind: str = "exact outside"

    def _parts(self, p):
        """(N, 7) distances to the ball and the six capsules, and the closest core points (N, 7, 3)."""
        n = len(p)
        cores = [np.zeros((n, 3))]
        for axis in range(3):
            for s in (1.0, -1.0):
                t = np.clip(s * p[:, axis], 0.0, self.spike_length)
                c = np.zeros((n, 3))
                c[:, axis] = s * t
                cores.append(c)
        cores = np.stack(cores, 1)
        radii = np.array([self.ball] + [self.spike_radius] * 6)
        d = np.linalg.norm(p[:, None, :] - cores, axis=-1) - radii
        return d, cores

    def sdf(self, points) -> np.ndarray:
        d, _ = self._parts(_points(points))
        return d.min(1)

    def normal(self, points) -> np.ndarray:
        p = _points(points)
        d, cores = self._parts(p)
        k = d.argmin(1)
        return _unit(p - cores[np.arange(len(p)), k])

    def albedo(self, points) -> np.ndarray:
        p = _points(points)
        r = 0.5 + 0.35 * np.sin(4.0 * p[:, 0] + 1.0)
        g = 0.5 + 0.35 * np.sin(4.0 * p[:, 1] + 2.0 * p[:, 2])
        b = 0.5 + 0.35 * np.cos(3.0 * p[:, 2] - p[:, 0])
        return np.stack([r, g, b], 1)

    def mesh(self, resolution: int | None = None, texture_size: int | None = None) -> SampleMesh:
        from skimage.measure import marching_cubes

        target = _faces_for(resolution, self.faces)
        n = max(16, int(round(128 * math.sqrt(target / 24000))))
        ext = self.spike_length + self.spike_radius + 0.05
        xs = np.linspace(-ext, ext, n)
        grid = np.stack(np.meshgrid(xs, xs, xs, indexing="ij"), -1).reshape(-1, 3)
        vol = self.sdf(grid).reshape(n, n, n)
        verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(xs[1] - xs[0],) * 3)
        verts = verts - ext
        faces = faces.astype(np.int64)
        for _ in range(3):  # project onto the surface (exact outside: one step lands on it)
            verts = verts - self.sdf(verts)[:, None] * self.normal(verts)
        tri = verts[faces]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        if (fn * self.normal(tri.mean(1))).sum() < 0:
            faces = faces[:, ::-1].copy()
        # drop faces that projection made degenerate
        tri = verts[faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        faces = faces[area > 1e-10]
        w = int(texture_size or self.texture_size)
        uv = _xatlas_uv(verts, faces, w)
        tex = _paint(verts, faces, uv, self.albedo, w, w)
        return SampleMesh(verts, faces, uv, tex)


def _xatlas_uv(verts: np.ndarray, faces: np.ndarray, size: int) -> np.ndarray:
    """Per-corner uv (F, 3, 2) of an xatlas parametrisation packed for a ``size``² texture with 4 texels of
    padding between charts (v = 0 at the bottom)."""
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(verts.astype(np.float32), faces.astype(np.uint32))
    pack = xatlas.PackOptions()
    pack.padding = 4
    pack.resolution = size
    pack.bilinear = True
    atlas.generate(pack_options=pack)
    vmapping, indices, uvs = atlas[0]
    # xatlas keeps the face order; its per-vertex uvs index through the new vertices
    uv = uvs.astype(np.float64)[indices.astype(np.int64)]
    return uv


def _paint(verts, faces, uv, colour_fn, width: int, height: int) -> np.ndarray:
    """Rasterise the UV charts: each covered texel gets ``colour_fn`` of its 3-D point; the rest is filled
    from the nearest covered texel (so bilinear lookups near chart borders do not bleed)."""
    from scipy import ndimage

    h, w = height, width
    tex = np.zeros((h, w, 3))
    covered = np.zeros((h, w), bool)
    px = uv[..., 0] * w - 0.5  # continuous texel coords, (0, 0) at the top-left texel centre
    py = (1.0 - uv[..., 1]) * h - 0.5
    tri = verts[faces]
    all_pts, all_idx = [], []
    for f in range(len(faces)):
        x, y = px[f], py[f]
        x0, x1 = max(0, int(np.floor(x.min()))), min(w - 1, int(np.ceil(x.max())))
        y0, y1 = max(0, int(np.floor(y.min()))), min(h - 1, int(np.ceil(y.max())))
        if x1 < x0 or y1 < y0:
            continue
        gx, gy = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
        gx, gy = gx.ravel(), gy.ravel()
        den = (y[1] - y[2]) * (x[0] - x[2]) + (x[2] - x[1]) * (y[0] - y[2])
        if abs(den) < 1e-14:
            continue
        l0 = ((y[1] - y[2]) * (gx - x[2]) + (x[2] - x[1]) * (gy - y[2])) / den
        l1 = ((y[2] - y[0]) * (gx - x[2]) + (x[0] - x[2]) * (gy - y[2])) / den
        l2 = 1.0 - l0 - l1
        inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        if not inside.any():
            continue
        lam = np.stack([l0, l1, l2], 1)[inside]
        all_pts.append(lam @ tri[f])
        all_idx.append(np.stack([gy[inside], gx[inside]], 1))
    if all_pts:
        pts, idx = np.concatenate(all_pts), np.concatenate(all_idx)
        tex[idx[:, 0], idx[:, 1]] = colour_fn(pts)
        covered[idx[:, 0], idx[:, 1]] = True
    if covered.any():
        _, (iy, ix) = ndimage.distance_transform_edt(~covered, return_indices=True)
        tex = tex[iy, ix]
    return tex.astype(np.float32)


#: The samples by name, in the order ``generate`` writes them.
SAMPLES = {s.name: s for s in (Sphere(), BumpySphere(), Torus(), Jack(), Dots())}


def get_sample(name: str):
    """The sample called ``name``; :class:`~neural_bake.errors.NeuralBakeError` naming the known ones otherwise."""
    from neural_bake.errors import NeuralBakeError

    try:
        return SAMPLES[name]
    except KeyError:
        raise NeuralBakeError(f"unknown sample {name!r} (known: {', '.join(SAMPLES)})") from None


def unit_frame_normals(sample, frame):
    """``sample``'s analytic unit normals as a function of unit-frame points (numpy (N, 3) → (N, 3)), for a
    mesh of it loaded with ``frame`` (the unit frame only scales and shifts, so directions are unchanged)."""
    return lambda p: sample.normal(frame.to_source(p))
