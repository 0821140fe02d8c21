"""Baking neural normals and colours per vertex and per texel (neural normal and texture mapping, §4.1–4.2).

``Baker(mesh)`` unwraps (if the mesh has no UVs), computes the tangent frames once and rasterises the UV
layout once; ``Baker.bake(sdf, texture)`` then evaluates ∇f (GEMM normals) and g at the texel points in
chunks and writes the maps. ``bake_texels`` is the one-off wrapper, ``bake_vertices`` the per-vertex bake.

A bake that streams its texels (large maps) keeps no per-sample arrays but a deterministic uniform subsample
of them (:class:`TexelSample`), on which :func:`neural_bake.bake.report.bake_report` measures its errors.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..constants import ADAPTIVE_CHECK_SAMPLES
from ..errors import NeuralBakeError
from ..fields import SdfField, TextureField, closest_surface_points
from ..geometry import angular_error, area_weighted_normals
from ..types import Frame, Mesh
from ..mesh.layout_cache import LayoutCache
from ..mesh.texels import TexelSet, kernel_status
from ..nets.grid import GridNet
from ..nets.grid import kernel_status as grid_kernel_status
from .adaptive import AdaptiveOptions, adaptive_evaluate, chart_labels, grid_positions, vertex_positions
from .adaptive import kernel_status as adaptive_kernel_status
from .adaptive_faces import face_geometry
from .baseline import kernel_status as classical_kernel_status
from .hybrid import kernel_status as hybrid_kernel_status
from .maps import NORMAL_SPACES, Y_CONVENTIONS, encode_tangent_space, normal_map_from_sums, splat_into
from .maps import kernel_status as encoding_kernel_status
from .padding import PADDING_METHODS, pad_charts
from .padding import kernel_status as padding_kernel_status

__all__ = ["TEXTURE_AT", "Baker", "BakeResult", "TexelSample", "sample_keys", "bake_texels", "bake_vertices",
           "welded_vertex_normals"]

DEFAULT_CHUNK = 1 << 16
#: Texel samples a streamed bake keeps for its quality report (about 64 MB of per-sample data).
REPORT_SAMPLES = 1 << 18
#: Sample positions per band when the Baker streams the layout (see :func:`neural_bake.mesh.texels.iter_texels`).
BAND_SAMPLES = 1 << 20
#: Per-sample fields of a :class:`TexelSet` (everything but the grid-level ones).
_TEXEL_FIELDS = ("pixel", "points", "normal", "tangent", "bitangent", "face", "bary", "weight", "texel", "border")


def sample_keys(index: np.ndarray, seed: int = 0) -> np.ndarray:
    """(N,) uint64 pseudo-random keys of global sample indices (N,) (splitmix64 of index and ``seed``).

    A sample's key depends only on its position in the full texel order and the seed, so the samples with
    the smallest keys are the same however the layout is cut into bands: a uniform sample without
    replacement, reproducible.
    """
    x = np.asarray(index).astype(np.uint64)  # a copy, mixed in place (one scratch array: half the fresh memory)
    x += np.uint64((int(seed) * 0x9E3779B97F4A7C15 + 0x632BE59BD9B4E019) % 2**64)
    t = x >> np.uint64(30)
    x ^= t
    x *= np.uint64(0xBF58476D1CE4E5B9)
    x ^= np.right_shift(x, np.uint64(27), out=t)
    x *= np.uint64(0x94D049BB133111EB)
    x ^= np.right_shift(x, np.uint64(31), out=t)
    return x


def keys_below(keys: np.ndarray, fraction: float) -> np.ndarray:
    """``keys.astype(float64) / 2**64 < fraction`` for :func:`sample_keys` ``keys`` (uint64), as one integer
    comparison: the smallest key whose float64 share reaches ``fraction`` is found by bisection (the rounding of
    uint64 to float64 is monotonic), so the same keys pass, without a float copy of them."""
    lo, hi = 0, 2**64  # the bound lies in [0, 2**64]; 2**64: every key passes
    while lo < hi:
        mid = (lo + hi) // 2
        if float(np.uint64(mid)) / 2.0**64 >= fraction:
            hi = mid
        else:
            lo = mid + 1
    keys = np.asarray(keys, dtype=np.uint64)
    return np.ones(keys.shape, dtype=bool) if lo >= 2**64 else keys < np.uint64(lo)


@dataclass
class TexelSample:
    """A uniform subsample of a bake's texel samples with their per-sample values (for the quality report).

    The N = min(limit, M) samples with the smallest :func:`sample_keys` among all M samples of the bake,
    in the order of the full texel set (as :func:`neural_bake.mesh.texels.rasterize_texels` orders it).

    - ``texels``: :class:`TexelSet` of the N samples (``coverage``: the texels holding one of them).
    - ``index``: (N,) int64 position of each in the full order.
    - ``normals``, ``encoded``, ``valid``, ``values``, ``colors``: as in :class:`BakeResult`, for these N.
    - ``total``: M, the bake's sample count; ``seed``: the key seed.
    - ``replaced``, ``neural``: as in :class:`BakeResult`, for these N (hybrid bakes; else None).
    """

    texels: TexelSet
    index: np.ndarray
    normals: np.ndarray
    encoded: np.ndarray
    valid: np.ndarray
    values: np.ndarray
    colors: np.ndarray | None
    total: int
    seed: int
    replaced: np.ndarray | None = None
    neural: np.ndarray | None = None

    @property
    def n_samples(self) -> int:
        return int(self.index.shape[0])


class _Reservoir:
    """Bottom-k sampling over streamed bands: keeps the ``limit`` samples with the smallest keys seen so far."""

    def __init__(self, limit: int, seed: int):
        self.limit, self.seed = int(limit), int(seed)
        self.seen = 0
        self.keys = np.zeros(0, dtype=np.uint64)
        self.index = np.zeros(0, dtype=np.int64)
        self.data: dict[str, np.ndarray] | None = None

    def add(self, arrays: dict[str, np.ndarray | None]) -> None:
        """Offer the next band's samples: ``arrays`` maps a name to its (n, ...) per-sample array (or None)."""
        n = len(arrays["points"])
        index = np.arange(self.seen, self.seen + n, dtype=np.int64)
        self.seen += n
        if self.limit == 0 or n == 0:
            return
        keys = sample_keys(index, self.seed)
        pick = np.flatnonzero(keys < self.keys.max()) if len(self.keys) >= self.limit else np.arange(n)
        if pick.size == 0:
            return
        if pick.size > self.limit:  # only the band's ``limit`` smallest keys can be among the smallest overall
            pick = np.sort(pick[np.argpartition(keys[pick], self.limit - 1)[: self.limit]])
        # np.take: a few times faster than fancy indexing on (n, 3) arrays
        new = {k: np.take(np.asarray(v), pick, axis=0) for k, v in arrays.items() if v is not None}
        keys, index = np.concatenate([self.keys, keys[pick]]), np.concatenate([self.index, index[pick]])
        data = new if self.data is None else {k: np.concatenate([self.data[k], new[k]]) for k in new}
        if len(keys) > self.limit:
            keep = np.sort(np.argpartition(keys, self.limit - 1)[: self.limit])  # sorted: full texel order
            keys, index = keys[keep], index[keep]
            data = {k: np.take(v, keep, axis=0) for k, v in data.items()}
        self.keys, self.index, self.data = keys, index, data

    def sample(self, size: tuple[int, int], supersample: int) -> TexelSample:
        d = self.data or {}
        if not d:  # no samples at all
            e3 = np.zeros((0, 3))
            d = {"pixel": np.zeros((0, 2), np.int64), "points": e3, "normal": e3, "tangent": e3, "bitangent": e3,
                 "face": np.zeros(0, np.int64), "bary": e3, "weight": np.zeros(0), "texel": np.zeros(0, np.int64),
                 "border": np.zeros(0, bool), "normals": e3, "encoded": e3, "valid": np.zeros(0, bool),
                 "values": np.zeros(0)}
        cov = np.zeros(size, dtype=bool)
        cov[d["pixel"][:, 0], d["pixel"][:, 1]] = True
        texels = TexelSet(size=size, coverage=cov, supersample=supersample, overlaps=0,
                          **{k: d[k] for k in _TEXEL_FIELDS})
        return TexelSample(texels=texels, index=self.index, normals=d["normals"], encoded=d["encoded"],
                           valid=d["valid"], values=d["values"], colors=d.get("colors"), total=self.seen,
                           seed=self.seed, replaced=d.get("replaced"), neural=d.get("neural"))


