"""Training data: points on and around a mesh, with normals, UVs, colours and signed distances.

Everything here works in the mesh's *unit frame* (``Mesh.vertices``; docs/design.md, "Frame"). Randomness comes
from ``numpy.random.default_rng(seed)``, so a seed gives identical arrays on every run.

- :func:`sample_surface` — area-uniform points on the surface faces (:func:`surface_faces`), with the outward
  normal, the interpolated UV and the bilinear texture colour (linear RGB) at each point.
- :func:`curvature_face_weights` — per-face sampling probabilities rising with the mesh's integrated mean
  curvature (dihedral angle × edge length), mixed with a uniform-by-area share (i3d-style detail sampling).
- :func:`sample_near` — surface points moved by isotropic Gaussian noise N(0, σ² I) (NGLOD, Appendix A.2),
  with their signed distance.
- :func:`sample_uniform` — points uniform in the cube [-bound, bound]³ with their signed distance.
- :func:`signed_distance` — unsigned distance to the triangles by open3d's BVH
  (``RaycastingScene.compute_closest_points``, then the length in float64), signed by the inside test of
  ``sign`` (below). Negative inside.

Sign methods (``sign=`` of :func:`signed_distance`, :func:`sample_near`, :func:`sample_uniform`):

- ``"winding"`` — the generalised winding number (Jacobson et al. 2013), accelerated
  (:func:`neural_bake.mesh.winding.winding_number`; inside where w > 1/2). Right for open meshes and meshes
  with holes.
- ``"winding_exact"`` — the exact sum over all faces, O(N·F) (the slow reference).
- ``"raycast"`` — open3d's ray-parity occupancy with :data:`RAY_SAMPLES` rays per point (majority vote).
  Only right for watertight meshes; fastest.
- ``"hybrid"`` — ray parity along :data:`HYBRID_RAYS` fixed directions; where they all agree that is the
  answer, where they disagree (a hole or a crack is in view) the accelerated winding number decides.
  Faster than ``"winding"`` when holes are small (most points see none; docs/findings.md has the figures for a
  holed mesh), but a point that sees a hole along none (or all) of the directions keeps the rays' answer: a
  heuristic, not the winding number's sign everywhere.
- ``"auto"`` (default) — ``"raycast"`` for watertight meshes (``mesh.watertight``) none of whose faces is
  buried in another shell, ``"winding"`` otherwise (ray parity counts a point inside two overlapping closed
  shells as outside; the winding number counts 2, inside).

The solid is the union of the mesh's shells. Faces inside another shell (:func:`neural_bake.mesh.shells.
buried_faces`: teeth set into gums, a belt pushed into a body) are not on its boundary: surface samples, the
distances' closest points and the gap rays use the surface faces only (:func:`surface_faces`), so the signed
distance is the union's; the inside tests count every face.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..constants import DIRECTION_EPS, SIGN_SURE_MARGIN
from ..geometry import (check_points, import_open3d, raycasting_scene, sampleable_faces, vertex_normals,
                        welded_edges)
from ..io.colour import sample_texture
from ..mesh.shells import buried_faces
from ..mesh.winding import winding_number
from ..nets.native import threads
from ..types import Mesh

__all__ = [
    "signed_distance_sure",
    "SurfaceSamples",
    "VolumeSamples",
    "sample_surface",
    "surface_faces",
    "curvature_face_weights",
    "hard_edge_sides",
    "HARD_EDGE_DEG",
    "EDGE_BAND",
    "map_texel_weights",
    "TEXEL_WEIGHT_SIZE",
    "sample_near",
    "sample_uniform",
    "signed_distance",
    "unsigned_distance",
    "distance_gradient_targets",
    "NEAR_TARGET_MAX_DEG",
    "inside_mask",
    "SIGN_METHODS",
]

#: The inside tests ``signed_distance`` offers (see the module docstring).
SIGN_METHODS = ("auto", "winding", "winding_exact", "raycast", "hybrid")
#: Rays per point of the ray-parity occupancy (odd, majority vote).
RAY_SAMPLES = 3
#: Ray directions of the "hybrid" test; points whose parities disagree get the winding number.
HYBRID_RAYS = 5

#: Width (unit frame, across the face) of the strips along hard edges that ``sample_surface``'s ``edge_share``
#: draws from: about the cabinet's thinnest boards (0.012 across), which its fitted field rounds wholly
#: (docs/findings.md).
EDGE_BAND = 0.01

#: Smallest angle (degrees) between a file's normals on the two sides of an edge for :func:`hard_edge_sides` to
#: take it as a hard edge: a smooth file gives both sides one normal (to float precision); a hard edge splits them
#: by the angle its faces make (a board's 90°).
HARD_EDGE_DEG = 10.0


@dataclass
class SurfaceSamples:
    """Points on a mesh's surface, unit frame.

    N points; C colour channels (3 RGB or 4 RGBA) of the mesh's texture.
    """

    points: np.ndarray
    """(N, 3) float32 positions on the surface, unit frame."""
    normals: np.ndarray
    """(N, 3) float32 unit outward normals: the sampled face's normal ("face") or the barycentric
    interpolation of the area-weighted vertex normals, renormalised ("vertex")."""
    uv: np.ndarray | None
    """(N, 2) float32 interpolated texture coordinates (v = 0 at the image's bottom), or None without UVs."""
    colors: np.ndarray | None
    """(N, C) float32 linear colour, bilinear lookup of the texture at ``uv``, or None without texture."""
    face_index: np.ndarray
    """(N,) int64 index of the face each point lies on (never a degenerate or buried face)."""

    def __len__(self) -> int:
        return int(self.points.shape[0])


@dataclass
class VolumeSamples:
    """Points in space with their signed distance to a mesh, unit frame."""

    points: np.ndarray
    """(N, 3) float32 positions, unit frame."""
    sdf: np.ndarray
    """(N,) float32 signed distance to the mesh in unit-frame units, negative inside."""
    sure: np.ndarray | None = None
    """(N,) bool: the sign is sure (:func:`signed_distance_sure`); None: not known."""
    normals: np.ndarray | None = None
    """(N, 3) float32 direction of the signed distance's gradient where it is known, zero rows elsewhere
    (:func:`sample_near` with ``targets``); None: not computed."""

    def __len__(self) -> int:
        return int(self.points.shape[0])


# ----------------------------------------------------------------------------------------------- helpers


def _check_count(n, what: str) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"{what}: n must be a non-negative integer, got {n!r}")
    return int(n)