@dataclass
class BakeResult:
    """The maps and per-sample values of one bake (H, W = map size; M = texel samples).

    - ``normal_map``: (H, W, 3) float32 in [0, 1], encoded ``(n + 1) / 2`` (linear data), padded.
    - ``albedo``: (H, W, C) float32 linear RGB(A), padded; None without a colour field.
    - ``coverage``: (H, W) bool, texels inside a chart (they received at least one sample).
    - ``miss``: (H, W) bool, texels with a sample outside the nesting band (|f| > δ); all False without δ.
    - ``normals``: (M, 3) float64 object-space (unit frame axes) unit normals per sample, after the
      geometric fallback for invalid gradients, in the order of ``Baker.texels`` (per-sample arrays are
      None when the bake streamed the texels without keeping them).
    - ``encoded``: (M, 3) float64 the per-sample vector stored in the map (tangent or object space, before
      the (x + 1)/2 encoding).
    - ``valid``: (M,) bool, |∇f| was usable; ``values``: (M,) f at the samples; ``colors``: (M, C) or None.
    - ``stats``: counts and seconds per stage, and the CPU threads the evaluations ran with (``threads``:
      :meth:`~neural_bake.nets.threads.ThreadChoice.as_dict`) and what was done to malloc (``heap``:
      :func:`~neural_bake.nets.heap.keep_freed_memory`) and which rasteriser, tangent-space encoding and
      padding ran (``kernels``: C or numpy, :func:`neural_bake.mesh.texels.kernel_status`,
      :func:`neural_bake.bake.maps.kernel_status`, :func:`neural_bake.bake.padding.kernel_status`; an adaptive bake's
      cell interpolation: C or torch, :func:`neural_bake.bake.adaptive.kernel_status`) (JSON-ready).
    - ``sample``: when the per-sample arrays are not kept, a :class:`TexelSample` (a seeded uniform
      subsample of the samples with their values) for the quality report; else None.
    - ``hybrid``: (H, W) bool, texels with a sample that took the classical normal (a hybrid bake), else None.
    - ``replaced``: (M,) bool, the samples that took it; ``neural``: (M, 3) their ∇f before (hybrid bakes
      that keep their samples; None otherwise).
    - ``hybrid_color``: (H, W) bool, texels with a sample that took the source texture's colour (a hybrid
      bake that decided colours), else None; ``colors_replaced`` (M,) and ``neural_colors`` (M, C): as
      ``replaced`` and ``neural``, for the colours.
    """

    normal_map: np.ndarray
    albedo: np.ndarray | None
    coverage: np.ndarray
    miss: np.ndarray
    normals: np.ndarray
    encoded: np.ndarray
    valid: np.ndarray
    values: np.ndarray
    colors: np.ndarray | None
    stats: dict = field(default_factory=dict)
    sample: TexelSample | None = None
    hybrid: np.ndarray | None = None
    replaced: np.ndarray | None = None
    neural: np.ndarray | None = None
    hybrid_color: np.ndarray | None = None
    colors_replaced: np.ndarray | None = None
    neural_colors: np.ndarray | None = None


def welded_vertex_normals(mesh: Mesh) -> np.ndarray:
    """(V, 3) area-weighted unit vertex normals computed over vertices welded by position, so the copies of
    a vertex split at a UV seam get the same normal. A vertex without usable faces gets +Z."""
    return area_weighted_normals(mesh.vertices, mesh.faces, weld=True, fallback=(0.0, 0.0, 1.0))


def _tensor_kwargs(f) -> dict:
    model = getattr(f, "model", None) or (f.fn if isinstance(f.fn, torch.nn.Module) else None)
    if model is not None:
        p = next(model.parameters(), None)
        if p is not None:
            return {"dtype": p.dtype, "device": p.device}
    return {"dtype": torch.float64, "device": torch.device("cpu")}


def _to_field_frame(points: np.ndarray, mesh_frame: Frame, field_frame: Frame | None) -> np.ndarray:
    if field_frame is None or field_frame == mesh_frame:
        return points
    return field_frame.to_unit(mesh_frame.to_source(points))


#: Where a bake reads the colour field: at the closest point of the SDF's zero set, or at the sample itself.
TEXTURE_AT = ("surface", "point")