# ----------------------------------------------------------------------------------------------- surface


def sample_surface(mesh: Mesh, n: int, *, seed: int = 0, normals: str = "face",
                   face_weights: np.ndarray | None = None, colors: bool = True, edge_share: float = 0.0,
                   edge_band: float = EDGE_BAND) -> SurfaceSamples:
    """``n`` points uniform by area on the surface faces of ``mesh`` (:func:`surface_faces`; unit frame).

    A face is drawn with probability proportional to its area (degenerate faces — ``mesh.degenerate`` or
    area ≤ ``DEGENERATE_AREA`` — and faces buried in another shell never), then a point uniform in it by the
    square-root trick: barycentrics (1 - √r1, √r1 (1 - r2), √r1 r2) for r1, r2 ~ U[0, 1).

    - ``face_weights``: (F,) non-negative probabilities of drawing each face instead of the area's (e.g.
      :func:`curvature_face_weights`); degenerate and buried faces are still never drawn.
    - ``edge_share``: this part of the points (shuffled among the others) uniform by area within ``edge_band``
      (across the face) of the mesh's hard edges (:func:`hard_edge_sides`), on both faces of each, where a
      fitted field rounds a board's right angle and area sampling puts few points; all of them by
      ``face_weights`` when the mesh has no hard edge.

    - ``normals="face"``: the sampled face's geometric normal (exact for the piecewise-flat mesh);
      ``"vertex"``: the interpolated area-weighted vertex normals, renormalised (a smooth-surface estimate;
      falls back to the face normal where the interpolation vanishes).
    - UVs are the barycentric interpolation of the face's corner UVs; colours the bilinear lookup of the
      texture there (``sample_texture`` with ``mesh.uv_policy``), in linear RGB(A); ``colors=False`` skips the
      lookup (``colors`` None), for callers that need the places only or look the colours up themselves.

    Raises :class:`MeshError` when the mesh has no non-degenerate face.
    """
    n = _check_count(n, "sample_surface")
    if normals not in ("face", "vertex"):
        raise ValueError(f"sample_surface: normals must be 'face' or 'vertex', got {normals!r}")
    if not (math.isfinite(edge_share) and 0.0 <= edge_share <= 1.0):
        raise ValueError(f"sample_surface: edge_share must be in [0, 1], got {edge_share!r}")
    if not (math.isfinite(edge_band) and edge_band > 0):
        raise ValueError(f"sample_surface: edge_band must be positive and finite, got {edge_band!r}")
    edges = _edge_band_draw(mesh, int(round(n * edge_share)), edge_band, seed) if edge_share > 0 else None
    if edges is not None:
        n -= len(edges[0])
    idx, areas = surface_faces(mesh)
    rng = np.random.default_rng(seed)
    if face_weights is not None:
        w = np.asarray(face_weights, dtype=np.float64)
        if w.shape != (mesh.n_faces,) or not np.isfinite(w).all() or (w < 0).any():
            raise ValueError(f"sample_surface: face_weights must be {mesh.n_faces} non-negative finite numbers")
        if w[idx].sum() > 0:
            areas = w[idx]
    cdf = np.cumsum(areas)
    pick = np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right")
    face = idx[np.minimum(pick, idx.size - 1)].astype(np.int64)
    r = rng.random((n, 2))
    s = np.sqrt(r[:, 0])
    bary = np.stack([1.0 - s, s * (1.0 - r[:, 1]), s * r[:, 1]], axis=1)  # (n, 3)
    if edges is not None:  # shuffled in, so that any run of the points (sample_near's σ groups) has its share
        order = np.random.default_rng([seed, 3]).permutation(n + len(edges[0]))
        face, bary = np.concatenate([face, edges[0]])[order], np.concatenate([bary, edges[1]])[order]
    tri = mesh.vertices[mesh.faces[face]]  # (n, 3, 3)
    points = np.einsum("nk,nkd->nd", bary, tri)

    nrm = _interp_normals(mesh, face, bary) if normals == "vertex" else mesh.face_normals[face]

    uv = rgb = None
    if mesh.uv is not None:
        uv = np.einsum("nk,nkd->nd", bary, np.asarray(mesh.uv, dtype=np.float64)[face])
        if colors and mesh.texture is not None:
            rgb = sample_texture(mesh.texture, uv, mesh.uv_policy).astype(np.float32)
        uv = uv.astype(np.float32)
    return SurfaceSamples(points.astype(np.float32), nrm.astype(np.float32), uv, rgb, face)