def _evaluate(
    points: np.ndarray, mesh_frame: Frame, sdf: SdfField | None, texture: TextureField | None, chunk_size: int,
    texture_at: str = "point", surface_normals: np.ndarray | None = None,
) -> dict:
    """f, unit ∇f, valid and g at ``points`` (M, 3) (mesh unit frame), in chunks of ``chunk_size``; g at the
    points themselves or, ``texture_at="surface"`` (with an SDF), at their closest points on f = 0.

    A colour field with normal inputs reads the SDF's unit ∇f where it reads at f = 0 (the normal of the surface
    it reads), and ``surface_normals`` (M, 3), the mesh's normals at the points, where it reads at the points
    themselves or ∇f is unusable or faces the other way there (:func:`_texture_normals`)."""
    m = len(points)
    out: dict = {"time_sdf": 0.0, "time_texture": 0.0}
    if sdf is not None:
        kw = _tensor_kwargs(sdf)
        values, normals, valid = np.empty(m), np.empty((m, 3)), np.empty(m, dtype=bool)
        in_sdf = _to_field_frame(points, mesh_frame, sdf.frame)
        t0 = time.perf_counter()
        for s in range(0, m, chunk_size):
            p = torch.as_tensor(in_sdf[s : s + chunk_size], **kw)
            v, n, ok = sdf.value_and_normal(p)
            values[s : s + chunk_size] = v.double().cpu().numpy()
            normals[s : s + chunk_size] = n.double().cpu().numpy()
            valid[s : s + chunk_size] = ok.cpu().numpy()
        out["time_sdf"] = time.perf_counter() - t0
        out.update(values=values, normals=normals, valid=valid)
    if texture is not None:
        kw = _tensor_kwargs(texture)
        at = points
        if texture_at == "surface" and sdf is not None:
            reach = texture.delta if texture.delta is not None else sdf.delta
            q = closest_surface_points(torch.from_numpy(np.asarray(in_sdf)), torch.from_numpy(values),
                                       torch.from_numpy(normals), torch.from_numpy(valid), reach).numpy()
            at = q if sdf.frame is None or sdf.frame == mesh_frame else mesh_frame.to_unit(sdf.frame.to_source(q))
        pts = _to_field_frame(at, mesh_frame, texture.frame)
        nrm = _texture_normals(texture, m, surface_normals, out if texture_at == "surface" else None)
        chunks = []
        t0 = time.perf_counter()
        for s in range(0, m, chunk_size):
            x = torch.as_tensor(pts[s : s + chunk_size], **kw)
            c = texture.color(x) if nrm is None else texture.color(x, torch.as_tensor(nrm[s : s + chunk_size], **kw))
            chunks.append(c.double().cpu().numpy())
        out["time_texture"] = time.perf_counter() - t0
        out["colors"] = np.concatenate(chunks) if chunks else np.zeros((0, 3))
    return out


def _texture_normals(texture: TextureField, m: int, surface: np.ndarray | None, sdf_eval: dict | None
                     ) -> np.ndarray | None:
    """The (m, 3) normals a colour field with normal inputs reads (None for any other field): the SDF's unit ∇f
    where ``sdf_eval`` (its evaluation at the samples) has a valid one facing the same side as the mesh's
    ``surface`` normal there, else that normal (an open mesh's SDF may face the other way: the colour of the
    other side). Without either, :class:`~neural_bake.errors.NeuralBakeError` names what is missing."""
    if not getattr(texture, "normal_inputs", False):
        return None
    if sdf_eval is not None and "normals" in sdf_eval:
        out = np.array(sdf_eval["normals"], dtype=np.float64)
        bad = ~np.asarray(sdf_eval["valid"], dtype=bool)
        if surface is None:
            out[bad] = 0.0
        else:
            surface = np.asarray(surface, dtype=np.float64)
            bad |= np.einsum("ij,ij->i", out, surface) < 0
            out[bad] = surface[bad]
        return out
    if surface is None:
        raise NeuralBakeError(f"{texture.name}: the colour field reads surface normals, and this bake gave none "
                              "(bake with the SDF, or from a mesh)")
    return np.asarray(surface, dtype=np.float64).reshape(m, 3)


def _quantiles(x: np.ndarray) -> dict:
    if x.size == 0:
        return {"median": None, "p95": None, "max": None}
    return {"median": float(np.median(x)), "p95": float(np.percentile(x, 95)), "max": float(x.max())}


class _ErrorControl:
    """How a bake evaluates its fields per band (every sample, or adaptively; float32 or reduced precision)
    and what that costs in error.

    ``evaluate(texels, points)`` returns :func:`_evaluate`'s dict for the band (plus ``evaluated``: (M,) bool,
    the samples the fields were evaluated at). ``check(points, ev)`` evaluates a seeded uniform choice of about
    ``samples`` of the bake's samples fully in float32 where they were not (interpolated ones, and every one
    of a reduced-precision bake) and keeps their error;
    ``summary()`` is the bake stats' ``adaptive`` and ``error_control`` entries.
    """

    def __init__(self, baker: "Baker", sdf, texture, adaptive, samples: int, seed: int, fast=None,
                 texture_at: str = "point"):
        self.baker, self.sdf, self.texture, self.adaptive = baker, sdf, texture, adaptive
        self.texture_at = texture_at
        self.fast_sdf, self.fast_tex = fast if fast is not None else (sdf, texture)
        self.reduced = self.fast_sdf is not sdf or self.fast_tex is not texture
        self.precision: dict = {}
        self.seed, self.seen = int(seed), 0
        expected = baker.size * baker.size * baker.supersample**2
        if baker.texels is not None:
            expected = baker.texels.n_samples
        self.checked = adaptive is not None or self.reduced
        self.fraction = min(1.0, samples / max(1, expected)) if self.checked else 0.0
        self.counts = {"samples": 0, "evaluated": 0, "interpolated": 0, "calls": 0, "outside": 0, "face_nodes": 0,
                       "face_interpolated": 0, "face_cells": 0, "given_up": 0, "rim": 0}
        self.cells: dict[str, int] = {}
        self.given_cells: dict[str, int] = {}
        self.source_cells: dict[str, int] = {}
        self.source_split: dict[str, int] = {}
        self.angles: list[np.ndarray] = []
        self.colors: list[np.ndarray] = []
        self.values: list[np.ndarray] = []
        self.interp: list[np.ndarray] = []
        self._charts = None
        self._faces = None
        self._face_normals: np.ndarray | None = None
        # float32 fields are interpolated in float32 (their own precision), anything else in float64
        dtypes = {_tensor_kwargs(f)["dtype"] for f in (sdf, texture) if f is not None}
        self.dtype = torch.float32 if dtypes == {torch.float32} else torch.float64

    def face_normals(self, face: np.ndarray) -> np.ndarray | None:
        """The coarse mesh's normals of the faces ``face`` (any shape), when the colour field reads normals."""
        if not getattr(self.texture, "normal_inputs", False):
            return None
        if self._face_normals is None:
            self._face_normals = self.baker.mesh.face_normals
        return self._face_normals[np.asarray(face, dtype=np.int64)]

    def evaluate(self, tx, points: np.ndarray, normals: np.ndarray | None = None, give_up=None) -> dict:
        """The fields at the band ``tx``'s ``points``; ``normals``: :meth:`face_normals` of its samples;
        ``give_up``: a hybrid's early decision, for an adaptive bake (:func:`~neural_bake.bake.adaptive.adaptive_evaluate`;
        its ``"given_up"`` samples are in the result)."""
        b = self.baker
        if self.adaptive is None:
            ev = _evaluate(points, b.mesh.frame, self.fast_sdf, self.fast_tex, b.chunk_size, self.texture_at,
                           normals)
            ev["evaluated"] = np.ones(len(points), dtype=bool)
            self.counts["samples"] += len(points)
            self.counts["evaluated"] += len(points)
            return ev
        t0 = time.perf_counter()
        if self._charts is None:
            self._charts = chart_labels(b.mesh)
            self._vertices = vertex_positions(b.mesh, b.shape, b.supersample)
            self._faces = face_geometry(b.mesh, b.shape, b.supersample)
        times = {"time_sdf": 0.0, "time_texture": 0.0}

        def at_points(p, nrm=None):
            e = _evaluate(p, b.mesh.frame, self.fast_sdf, self.fast_tex, b.chunk_size, self.texture_at, nrm)
            times["time_sdf"] += e["time_sdf"]
            times["time_texture"] += e["time_texture"]
            return e

        def at_samples(idx):
            return at_points(points[idx], None if normals is None else normals[idx])

        def at_face_points(p, face):
            return at_points(p, self.face_normals(face))

        res = adaptive_evaluate(tx, self._charts[np.asarray(tx.face, dtype=np.int64)], grid_positions(tx, b.mesh),
                                at_samples, self.adaptive, vertices=self._vertices,
                                dtype=self.dtype, faces=self._faces, evaluate_points=at_face_points,
                                give_up=give_up)
        st = res["stats"]
        for k in ("samples", "evaluated", "interpolated", "face_nodes", "face_interpolated", "face_cells", "given_up",
                  "rim"):
            self.counts[k] += st[k]
        for k, v in st["cells_given_up"].items():
            self.given_cells[k] = self.given_cells.get(k, 0) + v
        for k, v in st["cells_source_detail"].items():
            self.source_cells[k] = self.source_cells.get(k, 0) + v
        for k, v in st["cells_source_split"].items():
            self.source_split[k] = self.source_split.get(k, 0) + v
        self.counts["calls"] += st["evaluation_calls"]
        self.counts["outside"] += st["evaluated_outside_cells"]
        for k, v in st["cells_accepted"].items():
            self.cells[k] = self.cells.get(k, 0) + v
        ev = {"values": res["values"], "normals": res["normals"], "valid": res["valid"], "evaluated": res["evaluated"],
              "decide": res["decide"], "side": res["side"], "given_up": res["given_up"], **times}
        if self.texture is not None:
            ev["colors"] = res["colors"]
        ev["time_adaptive"] = time.perf_counter() - t0 - times["time_sdf"] - times["time_texture"]
        return ev

    def check(self, points: np.ndarray, ev: dict, normals: np.ndarray | None = None) -> None:
        n = len(points)
        index = np.arange(self.seen, self.seen + n, dtype=np.int64)
        self.seen += n
        if self.fraction <= 0 or n == 0:
            return
        keys = sample_keys(index, self.seed)
        pick = np.flatnonzero(keys_below(keys, self.fraction))
        if ev.get("given_up") is not None:  # the classical bake's texels: no interpolation of ∇f in the map
            pick = pick[~ev["given_up"][pick]]
        if pick.size == 0:
            return
        exact = ev["evaluated"][pick] & (not self.reduced)  # evaluated in float32: the reference itself
        self.interp.append(~ev["evaluated"][pick])
        ang = np.zeros(pick.size)
        col = np.zeros(pick.size)
        val = np.zeros(pick.size)
        redo = pick[~exact]
        if redo.size:
            ref = _evaluate(points[redo], self.baker.mesh.frame, self.sdf, self.texture, self.baker.chunk_size,
                            self.texture_at, None if normals is None else normals[redo])
            both = ref["valid"] & ev["valid"][redo]
            a = np.zeros(redo.size)
            a[both] = angular_error(ev["normals"][redo][both], ref["normals"][both])
            a[~both & (ref["valid"] != ev["valid"][redo])] = 180.0  # one of the two has no normal
            ang[~exact] = a
            val[~exact] = np.abs(ev["values"][redo] - ref["values"])
            if self.texture is not None:
                col[~exact] = np.abs(ev["colors"][redo] - ref["colors"]).max(axis=1)
        self.angles.append(ang)
        self.colors.append(col)
        self.values.append(val)

    def summary(self) -> dict:
        c = self.counts
        evaluated = (c["evaluated"] + c["face_nodes"]) / max(1, c["samples"])  # evaluations per sample
        out: dict = {"adaptive": None if self.adaptive is None else {
            "tolerance_deg": float(self.adaptive.tolerance_deg), "lattice": int(self.adaptive.lattice),
            "color_tol": float(self.adaptive.color_tol), "value_tol": float(self.adaptive.value_tol),
            "samples": c["samples"], "evaluated": c["evaluated"], "interpolated": c["interpolated"],
            "evaluated_fraction": evaluated,
            "evaluated_outside_cells": c["outside"], "cells_accepted": self.cells, "face_nodes": c["face_nodes"],
            "face_interpolated": c["face_interpolated"], "face_cells": c["face_cells"],
            "given_up": c["given_up"], "rim": c["rim"], "cells_given_up": self.given_cells,
            "cells_source_detail": self.source_cells, "cells_source_split": self.source_split,
            "evaluation_calls": c["calls"]},
            "evaluated_fraction": evaluated}
        out["precision"] = self.precision
        if self.checked:
            ang = np.concatenate(self.angles) if self.angles else np.zeros(0)
            col = np.concatenate(self.colors) if self.colors else np.zeros(0)
            val = np.concatenate(self.values) if self.values else np.zeros(0)
            interp = np.concatenate(self.interp) if self.interp else np.zeros(0, bool)
            out["error_control"] = {
                "reference": "full float32 evaluation of the same fields at the same samples",
                "samples": int(ang.size), "interpolated": int(interp.sum()), "seed": self.seed,
                "angle_deg": _quantiles(ang), "interpolated_angle_deg": _quantiles(ang[interp]),
                "precision_angle_deg": _quantiles(ang[~interp]) if self.reduced else None,
                "color_max": float(col.max()) if self.texture is not None and col.size else None,
                "value_max": float(val.max()) if val.size else None,
            }
        return out


def _check_texture_at(texture_at) -> str:
    if texture_at not in TEXTURE_AT:
        raise NeuralBakeError(f"texture_at must be one of {', '.join(TEXTURE_AT)}, got {texture_at!r}")
    return texture_at


def _check_chunk(chunk_size) -> int:
    if int(chunk_size) != chunk_size or chunk_size < 1:
        raise NeuralBakeError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    return int(chunk_size)