def _interior_sides(mesh: Mesh, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two face sides of every manifold interior edge (welded: :func:`~neural_bake.geometry.welded_edges`)
    whose faces are both ``valid`` ((F,) bool): ``(a (E,), b (E,))`` int64 rows k·F + f, side k of face f the
    edge from its corner k to corner k + 1 mod 3."""
    edge, counts = welded_edges(mesh)
    order = np.argsort(edge, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pair = starts[counts == 2]  # an interior edge's two sides are adjacent in ``order``
    a, b = order[pair], order[pair + 1]
    ok = valid[a % mesh.n_faces] & valid[b % mesh.n_faces]
    return a[ok], b[ok]


def _outward_corner_normals(mesh: Mesh, face: np.ndarray) -> np.ndarray:
    """(N, 3, 3) the file's own corner normals (``mesh.corner_normals``) of faces ``face`` (N,), each turned to
    its face's outward side."""
    vn = np.asarray(mesh.corner_normals, dtype=np.float64)[face]
    side = np.einsum("nkd,nd->nk", vn, mesh.face_normals[face])
    return np.where((side < 0)[..., None], -vn, vn)


def hard_edge_sides(mesh: Mesh, min_deg: float = HARD_EDGE_DEG) -> tuple[np.ndarray, np.ndarray]:
    """The face sides on the mesh's hard edges: ``(face (K,) int64, slot (K,) int64)``, side ``slot`` of
    ``face`` the edge from its corner ``slot`` to corner ``slot + 1 mod 3``, both sides of every hard edge.

    A hard edge is one the file declares: an edge inside the surface (two faces once vertices at one position
    are welded) where the file's own normals (``mesh.corner_normals``, each turned to its face's outward side)
    differ between the two faces by more than ``min_deg`` at either end, the split a glTF or OBJ gives an edge
    it shades hard. A mesh without its own normals has none; degenerate faces and faces buried in another
    shell never count (:func:`surface_faces`).
    """
    empty = np.zeros(0, dtype=np.int64)
    if mesh.corner_normals is None or mesh.n_faces == 0:
        return empty, empty
    idx, _ = surface_faces(mesh)
    valid = np.zeros(mesh.n_faces, dtype=bool)
    valid[idx] = True
    a, b = _interior_sides(mesh, valid)
    nf = mesh.n_faces
    fa, fb, sa, sb = a % nf, b % nf, a // nf, b // nf
    cn = _outward_corner_normals(mesh, np.arange(nf))
    faces = np.asarray(mesh.faces, dtype=np.int64)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    # the two sides run the edge the same way, else opposite ways (welded corners share their position exactly)
    same = (v[faces[fa, sa]] == v[faces[fb, sb]]).all(axis=1)
    ends_a = np.stack([sa, (sa + 1) % 3], axis=1)
    ends_b = np.where(same[:, None], np.stack([sb, (sb + 1) % 3], axis=1), np.stack([(sb + 1) % 3, sb], axis=1))
    na = np.take_along_axis(cn[fa], ends_a[..., None], axis=1)  # (E, 2, 3): both ends' normals on a's side
    nb = np.take_along_axis(cn[fb], ends_b[..., None], axis=1)
    hard = (np.einsum("ekd,ekd->ek", na, nb) < math.cos(math.radians(min_deg))).any(axis=1)
    return np.concatenate([fa[hard], fb[hard]]), np.concatenate([sa[hard], sb[hard]])


def _edge_band_draw(mesh: Mesh, n: int, band: float, seed: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Faces (n,) and barycentrics (n, 3) of ``n`` points uniform by area over the strips within ``band``
    (across the face) of the hard edges (:func:`hard_edge_sides`), on both faces of each; None without a hard edge.

    A side is drawn with probability proportional to its strip's area, then a point at fraction λ of the face's
    height over the edge (λ ≤ min(1, band / height), with density ∝ 1 − λ, the strip's length there), uniform
    along it."""
    face, slot = hard_edge_sides(mesh)
    if face.size == 0 or n == 0:
        return None
    v = np.asarray(mesh.vertices, dtype=np.float64)
    tri = v[np.asarray(mesh.faces, dtype=np.int64)[face]]  # (K, 3, 3)
    rows = np.arange(face.size)
    length = np.linalg.norm(tri[rows, (slot + 1) % 3] - tri[rows, slot], axis=1)
    height = 2.0 * np.asarray(mesh.face_areas, dtype=np.float64)[face] / np.maximum(length, DIRECTION_EPS)
    top = np.minimum(1.0, band / np.maximum(height, DIRECTION_EPS))  # the strip's share of the height
    strip = length * height * (top - 0.5 * top**2)
    if not strip.sum() > 0:
        return None
    rng = np.random.default_rng([seed, 2])
    cdf = np.cumsum(strip)
    pick = np.minimum(np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right"), face.size - 1)
    r = rng.random((n, 2))
    a = top[pick]
    lam = 1.0 - np.sqrt(1.0 - 2.0 * r[:, 0] * (a - 0.5 * a**2))  # the inverse of (λ − λ²/2) / (a − a²/2)
    k, t = slot[pick], r[:, 1]
    bary = np.zeros((n, 3))
    at = np.arange(n)
    bary[at, k] = (1.0 - lam) * (1.0 - t)
    bary[at, (k + 1) % 3] = (1.0 - lam) * t
    bary[at, (k + 2) % 3] = lam
    return face[pick].astype(np.int64), bary


def surface_faces(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Indices (K,) int64 and areas (K,) float64 of the faces on the solid's boundary: the non-degenerate faces
    (:func:`~neural_bake.geometry.sampleable_faces`) less those buried in another shell
    (:func:`~neural_bake.mesh.shells.buried_faces`; the outermost shell never is one). Raises
    :class:`MeshError` when the mesh has no non-degenerate face."""
    idx, areas = sampleable_faces(mesh)
    keep = ~buried_faces(mesh)[idx]
    return idx[keep], areas[keep]


#: The map on which :func:`map_texel_weights` counts each face's texels where a layout overlaps or tiles.
TEXEL_WEIGHT_SIZE = 1024


def map_texel_weights(mesh: Mesh, size: int = TEXEL_WEIGHT_SIZE) -> np.ndarray | None:
    """(F,) float64 probabilities of drawing each face as densely as a bake onto the mesh reads its map's
    texels there; None without UVs or without any texel.

    A layout inside [0, 1]² whose triangles do not overlap gives each face its UV area's share. Where triangles
    overlap (mirrored parts) or UVs leave [0, 1]² (tiling, as ``mesh.uv_policy`` wraps or clamps them), a face
    gets the texels of a ``size`` × ``size`` map it holds (:func:`~neural_bake.mesh.texels.texel_counts`: the
    lowest face where triangles overlap, as the bake writes them), so an overlapped copy or a repeated tile does
    not count its texels twice; a face smaller than a texel keeps its UV area's expected count (a clamped face whose
    centre lies outside the map, none).
    """
    from ..mesh.texels import face_uv_areas, texel_counts

    if mesh.uv is None:
        return None
    uv = np.asarray(mesh.uv, dtype=np.float64)
    uv_area = face_uv_areas(uv)
    if uv_area.sum() <= 0:
        return None
    counts, overlaps = texel_counts(mesh, size)
    if overlaps == 0 and not ((uv < 0) | (uv > 1)).any():
        return uv_area / uv_area.sum()
    expected = uv_area * float(size) ** 2
    small = expected < 1.0
    weight = counts.astype(np.float64)
    in_map = np.ones(len(uv), dtype=bool)
    if mesh.uv_policy != "wrap":
        centre = uv.mean(axis=1)
        in_map = ((centre >= 0) & (centre <= 1)).all(axis=1)
    weight[small] = np.where(in_map[small], expected[small], 0.0)
    total = weight.sum()
    return weight / total if total > 0 else None


def curvature_face_weights(mesh: Mesh, uniform_share: float = 0.5) -> np.ndarray:
    """(F,) float64 probabilities of drawing each face: ``uniform_share`` by area, the rest by curvature.

    The curvature part of face f is its share of the mesh's integrated absolute mean curvature, the discrete
    Σ_e |θ_e| · |e| / 2 over its edges (θ_e the angle between the normals of the two faces of edge e, each
    face taking half of the edge's), so a sampled point's density per unit area rises with the mesh's
    curvature (creases and fine relief) while the uniform share keeps every region sampled. The density
    (curvature per area) is clipped at its area-weighted 99th percentile so that a few sliver faces with
    large angles do not take the whole budget. Vertices are welded by position first (a UV seam's split
    vertices are one), boundary and non-manifold edges carry no curvature, and degenerate faces get 0. A
    mesh without curvature (a plane) gives the uniform-by-area probabilities. Sums to 1.
    """
    u = float(uniform_share)
    if not (math.isfinite(u) and 0.0 <= u <= 1.0):
        raise ValueError(f"curvature_face_weights: uniform_share must be in [0, 1], got {uniform_share!r}")
    idx, areas = sampleable_faces(mesh)
    valid = np.zeros(mesh.n_faces, dtype=bool)
    valid[idx] = True
    area = np.zeros(mesh.n_faces)
    area[idx] = areas
    p_area = area / area.sum()
    if u >= 1.0:
        return p_area
    a, b = _interior_sides(mesh, valid)
    fa, fb = a % mesh.n_faces, b % mesh.n_faces
    n = np.asarray(mesh.face_normals, dtype=np.float64)
    theta = np.arccos(np.clip((n[fa] * n[fb]).sum(axis=1), -1.0, 1.0))
    v = np.asarray(mesh.vertices, dtype=np.float64)
    slot = a // mesh.n_faces  # occurrence a is edge (slot, slot + 1 mod 3) of face fa
    corners = np.asarray(mesh.faces)[fa]
    ends = np.take_along_axis(corners, np.stack([slot, (slot + 1) % 3], axis=1), axis=1)
    length = np.linalg.norm(v[ends[:, 0]] - v[ends[:, 1]], axis=1)
    k = np.zeros(mesh.n_faces)
    np.add.at(k, fa, 0.5 * theta * length)
    np.add.at(k, fb, 0.5 * theta * length)
    k = np.where(valid & np.isfinite(k), k, 0.0)
    if k.sum() <= 0:
        return p_area
    density = np.divide(k, area, out=np.zeros_like(k), where=area > 0)
    order_d = np.argsort(density)
    cum = np.cumsum(area[order_d]) / area.sum()
    cap = density[order_d][min(int(np.searchsorted(cum, 0.99)), order_d.size - 1)]
    if cap > 0:
        k = np.minimum(density, cap) * area
    return u * p_area + (1.0 - u) * k / k.sum()


# ----------------------------------------------------------------------------------------------- volume


def _sigmas(sigma) -> list[float]:
    values = [sigma] if np.isscalar(sigma) else list(sigma)
    if not values:
        raise ValueError("sample_near: sigma must be a positive number or a non-empty sequence of them")
    out = []
    for v in values:
        v = float(v)
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"sample_near: sigma must be positive and finite, got {v!r}")
        out.append(v)
    return out


def sample_near(
    mesh: Mesh,
    n: int,
    *,
    sigma: float | Sequence[float] = 0.01,
    seed: int = 0,
    sign: str = "auto",
    face_weights: np.ndarray | None = None,
    targets: float = 0.0,
    target_normals: str = "vertex",
    target_gap_share: float = 0.0,
    edge_share: float = 0.0,
    edge_band: float = EDGE_BAND,
) -> VolumeSamples:
    """``n`` points near the surface with their signed distance (unit frame).

    Surface points (:func:`sample_surface`, same ``seed``, ``face_weights``, ``edge_share`` and ``edge_band``)
    are moved by isotropic Gaussian noise N(0, σ² I). A sequence of σ mixes them in equal parts (the first ones
    get the remainder of ``n``), e.g. ``sigma=(0.01, 0.003)``. The signed distance is :func:`signed_distance` with ``sign``.

    ``targets`` > 0 also gives each point within that distance of the mesh the gradient of its signed distance,
    :func:`distance_gradient_targets` with ``target_normals`` and ``target_gap_share`` (``VolumeSamples.normals``;
    zero rows where there is none).
    """
    n = _check_count(n, "sample_near")
    sigmas = _sigmas(sigma)
    surf = sample_surface(mesh, n, seed=seed, face_weights=face_weights, colors=False, edge_share=edge_share,
                          edge_band=edge_band)
    rng = np.random.default_rng([seed, 1])
    counts = [n // len(sigmas) + (1 if i < n % len(sigmas) else 0) for i in range(len(sigmas))]
    scale = np.repeat(np.asarray(sigmas), counts)
    points = surf.points.astype(np.float64) + rng.standard_normal((n, 3)) * scale[:, None]
    sdf, sure, closest = _signed_distance_closest(mesh, points, sign)
    grad = None
    if targets > 0:
        grad = (np.zeros((0, 3)) if closest is None
                else distance_gradient_targets(mesh, points, sdf, closest, targets, target_normals,
                                               target_gap_share)).astype(np.float32)
    return VolumeSamples(points.astype(np.float32), sdf.astype(np.float32), sure, grad)


#: Largest angle between the offset from a point's closest point of the mesh and the mesh's normal there for
#: :func:`distance_gradient_targets` to give the point that normal (degrees): past it the closest point is on an
#: open boundary or a sharp edge, where the distance's gradient is not the surface's normal.
NEAR_TARGET_MAX_DEG = 30.0


def distance_gradient_targets(mesh: Mesh, points: np.ndarray, sdf: np.ndarray, closest: dict,
                              reach: float, normals: str = "vertex", gap_share: float = 0.0) -> np.ndarray:
    """(N, 3) float64 unit directions the gradient of the signed distance takes at ``points`` (N, 3) within
    ``reach`` of ``mesh``: the normal at each point's closest point (``closest``: :func:`_closest_points`),
    which an exact SDF's gradient equals off a smooth surface, inside and out — ``normals="vertex"``: the
    interpolated vertex normal (the shading a bake scores against), ``"face"``: the face's own (the gradient of
    the piecewise-flat mesh's distance). Zero rows where the distance is 0 or beyond ``reach``, or where the
    offset from the closest point is more than :data:`NEAR_TARGET_MAX_DEG` off that normal (an open boundary,
    a crease). ``gap_share`` > 0 also gives none where the point is further from its closest point than that
    share of the gap on its side: the distance from the closest point along the normal (outwards for a point
    outside, inwards inside) to the next piece of the mesh. Between two sheets closer than the reach (a thin
    wall, the inside of a narrow cup) the exact gradient turns over halfway; the share keeps the targets away
    from that turn."""
    if normals not in ("face", "vertex"):
        raise ValueError(f"distance_gradient_targets: normals must be 'face' or 'vertex', got {normals!r}")
    if not (math.isfinite(gap_share) and 0.0 <= gap_share <= 1.0):
        raise ValueError(f"distance_gradient_targets: gap_share must be in [0, 1], got {gap_share!r}")
    n = (_interp_normals(mesh, closest["face"], closest["bary"]) if normals == "vertex"
         else np.asarray(mesh.face_normals[closest["face"]], dtype=np.float64))
    offset = (points - closest["points"]) * np.sign(sdf)[:, None]
    dist = np.linalg.norm(offset, axis=1)
    cos = np.einsum("ij,ij->i", offset, n) / np.maximum(dist, DIRECTION_EPS)
    ok = (dist > DIRECTION_EPS) & (np.abs(sdf) <= reach) & (cos >= math.cos(math.radians(NEAR_TARGET_MAX_DEG)))
    if gap_share > 0 and ok.any():
        gap = np.full(len(points), np.inf)
        gap[ok] = _gap_along(mesh, closest["points"][ok], n[ok] * np.sign(sdf[ok])[:, None])
        ok &= dist <= gap_share * gap
    return np.where(ok[:, None], n, 0.0)


def _gap_along(mesh: Mesh, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(N,) distance from ``origins`` (N, 3) on the mesh along unit ``directions`` (N, 3) to the next piece of
    the mesh's surface faces (inf where the ray leaves it); the origins are lifted by
    :data:`GAP_LIFT` off their own face first (the BVH is float32)."""
    o3d = import_open3d()
    _, scene = _faces_scene(mesh)
    rays = np.concatenate([origins + GAP_LIFT * directions, directions], axis=1).astype(np.float32)
    t = scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays)), nthreads=threads())["t_hit"].numpy()
    return t.astype(np.float64) + GAP_LIFT


#: How far :func:`distance_gradient_targets`' gap rays start off the surface (unit frame): above float32's
#: error at the unit cube's scale, far below any gap a target is kept for.
GAP_LIFT = 1e-5


def _interp_normals(mesh: Mesh, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """(N, 3) unit interpolated vertex normals at barycentrics ``bary`` (N, 3) of faces ``face`` (N,): the
    file's own per corner where it has them (``mesh.corner_normals``: a glTF's hard edges stay hard, where the
    welded vertices' normals would round a box's faces by tens of degrees), each turned to the face's outward
    side; the face's own normal where the interpolation vanishes."""
    own = mesh.face_normals[face]
    if mesh.corner_normals is not None:
        vn = _outward_corner_normals(mesh, face)
    else:
        vn = vertex_normals(mesh)[mesh.faces[face]]
    nrm = np.einsum("nk,nkd->nd", bary, vn)
    norm = np.linalg.norm(nrm, axis=1, keepdims=True)
    return np.where(norm > DIRECTION_EPS, nrm / np.maximum(norm, DIRECTION_EPS), own)


def sample_uniform(mesh: Mesh, n: int, *, seed: int = 0, bound: float = 1.0, sign: str = "auto") -> VolumeSamples:
    """``n`` points uniform in the cube [-bound, bound]³ (unit frame) with their signed distance to ``mesh``."""
    n = _check_count(n, "sample_uniform")
    if not (math.isfinite(float(bound)) and float(bound) > 0):
        raise ValueError(f"sample_uniform: bound must be positive and finite, got {bound!r}")
    rng = np.random.default_rng([seed, 2])
    points = (rng.random((n, 3)) * 2.0 - 1.0) * float(bound)
    sdf, sure = signed_distance_sure(mesh, points, sign=sign) if n else (np.zeros(0), np.zeros(0, dtype=bool))
    return VolumeSamples(points.astype(np.float32), sdf.astype(np.float32), sure)


# ----------------------------------------------------------------------------------------------- distance


def unsigned_distance(mesh: Mesh, points: np.ndarray) -> np.ndarray:
    """(N,) float64 distance from ``points`` (N, 3) to the closest point of the mesh's surface faces
    (:func:`surface_faces`).

    open3d's BVH finds the closest point (in float32); the distance to it is taken in float64.
    """
    p = check_points(points, "signed_distance")
    if p.shape[0] == 0:
        return np.zeros(0)
    return np.linalg.norm(p - _closest_points(mesh, p)["points"], axis=1)


def _faces_scene(mesh: Mesh, *, buried: bool = False):
    """(indices of faces, the cached BVH of those faces): the surface faces (:func:`surface_faces`), what the
    distances, their closest points and the gap rays query; ``buried``: every non-degenerate face, what ray
    parity counts."""
    idx, _ = sampleable_faces(mesh) if buried else surface_faces(mesh)
    return idx, raycasting_scene(mesh.vertices, mesh.faces[idx])


def _closest_points(mesh: Mesh, points: np.ndarray) -> dict:
    """Closest points of the mesh's surface faces to ``points`` (N, 3) by open3d's BVH: ``{"points"
    (N, 3) float64, "face" (N,) int64 (the mesh's face index), "bary" (N, 3) (weights of its corners)}``."""
    o3d = import_open3d()
    idx, scene = _faces_scene(mesh)
    # on the fit's threads (measured or fixed), not open3d's default of every core
    res = scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32)),
                                       nthreads=threads())
    uv = res["primitive_uvs"].numpy().astype(np.float64)
    return {"points": res["points"].numpy().astype(np.float64),
            "face": idx[res["primitive_ids"].numpy().astype(np.int64)],
            "bary": np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1)}