def bake_vertices(
    mesh: Mesh, sdf: SdfField, texture: TextureField | None = None, *, chunk_size: int = DEFAULT_CHUNK,
    texture_at: str = "surface",
) -> dict:
    """Per-vertex neural normal (and texture) mapping; ``texture_at`` as in :meth:`Baker.bake`.

    Returns ``{"normals": (V, 3) float64 unit (unit frame axes), "colors": (V, C) linear or None,
    "valid": (V,) bool, "sdf": (V,) f at the vertices, "invalid": count}``. Vertices with an unusable
    gradient (|∇f| ≈ 0) keep the mesh's own vertex normal.
    """
    from ..mesh.tangents import vertex_normals

    own = vertex_normals(mesh) if getattr(texture, "normal_inputs", False) else None  # a colour field reads them
    ev = _evaluate(mesh.vertices, mesh.frame, sdf, texture, _check_chunk(chunk_size), _check_texture_at(texture_at),
                   own)
    normals = ev["normals"]
    valid = ev["valid"]
    if (~valid).any():
        normals[~valid] = (vertex_normals(mesh) if own is None else own)[~valid]
    return {
        "normals": normals,
        "colors": ev.get("colors"),
        "valid": valid,
        "sdf": ev["values"],
        "invalid": int((~valid).sum()),
    }