def signed_distance(mesh: Mesh, points, *, sign: str = "auto") -> np.ndarray:
    """(N,) float64 signed distance from ``points`` (N, 3, unit frame) to ``mesh``; negative inside.

    The magnitude is the distance to the nearest surface face (:func:`surface_faces`; open3d BVH closest point,
    length in float64); the sign is the inside test ``sign`` (module docstring): ``"auto"`` ray parity for
    watertight meshes of shells that do not overlap, accelerated generalised winding number (inside where
    w > 1/2) otherwise.
    """
    return signed_distance_sure(mesh, points, sign=sign)[0]


def signed_distance_sure(mesh: Mesh, points, *, sign: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """(:func:`signed_distance` (N,), sure (N,) bool): whether each point's sign is sure, i.e. the ray parity of
    a watertight mesh, every ray of the "hybrid" test agreeing, or a winding number at least
    :data:`~neural_bake.constants.SIGN_SURE_MARGIN` from 1/2 (an open sheet reads about 1/2 on both sides)."""
    sdf, sure, _ = _signed_distance_closest(mesh, points, sign)
    return sdf, sure


def _signed_distance_closest(mesh: Mesh, points, sign: str) -> tuple[np.ndarray, np.ndarray, dict | None]:
    """:func:`signed_distance_sure`'s (signed distance, sure) and the closest points they were measured to
    (:func:`_closest_points`; None for no points)."""
    if sign not in SIGN_METHODS:
        raise ValueError(f"signed_distance: sign must be one of {SIGN_METHODS}, got {sign!r}")
    p = check_points(points, "signed_distance")
    if p.shape[0] == 0:
        return np.zeros(0), np.zeros(0, dtype=bool), None
    closest = _closest_points(mesh, p)
    dist = np.linalg.norm(p - closest["points"], axis=1)
    inside, sure = _inside_and_sure(mesh, p, sign)
    return np.where(inside, -dist, dist), sure, closest


def inside_mask(mesh: Mesh, points, *, method: str = "auto") -> np.ndarray:
    """(N,) bool: which ``points`` (N, 3) are inside ``mesh``, by ``method`` (module docstring)."""
    return _inside_and_sure(mesh, points, method)[0]


def _inside_and_sure(mesh: Mesh, points, method: str) -> tuple[np.ndarray, np.ndarray]:
    """(inside, sure), each (N,) bool: :func:`inside_mask` and whether the mesh defines that sign
    (:func:`signed_distance_sure`)."""
    if method not in SIGN_METHODS:
        raise ValueError(f"inside_mask: method must be one of {SIGN_METHODS}, got {method!r}")
    p = check_points(points, "signed_distance")
    if method == "auto":
        method = "raycast" if mesh.watertight and not buried_faces(mesh).any() else "winding"
    if method == "raycast":
        o3d = import_open3d()

        _, scene = _faces_scene(mesh, buried=True)
        occ = scene.compute_occupancy(o3d.core.Tensor(p.astype(np.float32)), nsamples=RAY_SAMPLES)
        inside = occ.numpy().astype(bool)
        return inside, np.ones(len(inside), dtype=bool)
    if method == "hybrid":
        votes = _ray_parities(mesh, p, HYBRID_RAYS)
        inside = votes.all(0)
        certain = np.ones(len(inside), dtype=np.bool_)
        unsure = np.flatnonzero(votes.any(0) & ~inside)
        if unsure.size:
            w = winding_number(mesh, p[unsure])
            inside[unsure] = w > 0.5
            certain[unsure] = np.abs(w - 0.5) >= SIGN_SURE_MARGIN
        return inside, certain
    w = winding_number(mesh, p, exact=(method == "winding_exact"))
    return w > 0.5, np.abs(w - 0.5) >= SIGN_SURE_MARGIN


def _ray_parities(mesh: Mesh, p: np.ndarray, k: int) -> np.ndarray:
    """(k, N) bool: odd number of crossings along each of ``k`` fixed, well-spread, non-axis directions."""
    o3d = import_open3d()

    _, scene = _faces_scene(mesh, buried=True)
    i = np.arange(k) + 0.5
    z = 1.0 - 2.0 * i / k
    phi = i * math.pi * (3.0 - math.sqrt(5.0)) + 0.3  # golden-angle spiral, turned off the axes
    dirs = np.stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z], 1)
    out = np.empty((k, p.shape[0]), dtype=bool)
    for j, d in enumerate(dirs):
        rays = np.concatenate([p, np.broadcast_to(d, p.shape)], 1).astype(np.float32)
        out[j] = scene.count_intersections(o3d.core.Tensor(rays)).numpy() % 2 == 1
    return out