class Baker:
    """Rasterise a mesh's UV layout once, then bake many fields into texture maps.

    - ``mesh``: the coarse mesh (unit frame). Without UVs it is unwrapped with xatlas
      (:func:`neural_bake.mesh.unwrap.unwrap`); with UVs its vertices are split at UV seams.
      ``self.mesh`` is the mesh the maps belong to: export that one, with ``self.tangents`` (V, 4).
    - ``size``: map side in texels (H = W = size).
    - ``supersample``: s×s samples per texel, averaged (anti-aliasing).
    - ``chunk_size``: texel samples per network evaluation.
    - ``normal_space``: "tangent" (glTF) or "object".
    - ``y_convention``: "opengl" (glTF, +Y green up) or "directx" (green flipped); tangent space only.
    - ``padding``: "pull-push", "dilate" or None (no padding); ``padding_pixels``: see :func:`pad_charts`.
    - ``unwrap_options``: keyword arguments for ``unwrap`` when the mesh has no UVs.
    - ``layout_cache``: a :class:`~neural_bake.mesh.layout_cache.LayoutCache` the unwrap is read from (and kept
      in) when an earlier run unwrapped the same mesh with the same options.
    - ``layout``: ``mesh`` unwrapped already with the same options (e.g. by :mod:`.preload`'s process), taken
      instead of unwrapping it here.
    - ``cache_texels``: keep the rasterised texels between bakes (``self.texels``); None = only when there
      are at most ``2**23`` samples (2048² with supersample 2). Without the cache every bake streams the
      layout band by band (:func:`neural_bake.mesh.texels.iter_texels`), so 4k maps fit in memory.
    - ``band_samples``: sample positions per band when streaming.
    """

    def __init__(
        self,
        mesh: Mesh,
        size: int = 2048,
        *,
        supersample: int = 1,
        chunk_size: int = DEFAULT_CHUNK,
        normal_space: str = "tangent",
        y_convention: str = "opengl",
        padding: str | None = "pull-push",
        padding_pixels: int | None = None,
        unwrap_options: dict | None = None,
        cache_texels: bool | None = None,
        band_samples: int = BAND_SAMPLES,
        layout_cache: LayoutCache | None = None,
        layout: Mesh | None = None,
    ):
        if isinstance(size, bool) or int(size) != size or size < 1:
            raise NeuralBakeError(f"map size must be a positive integer, got {size!r}")
        if int(supersample) != supersample or supersample < 1:
            raise NeuralBakeError(f"supersample must be a positive integer, got {supersample!r}")
        if normal_space not in NORMAL_SPACES:
            raise NeuralBakeError(f"normal_space must be one of {NORMAL_SPACES}, got {normal_space!r}")
        if y_convention not in Y_CONVENTIONS:
            raise NeuralBakeError(f"y_convention must be one of {Y_CONVENTIONS}, got {y_convention!r}")
        if padding is not None and padding not in PADDING_METHODS:
            raise NeuralBakeError(f"padding must be one of {PADDING_METHODS} or None, got {padding!r}")
        self.size, self.supersample = int(size), int(supersample)
        self.shape = (self.size, self.size)
        self.chunk_size = _check_chunk(chunk_size)
        if isinstance(band_samples, bool) or int(band_samples) != band_samples or band_samples < 1:
            raise NeuralBakeError(f"band_samples must be a positive integer, got {band_samples!r}")
        self.band_samples = int(band_samples)
        self.normal_space, self.y_convention = normal_space, y_convention
        self.padding, self.padding_pixels = padding, padding_pixels
        self.timings: dict[str, float] = {}
        from ..nets.heap import keep_freed_memory

        # the layout's and the bake's arrays reuse freed memory instead of page-faulting afresh (nets.heap)
        self.heap = keep_freed_memory()

        from ..mesh.tangents import tangent_frames

        t0 = time.perf_counter()
        self.unwrapped = mesh.uv is None
        if self.unwrapped:
            from ..mesh.unwrap import unwrap

            options = {"resolution": self.size, **(unwrap_options or {})}
            if layout is not None:
                mesh = layout
            elif layout_cache is not None:
                mesh = layout_cache.unwrap(mesh, **options)[0]
            else:
                mesh = unwrap(mesh, **options)
        from ..mesh.unwrap import split_uv_seams

        had_normals = mesh.vertex_normals is not None
        self.mesh = split_uv_seams(mesh)[0]
        if not had_normals:  # normals shared across seams, or the seams would show in shading
            self.mesh.vertex_normals = welded_vertex_normals(self.mesh)
        self.timings["unwrap"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        self.tangents = np.asarray(tangent_frames(self.mesh), dtype=np.float64)
        self.timings["tangents"] = time.perf_counter() - t0
        n_samples = self.size * self.size * self.supersample**2
        self.cache = (n_samples <= 1 << 23) if cache_texels is None else bool(cache_texels)
        self.texels = None
        if self.cache:
            from ..mesh.texels import rasterize_texels

            t0 = time.perf_counter()
            self.texels = rasterize_texels(self.mesh, self.size, supersample=self.supersample, tangents=self.tangents)
            self.timings["rasterize"] = time.perf_counter() - t0

    def _probe(self, field) -> torch.Tensor:
        """Up to PRECISION_PROBE_POINTS points of the layout (the mesh's vertices and face centres), in
        ``field``'s frame and dtype: where precision "auto" compares bfloat16 with float32."""
        from ..constants import PRECISION_PROBE_POINTS

        pts = np.concatenate([self.mesh.vertices, self.mesh.triangles.mean(axis=1)])
        pts = pts[np.linspace(0, len(pts) - 1, min(len(pts), PRECISION_PROBE_POINTS)).astype(np.int64)]
        return torch.as_tensor(_to_field_frame(pts, self.mesh.frame, field.frame), **_tensor_kwargs(field))

    def bands(self):
        """The texel samples in bands of texel rows: the cached :class:`TexelSet` as one band, or (streaming)
        one rasterised band after another (:func:`neural_bake.mesh.texels.iter_texels`). Their
        concatenation is the full texel set, in the same order either way."""
        if self.texels is not None:
            yield self.texels
            return
        from ..mesh.texels import iter_texels

        yield from iter_texels(self.mesh, self.size, supersample=self.supersample, tangents=self.tangents,
                               max_samples=self.band_samples)

    def bake(
        self,
        sdf: SdfField,
        texture: TextureField | None = None,
        *,
        delta: float | None = None,
        keep_samples: bool | None = None,
        report_samples: int = REPORT_SAMPLES,
        seed: int = 0,
        hybrid=None,
        adaptive: AdaptiveOptions | None = None,
        check_samples: int = ADAPTIVE_CHECK_SAMPLES,
        precision: str = "fp32",
        precision_measure=None,
        texture_at: str = "surface",
    ) -> BakeResult:
        """Bake ∇f (and g) at every texel sample into the maps.

        ``delta`` (default ``sdf.delta``) flags samples with |f| > δ as misses. ``keep_samples`` (default:
        when the texels are cached) returns the per-sample arrays in the result (else they are None).
        Without them the result keeps ``result.sample``: up to ``report_samples`` samples drawn uniformly
        without replacement (seeded by ``seed``, independent of the banding) with their values, for the
        quality report (0: none). Invalid gradients (|∇f| ≈ 0) take the interpolated geometric normal and
        are counted. ``hybrid``: a :class:`~neural_bake.bake.hybrid.HybridFallback` (or any callable
        ``(mesh, texels, normals, valid, evaluated, colors=…) -> (normals, replaced mask[, colors, colours'
        replaced mask])``, ``evaluated`` the band's (M,) mask of the samples the fields were evaluated at,
        ``colors`` their (M, C) neural colours or None; ``values``, ``decide`` and ``side`` as keywords: f at the
        samples, and an adaptive bake's decision points and interpolation cell sides, else None) run on each band
        before encoding: the samples it
        replaces are flagged in ``result.hybrid`` (colours: ``result.hybrid_color``) and counted.

        ``adaptive``: an :class:`~neural_bake.bake.adaptive.AdaptiveOptions` evaluates f, ∇f and g on a coarse
        lattice per chart, refined where interpolation would exceed its tolerances, and interpolates the
        other samples within their chart (:func:`~neural_bake.bake.adaptive.adaptive_evaluate`); None
        evaluates every sample. An adaptive bake evaluates about ``check_samples`` samples (a seeded uniform
        choice) fully as well and states in ``stats["error_control"]`` the angle between its normals and
        those of the full evaluation there (0: no check).

        ``precision``: "fp32", "bf16" or "auto": the networks' hidden GEMMs in bfloat16 where
        :func:`~neural_bake.nets.precision.resolve_precision` says (``precision_measure`` is its injectable
        speed check); ``stats["precision"]`` says what ran and why. A reduced-precision bake runs the same
        sampled check against float32 (``stats["error_control"]["precision_angle_deg"]``: its evaluated
        samples).

        ``texture_at``: where g is read: "surface" (default), at each sample's closest point on the SDF's
        zero set, p − f(p)·∇f(p) with |f| clamped to the colour field's δ, so the colours the texture was
        fitted to on the source surface reach a coarse surface off it; "point", at the sample itself (right
        when the mesh baked is the source, ``--coarse keep``).
        """
        _check_texture_at(texture_at)
        if delta is None:
            delta = sdf.delta
        if delta is not None and not (np.isfinite(delta) and delta > 0):
            raise NeuralBakeError(f"delta must be a positive number, got {delta!r}")
        if isinstance(report_samples, bool) or int(report_samples) != report_samples or report_samples < 0:
            raise NeuralBakeError(f"report_samples must be a non-negative integer, got {report_samples!r}")
        if isinstance(seed, bool) or int(seed) != seed or seed < 0:
            raise NeuralBakeError(f"seed must be a non-negative integer, got {seed!r}")
        if isinstance(check_samples, bool) or int(check_samples) != check_samples or check_samples < 0:
            raise NeuralBakeError(f"check_samples must be a non-negative integer, got {check_samples!r}")
        if adaptive is not None and not isinstance(adaptive, AdaptiveOptions):
            raise NeuralBakeError(f"adaptive must be AdaptiveOptions or None, got {type(adaptive).__name__}")
        control, threads = self._prepare(sdf, texture, adaptive, int(check_samples), seed, precision,
                                         precision_measure, texture_at)
        keep = self.cache if keep_samples is None else bool(keep_samples)
        reservoir = None if keep or report_samples == 0 else _Reservoir(report_samples, seed)
        maps = _MapAccumulator(self.shape, delta, hybrid=hybrid is not None)
        kept = _Kept(texture is not None) if keep else None
        secs = {"rasterize": 0.0, "sdf": 0.0, "texture": 0.0, "maps": 0.0, "hybrid": 0.0, "adaptive": 0.0,
                "check": 0.0}
        t_all = time.perf_counter()
        t_band = time.perf_counter()
        for tx in self.bands():
            if self.texels is None:
                secs["rasterize"] += time.perf_counter() - t_band
            points = np.asarray(tx.points, dtype=np.float64)
            surface = control.face_normals(tx.face)
            early = hybrid.early(self.mesh, tx, textured=texture is not None) \
                if adaptive is not None and hasattr(hybrid, "early") else None
            ev = control.evaluate(tx, points, surface, give_up=early)
            secs["sdf"] += ev["time_sdf"]
            secs["texture"] += ev["time_texture"]
            secs["adaptive"] += ev.get("time_adaptive", 0.0)
            t0 = time.perf_counter()
            control.check(points, ev, surface)
            secs["check"] += time.perf_counter() - t0
            t0 = time.perf_counter()
            normals, valid, values = ev["normals"], ev["valid"], ev["values"]
            if (~valid).any():  # zero gradient: the interpolated geometric normal
                normals[~valid] = tx.normal[~valid]
            band = _Band(normals=normals, valid=valid, values=values, colors=ev.get("colors"))
            if hybrid is not None:
                t1 = time.perf_counter()
                band.neural, band.neural_colors = normals, band.colors
                given = ev.get("given_up") if early is not None else None
                out = hybrid(self.mesh, tx, normals, valid, ev["evaluated"], colors=band.colors, values=values,
                             decide=ev.get("decide"), side=ev.get("side"),
                             **({} if given is None else {"given_up": given}))
                band.normals, band.replaced = out[0], np.asarray(out[1], dtype=bool)
                if len(out) > 2 and out[2] is not None:
                    band.colors, band.colors_replaced = out[2], np.asarray(out[3], dtype=bool)
                if given is not None and given.any():  # not evaluated there: no figure of the fields' own
                    band.neural[given] = np.nan  # the fields' arrays (the hybrid's output is a copy)
                    if band.neural_colors is not None and band.colors is not band.neural_colors:
                        band.neural_colors[given] = np.nan
                secs["hybrid"] += time.perf_counter() - t1
            if self.normal_space == "tangent":
                band.encoded, band.frame_ok = encode_tangent_space(band.normals, tx.tangent, tx.bitangent, tx.normal,
                                                                   self.y_convention)
            else:
                band.encoded, band.frame_ok = band.normals.copy(), np.ones(len(band.normals), dtype=bool)
            maps.add(tx, band)
            if kept is not None:
                kept.add(band)
            if reservoir is not None:
                reservoir.add({**{k: getattr(tx, k) for k in _TEXEL_FIELDS}, "normals": band.normals,
                               "encoded": band.encoded, "valid": valid, "values": values, "colors": band.colors,
                               "replaced": band.replaced, "neural": band.neural})
            secs["maps"] += time.perf_counter() - t0
            t_band = time.perf_counter()
        t0 = time.perf_counter()
        normal_map, albedo = maps.finish()
        # the maps are float32 from here (what the result holds): padding runs on half the bytes
        normal_map = normal_map.astype(np.float32, copy=False)
        albedo = None if albedo is None else albedo.astype(np.float32, copy=False)
        secs["maps"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        if self.padding is not None:
            normal_map = pad_charts(normal_map, maps.covered, method=self.padding, pixels=self.padding_pixels)
            if albedo is not None:
                albedo = pad_charts(albedo, maps.covered, method=self.padding, pixels=self.padding_pixels)
        secs["padding"] = time.perf_counter() - t0
        secs["bake"] = time.perf_counter() - t_all
        stats = {
            **self._settings(),
            **maps.stats(),
            "delta": delta,
            "seconds": {
                **{k: float(v) for k, v in self.timings.items()},
                **{k: float(v) for k, v in secs.items()},
                "rasterize": float(self.timings.get("rasterize", 0.0) + secs["rasterize"]),
            },
            "texels_per_second": float(maps.n_texels / secs["bake"]) if secs["bake"] > 0 else None,
            "threads": threads.as_dict(),
            "heap": self.heap,
            "kernels": {"rasteriser": kernel_status(), "tangent_encoding": encoding_kernel_status(),
                        "padding": padding_kernel_status(),
                        **({"interpolation": adaptive_kernel_status()} if adaptive is not None else {}),
                        **({"classical": classical_kernel_status(), "hybrid_ring": hybrid_kernel_status()}
                           if hybrid is not None else {}),
                        **({"grid_encoding": grid_kernel_status()} if texture is not None
                           and isinstance(getattr(texture, "model", None), GridNet) else {})},
            "field": sdf.name,
            "texture_field": None if texture is None else texture.name,
            "texture_at": None if texture is None else texture_at,
            **control.summary(),
        }
        per_sample = kept.arrays() if kept is not None else {}
        return BakeResult(
            normal_map=normal_map,
            albedo=albedo,
            coverage=maps.covered,
            miss=maps.miss,
            stats=stats,
            sample=None if reservoir is None else reservoir.sample(self.shape, self.supersample),
            hybrid=maps.hybrid_map,
            hybrid_color=maps.hybrid_color_map,
            **{k: per_sample.get(k) for k in _Kept.FIELDS},
        )

    def _prepare(self, sdf, texture, adaptive, check_samples: int, seed: int, precision: str, precision_measure,
                 texture_at: str):
        """The evaluation of a bake: the thread count measured on a slice of its own work, the precision each
        network runs in, and the error control that evaluates (adaptively or not) and checks the fields."""
        from ..nets.threads import choose_threads

        # the threads the bake's evaluations run fastest with on the machine as it is (nets.threads)
        points = self._probe(sdf)
        slice_ = points.repeat(4, 1)  # a slice the size of a few evaluation chunks: threads show what they pay
        threads = choose_threads(lambda: sdf.value_and_normal(slice_), device=points.device)
        probe = points if precision == "auto" else None
        fast_sdf, sdf_prec, sdf_why = sdf.with_precision(precision, measure=precision_measure, probe=probe) \
            if hasattr(sdf, "with_precision") else (sdf, "fp32", "no precision choice")
        fast_tex, tex_prec, tex_why = (None, None, None) if texture is None else (
            texture.with_precision(precision, measure=precision_measure,
                                   probe=None if probe is None else self._probe(texture))
            if hasattr(texture, "with_precision") else (texture, "fp32", "no precision choice"))
        control = _ErrorControl(self, sdf, texture, adaptive, int(check_samples), seed, fast=(fast_sdf, fast_tex),
                                texture_at=texture_at)
        control.precision = {"asked": precision, "sdf": sdf_prec, "sdf_reason": sdf_why, "texture": tex_prec,
                             "texture_reason": tex_why}
        return control, threads

    def _settings(self) -> dict:
        """The map's settings as the bake's stats state them."""
        h, w = self.shape
        return {"size": [h, w], "normal_space": self.normal_space, "y_convention": self.y_convention,
                "supersample": self.supersample}


@dataclass
class _Band:
    """One band's per-sample results on their way into the maps: the normals and colours baked (after the
    hybrid's replacements), what the fields gave (``neural``, ``neural_colors``; hybrid bakes), the
    replacement masks, and the encoded vectors with their frames' validity."""

    normals: np.ndarray
    valid: np.ndarray
    values: np.ndarray
    colors: np.ndarray | None = None
    neural: np.ndarray | None = None
    neural_colors: np.ndarray | None = None
    replaced: np.ndarray | None = None
    colors_replaced: np.ndarray | None = None
    encoded: np.ndarray | None = None
    frame_ok: np.ndarray | None = None


class _MapAccumulator:
    """The maps of a bake summed band by band: weighted sums of the encoded vectors and colours per texel,
    coverage, misses (|f| > δ) and the hybrid's replacements, and the per-sample counts."""

    def __init__(self, shape: tuple[int, int], delta: float | None, *, hybrid: bool):
        h, w = self.shape = shape
        self.delta = delta
        self.vec = np.zeros((h, w, 3), dtype=np.float32)  # weighted sums; float32 keeps 4k maps small
        self.col: np.ndarray | None = None
        self.wsum = np.zeros((h, w), dtype=np.float32)
        self.miss_count = np.zeros((h, w), dtype=np.float32)
        self.hybrid_count = np.zeros((h, w), dtype=np.float32) if hybrid else None
        self.hybrid_color_count: np.ndarray | None = None  # at the first band whose colours the hybrid decided
        self.colour_decided = False
        self.covered = np.zeros((h, w), dtype=bool)
        self.counts = {"samples": 0, "invalid": 0, "singular": 0, "miss": 0, "hybrid": 0}
        self.miss = np.zeros((h, w), dtype=bool)  # set by finish()
        self.hybrid_map: np.ndarray | None = None
        self.hybrid_color_map: np.ndarray | None = None

    def _count_image(self, image: np.ndarray, pix: np.ndarray, rows: tuple[int, int]) -> None:
        """Add to ``image`` (H, W) the number of samples at each pixel of ``pix`` (n, 2), all within ``rows``."""
        w = self.shape[1]
        flat = (np.asarray(pix[:, 0], dtype=np.int64) - rows[0]) * w + np.asarray(pix[:, 1], dtype=np.int64)
        counts = image[rows[0]: rows[1]].reshape(-1)  # a view: the image's rows are contiguous
        if len(flat) and bool((flat[1:] > flat[:-1]).all()):  # each texel once, as rasterised: a scatter
            counts[flat] += 1
        elif len(flat):
            counts += np.bincount(flat, minlength=len(counts))

    def add(self, tx, band: _Band) -> None:
        values = band.values
        miss_s = np.zeros(0, dtype=bool)
        if len(values):
            pix = np.asarray(tx.pixel)
            rows = (int(pix[:, 0].min()), int(pix[:, 0].max()) + 1)
            splat_into(self.vec, self.wsum, band.encoded, pix, tx.weight)
            miss_s = np.abs(values) > self.delta if self.delta is not None else np.zeros(len(values), dtype=bool)
            if miss_s.any():
                self._count_image(self.miss_count, pix[miss_s], rows)
            if band.replaced is not None and band.replaced.any():
                self._count_image(self.hybrid_count, pix[band.replaced], rows)
            if band.colors_replaced is not None and band.colors_replaced.any():
                if self.hybrid_color_count is None:
                    self.hybrid_color_count = np.zeros(self.shape, dtype=np.float32)
                self._count_image(self.hybrid_color_count, pix[band.colors_replaced], rows)
            if band.colors is not None:
                if self.col is None:
                    self.col = np.zeros((*self.shape, band.colors.shape[1]), dtype=np.float32)
                splat_into(self.col, None, band.colors, pix, tx.weight)
            # a band's coverage is the full grid, set in its own rows only
            self.covered[rows[0]: rows[1]] |= np.asarray(tx.coverage, dtype=bool)[rows[0]: rows[1]]
        self.counts["samples"] += len(values)
        self.counts["invalid"] += int((~band.valid).sum())
        self.counts["singular"] += int((~band.frame_ok).sum())
        self.counts["miss"] += int(miss_s.sum())
        self.counts["hybrid"] += 0 if band.replaced is None else int(band.replaced.sum())
        self.colour_decided |= band.colors_replaced is not None

    def finish(self) -> tuple[np.ndarray, np.ndarray | None]:
        """(normal map (H, W, 3) encoded (x + 1)/2, albedo (H, W, C) or None), unpadded; sets the masks."""
        # the average of a texel's unit vectors, renormalised (the weight sum cancels out)
        normal_map = normal_map_from_sums(self.vec)
        albedo = None
        if self.col is not None:
            albedo = self.col
            np.divide(albedo, self.wsum[:, :, None], out=albedo, where=self.wsum[:, :, None] > 0)
        self.miss = self.miss_count > 0
        self.hybrid_map = None if self.hybrid_count is None else self.hybrid_count > 0
        if self.colour_decided:
            self.hybrid_color_map = np.zeros(self.shape, dtype=bool) if self.hybrid_color_count is None \
                else self.hybrid_color_count > 0
        return normal_map, albedo

    @property
    def n_texels(self) -> int:
        return int(self.covered.sum())

    def stats(self) -> dict:
        """Counts over the samples and texels (after :meth:`finish`)."""
        n = self.n_texels
        out = {
            "samples": self.counts["samples"],
            "texels_covered": n,
            "coverage": float(self.covered.mean()),
            "invalid_gradients": self.counts["invalid"],
            "singular_frames": self.counts["singular"],
            "miss_samples": self.counts["miss"],
            "miss_texels": int(self.miss.sum()),
        }
        if self.hybrid_map is not None:
            out.update({"hybrid_samples": self.counts["hybrid"], "hybrid_texels": int(self.hybrid_map.sum()),
                        "hybrid_fraction": float(self.hybrid_map.sum() / max(1, n))})
        if self.hybrid_color_map is not None:
            out.update({"hybrid_color_texels": int(self.hybrid_color_map.sum()),
                        "hybrid_color_fraction": float(self.hybrid_color_map.sum() / max(1, n))})
        return out


class _Kept:
    """The per-sample arrays of a bake that keeps them, band after band, concatenated at the end."""

    FIELDS = ("normals", "encoded", "valid", "values", "colors", "replaced", "neural", "colors_replaced",
              "neural_colors")

    def __init__(self, textured: bool):
        self.textured = textured
        self.parts: dict[str, list] = {k: [] for k in self.FIELDS}

    def add(self, band: _Band) -> None:
        for k in ("normals", "encoded", "valid", "values"):
            self.parts[k].append(getattr(band, k))
        if self.textured:
            self.parts["colors"].append(band.colors)
        if band.replaced is not None:
            self.parts["replaced"].append(band.replaced)
            self.parts["neural"].append(band.neural)
        if band.colors_replaced is not None:
            self.parts["colors_replaced"].append(band.colors_replaced)
            self.parts["neural_colors"].append(band.neural_colors)

    def arrays(self) -> dict[str, np.ndarray | None]:
        # one band (a cached layout): its arrays as they are, not a copy
        return {k: (v[0] if len(v) == 1 else np.concatenate(v)) if v else None for k, v in self.parts.items()}


def bake_texels(
    mesh: Mesh, sdf: SdfField, texture: TextureField | None = None, size: int = 1024, *, delta: float | None = None, **options
) -> BakeResult:
    """One-off bake: ``Baker(mesh, size, **options).bake(sdf, texture, delta=delta)``."""
    return Baker(mesh, size, **options).bake(sdf, texture, delta=delta)
