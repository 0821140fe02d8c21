"""Hybrid bake: every texel where the neural field is not faithful takes the classical mesh-to-mesh normal.

A texel sample is *not faithful* when |f| at the point of the source surface it maps to (where the classical
bake's ray lands) is above ``sdf_tol`` (the field does not put its surface there), when ∇f at the texel
disagrees with the source mesh's normal there by more than ``angle_deg``, or when ∇f is unusable (|∇f| ≈ 0).
Such samples take the classical bake's normal (:func:`~neural_bake.bake.baseline.baseline_bake`), so no
texel of the map is further than ``angle_deg`` from the source mesh's normal.

Colours follow the same rule when a texture is baked and ``color_tol`` or ``color_psnr`` is set: a sample whose
neural colour differs from the source's texture at the same source point by more than ``color_tol``
(CIEDE2000 ΔE, on the sRGB-encoded colours), or whose PSNR against it (the sRGB-encoded RGB, peak 1) is
below ``color_psnr`` dB, takes the source's colour. The PSNR rule holds per sample, so the hybrid colours'
PSNR against the source's at the same points is at least ``color_psnr`` over any set of samples. With
``color_within`` (dB) the colours also stay that close to the classical transfer's PSNR: of the neural colours the
other rules keep, the closest to the source's (compared as the map stores them, quantised to ``color_bits``) are
kept, closest first, while their summed squared difference stays within the share of the map's quantisation
noise (a step² / 12 a channel, a transfer's error into such a map unless the texture's own values land on the
map's) that ``color_within`` allows, 10^(dB/10) − 1; the rest take the source's colour. At 0 (the bake's
default) a neural colour stays only where the map stores the same value as the transfer's, so the decided
samples' colours are the classical transfer's to the map's precision. The decision uses the same rays and the same samples as the
normals' (a sample near an unfaithful colour is decided too).

Where the decision is made (``decide``): at every sample ("all": a ray cast and a forward pass of f per
sample, a second bake's cost), or on the adaptive lattice ("lattice", the default): at the samples the bake
evaluated its fields at (the lattice nodes, borders, seams; of an adaptive bake, one that says ``side``, those
whose texel's row and column are multiples of ``stride``, which at one sample per texel every lattice node of a
cell of side 4 and up is), and at the other samples within ``reach`` sample-grid positions of one found
unfaithful (every sample of an interpolation cell lies that close to its nodes); when the bake says in which
cell side each sample was interpolated (``side``), within that side instead, so a sample of a side-4 cell is
decided only when an unfaithful node lies within 4 positions, and an evaluated sample between the stride's
within ``stride`` positions (where the fields vary too fast for any cell, an unfaithful region holds several of
the stride's samples). The other samples keep ∇f as their cell's faithful nodes do; a seeded uniform subsample of them is
decided in full as a check (``summary()["lattice_check"]``: how many of those the lattice rule would have
missed; they are replaced too).

f at the source point p of a sample the bake evaluated (where f(x) and ∇f(x) at its texel point x are known)
is first estimated to first order, ``f(x) + n(x)·(p − x)`` with n the unit gradient: where the ray is shorter
than ``sdf_tol / 2`` and the estimate is under ``sdf_tol / 2`` the sample is faithful as far as f goes, and
the network's forward pass runs only at the others (a first-order error above ``sdf_tol / 2`` over such a
distance would need second derivatives of f far beyond a fitted SDF's: docs/findings.md, "Baking"). The
interpolated samples the ring decides are estimated likewise from the bake's interpolated f(x) and ∇f(x), with
the estimate under ``sdf_tol / 4`` (the other quarter is room for the interpolation's error, which the bake
holds within its value tolerance). A seeded uniform subsample of the estimated samples is evaluated anyway as a
check (``summary()["estimate_check"]``: how many the estimate would have called faithful wrongly; they are
decided on the evaluated f).

An adaptive bake asks for the decision while it refines (:meth:`HybridFallback.early`): at the nodes of every
cell that fails its interpolation test. A cell with at least ``give_up_nodes`` of its 9 nodes unfaithful
(:data:`~neural_bake.constants.HYBRID_GIVE_UP_NODES`) is *given up* instead of refined: its samples take the
classical normal without being evaluated or decided (their colours, interpolated from the nodes, go through the
colour rules as any other). Where the field is unfaithful the bake spends no evaluations on samples that would
take the classical normal anyway; a given-up cell's few faithful samples take it too (the classical normal is the
source's, so no texel gets further from it). The reports' figures of the fields alone leave those samples out.
In a bake without colours, a failing cell no wider than ``detail_side``
(:data:`~neural_bake.constants.HYBRID_DETAIL_SIDE`) whose 9 nodes' classical rays all hit the source is given up too (a *detail* cell; its nodes take the classical
normal as well): the fields vary faster than the lattice holds there, so every sample would be evaluated one by one,
at several times a ray's cost, for a normal further from the source's than the rays find. Two more rules, in such a
bake, save the evaluations that would only have found the same: a cell no wider than ``detail_side`` whose nodes'
rays all hit a source whose normals fail the cell's interpolation test is given up before ∇f is evaluated at its
nodes (*the source's detail*: the classical normal is the source's, and a field cannot follow detail its source has
between the nodes better than the rays do; the nodes evaluated already take the classical normal too), and a sample
no cell holds (chart borders, border samples) within ``detail_side / 2`` positions of a given-up sample takes the
classical normal where its rays hit (*the detail rim*). Where f is not evaluated the bake takes the source's signed
distance found by the rays, to first order, for its miss test.

:class:`HybridFallback` is what :meth:`neural_bake.bake.baker.Baker.bake` calls per band of texel samples.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

from types import SimpleNamespace
from typing import NamedTuple

from ..constants import (ADAPTIVE_LATTICE, HYBRID_ANGLE_DEG, HYBRID_CHECK_FRACTION, HYBRID_CHECK_MIN,
                         HYBRID_DETAIL_SIDE, HYBRID_GIVE_UP_NODES, HYBRID_SDF_TOL, HYBRID_STRIDE)
from ..errors import NeuralBakeError
from ..nets.native import Kernel, threads
from ..types import Mesh

__all__ = ["HybridFallback", "HybridBand", "unfaithful", "colour_difference", "colour_psnr", "colour_budget",
           "HYBRID_DECISIONS", "kernel_status", "ENV_SWITCH"]

#: 0/off/false: the numpy ring even where the C kernel (hybrid.c) builds (A/B checks).
ENV_SWITCH = "NEURAL_BAKE_NATIVE_HYBRID"


def _declare(lib) -> None:
    p, i64 = ctypes.c_void_p, ctypes.c_int64
    lib.nb_near.argtypes = [p, p, i64, i64, p, i64, p, i64, p, i64, i64, p, i64]
    lib.nb_near.restype = ctypes.c_int
    f64 = ctypes.c_double
    lib.nb_decide.argtypes = [p, i64, p, p, p, f64, p, p, p, p, p, f64, f64, p, p, p, p, i64]
    lib.nb_decide.restype = None
    lib.nb_keep_rays.argtypes = [p, i64, p, p, p, p, p, p, p, p, p, i64]
    lib.nb_keep_rays.restype = None


#: The C kernel (hybrid.c, :class:`neural_bake.nets.native.Kernel`; the candidates on torch's OpenMP team where it
#: shares it); numpy where it does not build.
KERNEL = Kernel(Path(__file__).with_name("hybrid.c"), switch=ENV_SWITCH, declare=_declare, openmp=True)


def kernel_status() -> str:
    """Which ring search and per-sample rules of the hybrid run here: the C kernel (and its file), or why numpy
    does."""
    return KERNEL.status()

#: Where a hybrid bake decides: at every sample, or on the adaptive lattice (module docstring).
HYBRID_DECISIONS = ("lattice", "all")


def unfaithful(f_surface: np.ndarray, neural: np.ndarray, source: np.ndarray, valid: np.ndarray, *,
               sdf_tol: float = HYBRID_SDF_TOL, angle_deg: float = HYBRID_ANGLE_DEG) -> dict[str, np.ndarray]:
    """Which samples the neural field does not represent faithfully.

    - ``f_surface``: (M,) f at the source-surface point of each sample (unit frame distances).
    - ``neural``: (M, 3) unit ∇f at the samples; ``source``: (M, 3) unit source-mesh normals there.
    - ``valid``: (M,) bool, ∇f was usable.

    Returns ``{"mask": (M,) bool (any reason), "sdf": |f| > sdf_tol, "angle": angle > angle_deg,
    "invalid": ~valid}``; a non-finite f counts as above the tolerance.
    """
    far = far_from_surface(f_surface, sdf_tol)
    cos = np.einsum("ij,ij->i", np.asarray(neural, dtype=np.float64), np.asarray(source, dtype=np.float64))
    off = ~(cos >= np.cos(np.radians(angle_deg)))
    invalid = ~np.asarray(valid, dtype=bool)
    return {"mask": far | off | invalid, "sdf": far, "angle": off & ~invalid, "invalid": invalid}


def far_from_surface(f_surface: np.ndarray, sdf_tol: float) -> np.ndarray:
    """(M,) bool: |f| at the source-surface points above ``sdf_tol`` (a non-finite f counts as above)."""
    return ~(np.abs(np.asarray(f_surface, dtype=np.float64)) <= sdf_tol)


def colour_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """CIEDE2000 ΔE (M,) between linear RGB(A) colours ``a`` and ``b`` (M, ≥3) (alpha ignored), through
    their sRGB encodings (scikit-image's ``rgb2lab``, D65); about 1 is a just noticeable difference."""
    from skimage.color import deltaE_ciede2000, rgb2lab

    from ..io.colour import linear_to_srgb

    if len(a) == 0:
        return np.zeros(0)
    lab = [rgb2lab(linear_to_srgb(np.asarray(c, dtype=np.float64)[:, :3])) for c in (a, b)]
    return np.asarray(deltaE_ciede2000(lab[0], lab[1]), dtype=np.float64)


def colour_psnr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """PSNR (M,) in dB of linear RGB(A) colours ``a`` against ``b`` (M, ≥3) (alpha ignored), per colour: the mean
    squared difference of the sRGB-encoded RGB (peak 1); inf for equal colours."""
    from ..io.colour import linear_to_srgb

    if len(a) == 0:
        return np.zeros(0)
    d = linear_to_srgb(np.clip(np.asarray(a, dtype=np.float64)[:, :3], 0.0, 1.0)) \
        - linear_to_srgb(np.clip(np.asarray(b, dtype=np.float64)[:, :3], 0.0, 1.0))
    mse = np.einsum("ij,ij->i", d, d) / 3.0
    with np.errstate(divide="ignore"):
        return -10.0 * np.log10(mse)


def colour_budget(a: np.ndarray, b: np.ndarray, within_db: float, bits: int = 8,
                  replaced: np.ndarray | None = None) -> np.ndarray:
    """Which of the linear RGB(A) colours ``a`` (M, ≥3) to replace by ``b`` so the rest stay within ``within_db``
    of a classical transfer into a ``bits``-bit map: (M,) bool. Both are compared as the map stores them (sRGB,
    quantised to ``bits``); the colours with the smallest squared difference are kept, smallest first, while
    the sum stays within M × (10^(within_db/10) − 1) × step² / 12 (the quantisation noise a channel, which a
    transfer into the map errs by unless the texture's values land on the map's: then any kept difference
    costs more than ``within_db``; 0 keeps only the colours the map stores as ``b``'s). ``replaced`` (M,) bool: colours another rule replaces already
    (they take ``b``, a zero difference, and are returned as replaced)."""
    from ..io.colour import linear_to_srgb

    m = len(a)
    out = np.zeros(m, dtype=bool) if replaced is None else np.asarray(replaced, dtype=bool).copy()
    if m == 0:
        return out
    top = float(2 ** int(bits) - 1)
    q = [np.rint(linear_to_srgb(np.clip(np.asarray(c, dtype=np.float64)[:, :3], 0.0, 1.0)) * top) for c in (a, b)]
    d2 = np.einsum("ij,ij->i", q[0] - q[1], q[0] - q[1]) / (3.0 * top * top)
    d2[out] = 0.0
    budget = m * (10.0 ** (float(within_db) / 10.0) - 1.0) / (12.0 * top * top)
    order = np.argsort(d2, kind="stable")
    out[order[np.cumsum(d2[order]) > budget]] = True
    return out


class HybridBand(NamedTuple):
    """What :class:`HybridFallback` gives for one band: the normals (M, 3) with the unfaithful samples
    replaced and their mask (M,), and the colours (M, C) with the replaced ones and their mask (None when no
    colours were decided)."""

    normals: np.ndarray
    replaced: np.ndarray
    colors: np.ndarray | None = None
    colors_replaced: np.ndarray | None = None


class HybridFallback:
    """Per band of texel samples: the classical bake, f at its source points, and the replacement.

    - ``fine``: the source mesh (unit frame), the classical bake's target and the normals' reference.
    - ``sdf``: the SDF field the neural normals come from (its ``frame``, if any, is honoured).
    - ``sdf_tol``, ``angle_deg``: the two thresholds (:data:`~neural_bake.constants.HYBRID_SDF_TOL`,
      :data:`~neural_bake.constants.HYBRID_ANGLE_DEG`).
    - ``cage``: the classical bake's ray distance (unit frame; None: its default).
    - ``keep_baseline``: keep each band's classical bake over every sample (``self.baselines``), e.g. for
      the quality report of a bake whose texels are cached, so it is not cast twice (every sample is then
      ray-cast, f still only where the decision needs it).
    - ``decide``: "lattice" (default) or "all" (:data:`HYBRID_DECISIONS`, module docstring); ``reach``:
      the lattice rule's neighbourhood in sample-grid positions (default: the adaptive lattice's side);
      ``stride``: of the evaluated samples it decides first (:data:`~neural_bake.constants.HYBRID_STRIDE`).
    - ``seed``: of the lattice rule's check subsample.
    - ``color_tol``: ΔE (CIEDE2000) above which a neural colour takes the source texture's; ``color_psnr``: the
      least PSNR (dB) a neural colour keeps against the source's; ``color_within``: the dB the colours may lose
      against a classical transfer into a ``color_bits``-bit map (:func:`colour_budget`) (all None: colours are
      not decided). Need ``fine`` with UVs and a texture.
    - ``give_up_nodes``: of a failing cell's 9 nodes, how many unfaithful ones give it up (module docstring; 10:
      never); ``detail_side``: the widest failing cell given up where the classical rays hit at all its nodes
      (module docstring; 0: never).

    Called as ``fallback(coarse, texels, normals, valid, evaluated, colors=None)`` with the coarse mesh the
    texels lie on, a :class:`~neural_bake.mesh.texels.TexelSet` band, its (M, 3) unit ∇f, (M,) valid mask,
    (M,) mask of the samples the fields were evaluated at (None: all of them) and its (M, C) linear neural
    colours (None: no texture baked); ``values`` (f at the samples), ``decide`` (the adaptive bake's decision
    points) and ``side`` (its interpolation cell sides, :func:`~neural_bake.bake.adaptive.adaptive_evaluate`)
    are optional keywords, as is ``given_up`` (the adaptive bake's given-up samples, after :meth:`early`); returns a
    :class:`HybridBand`. ``self.counts`` sums the samples per
    reason over the calls (f at the source is tested, and counted, only where the angle and validity rules keep
    the sample); ``self.f_abs`` keeps |f| at the source points of those tested samples.
    """

    def __init__(self, fine: Mesh, sdf, *, sdf_tol: float = HYBRID_SDF_TOL, angle_deg: float = HYBRID_ANGLE_DEG,
                 cage: float | None = None, keep_baseline: bool = False, chunk_size: int = 1 << 16,
                 decide: str = "lattice", reach: int = ADAPTIVE_LATTICE, stride: int = HYBRID_STRIDE, seed: int = 0,
                 color_tol: float | None = None, color_psnr: float | None = None,
                 color_within: float | None = None, color_bits: int = 8, give_up_nodes: int = HYBRID_GIVE_UP_NODES,
                 detail_side: int = HYBRID_DETAIL_SIDE):
        if not (np.isfinite(sdf_tol) and sdf_tol > 0):
            raise NeuralBakeError(f"hybrid sdf_tol must be a positive distance, got {sdf_tol!r}", parameter="sdf_tol")
        if not (np.isfinite(angle_deg) and 0 < angle_deg <= 180):
            raise NeuralBakeError(f"hybrid angle_deg must be in (0, 180] degrees, got {angle_deg!r}",
                                  parameter="angle_deg")
        if decide not in HYBRID_DECISIONS:
            raise NeuralBakeError(f"hybrid decide must be one of {', '.join(HYBRID_DECISIONS)}, got {decide!r}",
                                  parameter="decide")
        if isinstance(reach, bool) or int(reach) != reach or reach < 1:
            raise NeuralBakeError(f"hybrid reach must be a positive integer, got {reach!r}", parameter="reach")
        if isinstance(stride, bool) or int(stride) != stride or not 1 <= stride <= reach:
            raise NeuralBakeError(f"hybrid stride must be an integer from 1 to reach ({reach}), got {stride!r}",
                                  parameter="stride")
        if color_tol is not None and not (color_tol > 0):  # NaN and non-positive
            raise NeuralBakeError(f"hybrid color_tol must be a positive ΔE, got {color_tol!r}", parameter="color_tol")
        if color_psnr is not None and not (np.isfinite(color_psnr) and color_psnr > 0):
            raise NeuralBakeError(f"hybrid color_psnr must be a positive number of dB, got {color_psnr!r}",
                                  parameter="color_psnr")
        if color_within is not None and not (np.isfinite(color_within) and color_within >= 0):
            raise NeuralBakeError(f"hybrid color_within must be a number of dB ≥ 0, got {color_within!r}",
                                  parameter="color_within")
        if isinstance(give_up_nodes, bool) or int(give_up_nodes) != give_up_nodes or not 1 <= give_up_nodes <= 10:
            raise NeuralBakeError(f"hybrid give_up_nodes must be an integer from 1 to 9 (10: never), got {give_up_nodes!r}",
                                  parameter="give_up_nodes")
        if isinstance(detail_side, bool) or int(detail_side) != detail_side or detail_side < 0:
            raise NeuralBakeError(f"hybrid detail_side must be a non-negative integer (0: never), got {detail_side!r}",
                                  parameter="detail_side")
        if color_bits not in (8, 16):
            raise NeuralBakeError(f"hybrid color_bits must be 8 or 16, got {color_bits!r}", parameter="color_bits")
        rules = {"color_tol": color_tol, "color_psnr": color_psnr, "color_within": color_within}
        given = [k for k, v in rules.items() if v is not None]
        if given and (fine.uv is None or fine.texture is None):
            raise NeuralBakeError(f"{fine.name}: hybrid colours need a source mesh with UVs and a texture",
                                  parameter=given[0])
        from ..geometry import vertex_normals
        from .baseline import raycasting_scene

        self.fine, self.sdf, self.sdf_tol, self.angle_deg = fine, sdf, float(sdf_tol), float(angle_deg)
        self.cage, self.keep_baseline, self.chunk_size = cage, bool(keep_baseline), int(chunk_size)
        self.decide, self.reach, self.stride, self.seed = decide, int(reach), int(stride), int(seed)
        self.color_tol = None if color_tol is None else float(color_tol)
        self.color_psnr = None if color_psnr is None else float(color_psnr)
        self.color_within = None if color_within is None else float(color_within)
        self.color_bits = int(color_bits)
        self.give_up_nodes = int(give_up_nodes)
        self.detail_side = int(detail_side)
        self._early: SimpleNamespace | None = None
        self._rays: SimpleNamespace | None = None  # the band's kept rays (:meth:`_cached_rays`)
        self.decides_colours = bool(given)
        self.scene = raycasting_scene(fine)
        self.fine_normals = vertex_normals(fine)  # shared by every band's classical shading
        self.baselines: list[dict] = []
        self.counts = {"samples": 0, "replaced": 0, "sdf": 0, "angle": 0, "invalid": 0, "given_up": 0, "decided": 0,
                       "detail_nodes": 0, "detail_cells": 0, "color_replaced": 0, "color_within_replaced": 0}
        self.check = {"samples": 0, "missed": 0}
        self.estimate = {"estimated": 0, "samples": 0, "missed": 0}
        self.f_abs: list[np.ndarray] = []
        self.seconds = 0.0
        self._seen = 0

    def field_values(self, points: np.ndarray) -> np.ndarray:
        """f (M,) at ``points`` (M, 3) in the fine mesh's unit frame (converted to the field's frame): the
        field's forward pass alone (:meth:`~neural_bake.fields.sdf.SdfField.value`), no gradient."""
        import torch

        from .baker import _tensor_kwargs, _to_field_frame

        pts = _to_field_frame(np.asarray(points, dtype=np.float64), self.fine.frame, self.sdf.frame)
        kw = _tensor_kwargs(self.sdf)
        out = np.empty(len(pts))
        for s in range(0, len(pts), self.chunk_size):
            out[s: s + self.chunk_size] = self.sdf.value(torch.as_tensor(pts[s: s + self.chunk_size], **kw)).double().cpu().numpy()
        return out

    def _source_values(self, coarse: Mesh, texels, idx: np.ndarray, source_points: np.ndarray,
                       normals: np.ndarray, values: np.ndarray | None, valid: np.ndarray,
                       share: float = 0.5, estimate: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """f at the source points of the samples ``idx``: estimated to first order from ``values`` (f at
        the texel points, None: not known) and the unit ``normals`` where that is safe (module docstring; the
        estimate must stay under ``share`` · sdf_tol), the field's forward pass elsewhere and at a seeded check
        subsample of the estimated ones. ``estimate``: (where safe, the estimate), as :meth:`_rules_native`
        gives them, instead of computing them here."""
        from .baker import _to_field_frame

        f = np.empty(len(idx))
        near = np.zeros(len(idx), dtype=bool)
        check = np.zeros(len(idx), dtype=bool)
        if estimate is not None:
            near, est = np.asarray(estimate[0], dtype=bool), estimate[1]
            check[near] = self._check_mask(idx[near], 2)
            f[near] = est[near]
        elif values is not None:
            x = _to_field_frame(np.asarray(texels.points)[idx], coarse.frame, self.sdf.frame)
            p = _to_field_frame(np.asarray(source_points, dtype=np.float64), self.fine.frame, self.sdf.frame)
            step = p - x
            dist = np.sqrt(np.einsum("ij,ij->i", step, step))
            est = values[idx] + np.einsum("ij,ij->i", normals[idx], step)
            near = valid[idx] & np.isfinite(est) & (dist < 0.5 * self.sdf_tol) & (np.abs(est) < share * self.sdf_tol)
            check[near] = self._check_mask(idx[near], 2)
            f[near] = est[near]
        exact = ~near | check
        if exact.any():
            f[exact] = self.field_values(np.asarray(source_points)[exact])
        self.estimate["estimated"] += int((near & ~check).sum())
        self.estimate["samples"] += int(check.sum())
        self.estimate["missed"] += int((check & ~(np.abs(f) <= self.sdf_tol)).sum())
        return f

    def _rules_native(self, lib, coarse: Mesh, texels, idx: np.ndarray, normals: np.ndarray, valid: np.ndarray,
                      values: np.ndarray | None, b: dict, share: float) -> tuple[np.ndarray, ...]:
        """(off, invalid, near, est) (n,) of the samples ``idx`` by the C kernel (hybrid.c ``nb_decide``): the angle
        and validity rules (:func:`unfaithful`) and, where neither replaces a sample, :meth:`_source_values`'
        first-order estimate of f at its source point (``b["points"]``) and whether it is safe."""
        def frame(mesh_frame) -> np.ndarray:  # _to_field_frame's map: (y / s_m + c_m − c_f) · s_f, or none
            f = self.sdf.frame
            if f is None or f == mesh_frame:
                return np.zeros(9)
            return np.array([1.0, mesh_frame.scale, *mesh_frame.center, f.scale, *f.center], dtype=np.float64)

        n = len(idx)
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        nrm = np.ascontiguousarray(normals, dtype=np.float64)
        ok = np.ascontiguousarray(valid, dtype=bool).view(np.uint8)
        source_n = np.ascontiguousarray(b["normals"], dtype=np.float64)
        source_p = np.ascontiguousarray(b["points"], dtype=np.float64)
        pts = np.ascontiguousarray(texels.points, dtype=np.float64)
        val = None if values is None else np.ascontiguousarray(values, dtype=np.float64)
        to_x, to_p = frame(coarse.frame), frame(self.fine.frame)
        off, invalid, near = (np.zeros(n, dtype=np.uint8) for _ in range(3))
        est = np.empty(n)
        lib.nb_decide(idx.ctypes.data, n, nrm.ctypes.data, ok.ctypes.data, source_n.ctypes.data,
                      float(np.cos(np.radians(self.angle_deg))), pts.ctypes.data, None if val is None else val.ctypes.data,
                      source_p.ctypes.data, to_x.ctypes.data, to_p.ctypes.data, 0.5 * self.sdf_tol, share * self.sdf_tol,
                      off.ctypes.data, invalid.ctypes.data, near.ctypes.data, est.ctypes.data, threads())
        return off.view(bool), invalid.view(bool), near.view(bool), est

    def _baseline(self, coarse: Mesh, texels, idx: np.ndarray, base: dict | None = None) -> dict:
        """The classical bake of the samples ``idx`` of the band ``texels``: their rows of ``base`` (the band's kept
        classical bake) where given, else rays (or each sample's own face and barycentrics on a bake onto the
        source)."""
        if base is not None:
            return {k: None if base[k] is None else base[k][idx] for k in ("normals", "points", "colors", "hit")}
        rays = self._rays
        if rays is not None and rays.texels is texels:  # the band's rays kept (a bake of normals alone): cast once
            self._cast(rays, coarse, texels, idx[~rays.done[idx]])
            return {"normals": rays.normals[idx], "points": rays.points[idx], "colors": None, "hit": rays.hit[idx]}
        return self._cast_rays(coarse, texels, idx)

    def _cast_rays(self, coarse: Mesh, texels, idx: np.ndarray) -> dict:
        """:func:`~neural_bake.bake.baseline.baseline_bake` of the samples ``idx`` of the band ``texels``."""
        from .baseline import baseline_bake, same_surface

        own = same_surface(coarse, self.fine)
        sub = texels if own else SimpleNamespace(points=texels.points, normal=texels.normal, face=None, bary=None)
        return baseline_bake(coarse, self.fine, sub, cage=self.cage, scene=self.scene, fine_normals=self.fine_normals,
                             index=idx, colors=self.decides_colours)

    def _decide(self, coarse: Mesh, texels, idx: np.ndarray, normals: np.ndarray, valid: np.ndarray,
                base: dict | None, colors: np.ndarray | None = None,
                values: np.ndarray | None = None, share: float = 0.5) -> tuple[dict, dict]:
        """(reasons, classical bake) of the samples ``idx``: rays cast unless ``base`` holds the band's.
        With ``colors`` (the band's neural colours), ``reasons["color"]`` holds the colours found unfaithful;
        with ``values`` (f at the texel points), f at the source is estimated where safe (``share``:
        :meth:`_source_values`)."""
        b = self._baseline(coarse, texels, idx, base)
        # the angle and validity rules first: f at the source is needed only where neither replaces the sample
        lib = KERNEL.lib()
        estimate = None
        if lib is not None:
            off, invalid, near, est = self._rules_native(lib, coarse, texels, idx, normals, valid, values, b, share)
            why = {"mask": off | invalid, "sdf": np.zeros(len(idx), dtype=bool), "angle": off & ~invalid,
                   "invalid": invalid}
        else:
            why = unfaithful(np.zeros(len(idx)), normals[idx], b["normals"], valid[idx], sdf_tol=self.sdf_tol,
                             angle_deg=self.angle_deg)
        tested = np.flatnonzero(~why["mask"])
        if lib is not None and values is not None:
            estimate = (near[tested], est[tested])
        f_surf = self._source_values(coarse, texels, idx[tested], b["points"][tested], normals, values, valid, share,
                                     estimate) if len(tested) else np.zeros(0)
        self.f_abs.append(np.abs(f_surf))
        far = np.zeros(len(idx), dtype=bool)
        far[tested] = far_from_surface(f_surf, self.sdf_tol)
        why["sdf"], why["mask"] = far, why["mask"] | far
        if colors is not None:
            why["color"] = self._colour_rules(colors[idx], b["colors"])
        return why, b

    def _colour_rules(self, neural: np.ndarray, source: np.ndarray) -> np.ndarray:
        """(n,) bool: the ``neural`` colours (n, C) the colour rules replace by the ``source``'s (n, C)."""
        bad = np.zeros(len(neural), dtype=bool)
        # a budget of 0 replaces every colour the map would store differently, which takes in every colour
        # more than ΔE color_tol off: the CIEDE2000 pass would decide nothing more
        if self.color_tol is not None and self.color_within != 0:
            bad |= colour_difference(neural, source) > self.color_tol
        if self.color_psnr is not None:
            bad |= ~(colour_psnr(neural, source) >= self.color_psnr)
        if self.color_within is not None:
            within = colour_budget(neural, source, self.color_within, self.color_bits, replaced=bad)
            self.counts["color_within_replaced"] += int((within & ~bad).sum())
            bad = within
        return bad

    def _near(self, texels, seeds: np.ndarray, candidates: np.ndarray, side: np.ndarray | None = None) -> np.ndarray:
        """Which ``candidates`` (indices) lie within ``reach`` sample-grid positions of a ``seeds`` sample; with
        ``side`` ((M,) the band's interpolation cell sides), within their own cell's side (at most ``reach``).
        Counted in texels (a reach of k positions is ⌈k / s⌉ + 1 texels at supersample s). Blocks of the
        largest reach in texels first rule out the candidates with no seed in their own or a neighbouring block;
        the others are counted exactly from the seeds' integral image, four lookups a candidate. By the C kernel
        (hybrid.c: every candidate looked up) where it builds."""
        if not len(seeds) or not len(candidates):
            return np.zeros(len(candidates), dtype=bool)
        from .adaptive import _integral

        pix = np.asarray(texels.pixel)
        r0 = int(pix[:, 0].min())
        h = int(pix[:, 0].max()) - r0 + 1
        w = int(texels.size[1])
        s = max(1, int(getattr(texels, "supersample", 1)))
        lib = KERNEL.lib()
        if lib is not None:
            found = np.zeros(len(candidates), dtype=np.uint8)
            row = np.ascontiguousarray(pix[:, 0], dtype=np.int64) - r0
            col = np.ascontiguousarray(pix[:, 1], dtype=np.int64)
            own = None if side is None else np.ascontiguousarray(side, dtype=np.int16)
            seeds, candidates = (np.ascontiguousarray(a, dtype=np.int64) for a in (seeds, candidates))
            if lib.nb_near(row.ctypes.data, col.ctypes.data, h, w, seeds.ctypes.data, len(seeds),
                           candidates.ctypes.data, len(candidates), None if own is None else own.ctypes.data,
                           self.reach, s, found.ctypes.data, threads()):
                return found.view(bool)
        block = -(-self.reach // s) + 1  # the largest reach in texels: a seed that near is in a neighbouring block
        rows, cols = pix[:, 0] - r0, pix[:, 1]
        seed_blocks = np.zeros((-(-h // block) + 2, -(-w // block) + 2), dtype=bool)  # a ring of empty blocks
        seed_blocks[rows[seeds] // block + 1, cols[seeds] // block + 1] = True
        near_blocks = seed_blocks.copy()
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if dr or dc:
                    near_blocks[1:-1, 1:-1] |= seed_blocks[1 + dr: seed_blocks.shape[0] - 1 + dr,
                                                           1 + dc: seed_blocks.shape[1] - 1 + dc]
        row, col = rows[candidates], cols[candidates]
        out = near_blocks[row // block + 1, col // block + 1]
        maybe = np.flatnonzero(out)
        if not len(maybe):
            return out
        seed_image = np.zeros((h, w), dtype=bool)
        seed_image[rows[seeds], cols[seeds]] = True
        counts = _integral(seed_image)
        reach = np.full(len(maybe), self.reach, dtype=np.int64)
        if side is not None:
            own = np.asarray(side, dtype=np.int64)[candidates[maybe]]
            reach = np.where(own > 0, np.minimum(own, self.reach), self.reach)
        reach = -(-reach // s) + 1
        row, col = row[maybe], col[maybe]
        top, bottom = np.maximum(row - reach, 0), np.minimum(row + reach, h - 1) + 1
        left, right = np.maximum(col - reach, 0), np.minimum(col + reach, w - 1) + 1
        out[maybe] = (counts[bottom, right] - counts[top, right] - counts[bottom, left] + counts[top, left]) > 0
        return out

    def _check_mask(self, candidates: np.ndarray, stream: int) -> np.ndarray:
        """(len(candidates),) bool: a seeded uniform choice among ``candidates`` (indices into the band) of
        :data:`~neural_bake.constants.HYBRID_CHECK_FRACTION` of them, at least
        :data:`~neural_bake.constants.HYBRID_CHECK_MIN`; ``stream`` keeps the checks' choices apart."""
        from .baker import keys_below, sample_keys

        if not len(candidates):
            return np.zeros(0, dtype=bool)
        return keys_below(sample_keys(self._seen + candidates, self.seed + stream),
                          max(HYBRID_CHECK_FRACTION, min(1.0, HYBRID_CHECK_MIN / len(candidates))))

    def _check_pick(self, candidates: np.ndarray) -> np.ndarray:
        """The lattice rule's check: :meth:`_check_mask`'s choice among ``candidates``."""
        return candidates[self._check_mask(candidates, 1)]

    def early(self, coarse: Mesh, texels, *, textured: bool = False):
        """The decision at evaluated samples while an adaptive bake refines the band ``texels`` of ``coarse``: a
        callable ``(cells' nodes (P, 9) sample indices, normals (M, 3), valid (M,), values (M,), colours (M, C) or
        None: the band's fields so far, side=the cells' side) → (P,) bool``, True for the cells with at least
        ``give_up_nodes`` nodes whose normal is unfaithful by the rules of :meth:`__call__` (each sample decided
        once, its colour too) and, no wider than ``detail_side`` in a bake without colours, those whose nodes'
        classical rays all hit (their nodes take the classical normal too), which
        :func:`~neural_bake.bake.adaptive.adaptive_evaluate` gives up; the next call for the band takes those
        decisions and its ``given_up`` samples. None where it does not apply: deciding "all", ``give_up_nodes`` 10
        and ``detail_side`` 0, or colours baked that it does not decide (a given-up cell's colours would stay
        interpolated). A kept classical bake (``keep_baseline``) is cast here, over the whole band.

        In a bake without colours with ``detail_side`` > 0 the callable also carries ``classical`` ((sample indices
        (n,)) → the band's rays: (M,) ``hit``, (M, 3) unit ``normals`` and (M,) ``values``, the source's signed distance,
        valid at those samples; each sample cast once, :meth:`_cached_rays`), ``detail_side`` and ``rim_reach`` (half of it), with
        which the bake gives up cells on the source's own detail and the samples next to given-up ones (module
        docstring)."""
        from .baseline import baseline_bake

        self._early = self._rays = None
        if self.decide != "lattice" or (self.give_up_nodes > 9 and not self.detail_side) \
                or (textured and not self.decides_colours):
            return None
        m = int(texels.n_samples)
        base = baseline_bake(coarse, self.fine, texels, cage=self.cage, scene=self.scene,
                             fine_normals=self.fine_normals) if self.keep_baseline else None
        state = SimpleNamespace(texels=texels, decided=np.zeros(m, bool), bad=np.zeros(m, bool), hit=np.zeros(m, bool),
                                detail=np.zeros(m, bool), parts=[], base=base)
        self._early = state

        def give_up(nodes, normals, valid, values, colors, side=None):
            nodes = np.asarray(nodes, dtype=np.int64)
            fresh = np.unique(nodes[~state.decided[nodes]])
            if fresh.size:
                col = np.asarray(colors, dtype=np.float64) if colors is not None and self.decides_colours else None
                why, b = self._decide(coarse, texels, fresh, np.asarray(normals, dtype=np.float64),
                                      np.asarray(valid, dtype=bool), state.base, col,
                                      values=np.asarray(values, dtype=np.float64))
                state.parts.append((fresh, why, b))
                state.decided[fresh] = True
                state.bad[fresh] = why["mask"]  # the normal's rules: a cell is given up where the SDF is unfaithful
                state.hit[fresh] = b["hit"]
            out = state.bad[nodes].sum(axis=1) >= self.give_up_nodes
            # too fine for the lattice: the source's normals (a normal-only bake: with colours a cell may fail for
            # its colours alone, and its faithful normals would be replaced)
            if side is not None and side <= self.detail_side and colors is None:
                detail = ~out & state.hit[nodes].all(axis=1)
                state.detail[nodes[detail].reshape(-1)] = True
                self.counts["detail_cells"] += int(detail.sum())
                out |= detail
            return out

        if self.detail_side and not textured:  # the source's detail (adaptive_evaluate): its rays, cached
            give_up.classical = self._cached_rays(state, coarse, texels)  # type: ignore[attr-defined]
            give_up.detail_side = self.detail_side  # type: ignore[attr-defined]
            give_up.rim_reach = max(1, self.detail_side // 2)  # type: ignore[attr-defined]
        return give_up

    def _cached_rays(self, state: SimpleNamespace, coarse: Mesh, texels):
        """``(sample indices (n,)) → rays`` of the band ``texels``: the classical bake's rays cast at those samples not
        cast yet, and the band's kept rays returned (:meth:`_cast`: (M,) arrays, valid where ``done``), which every
        decision and the given-up samples' normals reuse."""
        m = int(texels.n_samples)
        rays = self._rays = state.rays = SimpleNamespace(
            texels=texels, base=state.base, done=np.zeros(m, bool), hit=np.zeros(m, bool), normals=np.zeros((m, 3)),
            points=np.zeros((m, 3)), values=np.zeros(m))

        def classical(idx):
            idx = np.asarray(idx, dtype=np.int64)
            self._cast(rays, coarse, texels, idx[~rays.done[idx]])
            return rays

        return classical

    def _cast(self, rays: SimpleNamespace, coarse: Mesh, texels, idx: np.ndarray) -> None:
        """The classical bake of the samples ``idx`` of ``texels`` into the band's kept rays ``rays`` (``done``, ``hit``,
        ``normals``, ``points``, ``values``: (M,) each; the band's kept classical bake's rows where there is one).
        ``values``: the source's signed distance at each sample to first order, (x − p)·n with p the point the ray
        found and n the source's normal there, in the field's frame (what f approximates; the bake's miss test reads
        it where f is not evaluated)."""
        from .baker import _to_field_frame

        if len(idx):
            b = {k: rays.base[k][idx] for k in ("normals", "points", "hit")} if rays.base is not None \
                else self._cast_rays(coarse, texels, idx)
            lib = KERNEL.lib()
            frame = self.sdf.frame
            if lib is not None and (frame is None or frame == coarse.frame == self.fine.frame):  # no frame to change
                idx = np.ascontiguousarray(idx, dtype=np.int64)
                x = np.ascontiguousarray(texels.points, dtype=np.float64)
                nrm, pts = (np.ascontiguousarray(b[k], dtype=np.float64) for k in ("normals", "points"))
                hit = np.ascontiguousarray(b["hit"], dtype=bool)
                lib.nb_keep_rays(idx.ctypes.data, len(idx), x.ctypes.data, nrm.ctypes.data, pts.ctypes.data,
                                 hit.ctypes.data, rays.normals.ctypes.data, rays.points.ctypes.data,
                                 rays.hit.ctypes.data, rays.values.ctypes.data, rays.done.ctypes.data, threads())
                return
            x = _to_field_frame(np.asarray(texels.points, dtype=np.float64)[idx], coarse.frame, frame)
            p = _to_field_frame(np.asarray(b["points"], dtype=np.float64), self.fine.frame, frame)
            rays.hit[idx], rays.normals[idx], rays.points[idx], rays.done[idx] = b["hit"], b["normals"], b["points"], True
            rays.values[idx] = np.einsum("ij,ij->i", x - p, b["normals"])

    def _classical(self, coarse: Mesh, texels, idx: np.ndarray, colors: np.ndarray | None,
                   base: dict | None) -> tuple[dict, dict]:
        """(reasons, classical bake) of samples ``idx`` whose normals are replaced without a decision (given-up
        cells' samples); their ``colors`` (the band's (M, C), None: not decided) by the colour rules, as anywhere
        (what they keep is as close to the source's). Rays cast unless ``base`` holds the band's classical bake."""
        b = self._baseline(coarse, texels, idx, base)
        n = len(idx)
        why = {"mask": np.ones(n, bool), "sdf": np.zeros(n, bool), "angle": np.zeros(n, bool),
               "invalid": np.zeros(n, bool)}
        if colors is not None:
            why["color"] = self._colour_rules(colors[idx], b["colors"])
        return why, b

    def __call__(self, coarse: Mesh, texels, normals: np.ndarray, valid: np.ndarray, evaluated=None,
                 colors: np.ndarray | None = None, values: np.ndarray | None = None,
                 decide: np.ndarray | None = None, side: np.ndarray | None = None,
                 given_up: np.ndarray | None = None) -> HybridBand:
        import time

        from .baseline import baseline_bake

        t0 = time.perf_counter()
        normals = np.asarray(normals, dtype=np.float64)
        valid = np.asarray(valid, dtype=bool)
        m = len(normals)
        colors = None if colors is None or not self.decides_colours else np.asarray(colors, dtype=np.float64)
        color_mask = np.zeros(m, dtype=bool) if colors is not None else None
        source_colors = np.zeros_like(colors) if colors is not None else None
        state, self._early = self._early, None
        if state is not None and (given_up is None or state.texels is not texels):
            state = None
        if state is not None and state.base is not None:
            base = state.base
        else:
            base = baseline_bake(coarse, self.fine, texels, cage=self.cage, scene=self.scene,
                                 fine_normals=self.fine_normals) if self.keep_baseline else None
        if self.decide == "all" or evaluated is None:
            first = np.arange(m)
        else:
            # the evaluated samples on the stride's texels, and the decision points of what was interpolated
            # without them (``decide``); the evaluated samples between the stride's are decided near unfaithful ones
            points = np.asarray(evaluated if decide is None else decide, dtype=bool)
            between = np.zeros(m, dtype=bool)
            if self.stride > 1 and side is not None:  # an adaptive bake: its evaluated samples lie where it refined
                pix = np.asarray(texels.pixel)
                between = np.asarray(evaluated, dtype=bool) & ((pix[:, 0] % self.stride != 0)
                                                               | (pix[:, 1] % self.stride != 0))
                side = np.asarray(side).copy()
                side[between] = self.stride
            first = np.flatnonzero((points & ~between) | ~valid)
        # f and ∇f are known at the evaluated samples (all without ``evaluated``): f at their source points
        # can be estimated; the interpolated samples' (NaN here) are not used until the ring
        values = None if values is None else np.asarray(values, dtype=np.float64)
        estimable = values if values is None or evaluated is None \
            else np.where(np.asarray(evaluated, dtype=bool), values, np.nan)
        mask = np.zeros(m, dtype=bool)
        # the band's rays cast while it was refined (normals alone): every sample's classical normal is its own
        rays = getattr(state, "rays", None) if state is not None and colors is None else None
        classical = np.zeros((m, 3)) if rays is None else rays.normals
        reasons = {k: np.zeros(m, dtype=bool) for k in ("sdf", "angle", "invalid")}
        decided = np.zeros(m, dtype=bool)

        def take(idx, why, b):
            decided[idx] = True
            mask[idx] = why["mask"]
            classical[idx] = b["normals"]
            for k in reasons:
                reasons[k][idx] = why[k]
            if color_mask is not None:
                color_mask[idx] = why["color"]
                source_colors[idx] = b["colors"]

        def either(why):  # unfaithful normal or colour
            return why["mask"] | why["color"] if color_mask is not None else why["mask"]

        forced = None
        if state is not None:
            for idx, why, b in state.parts:  # decided while the bake refined the band
                take(idx, why, b)
            # a detail cell's nodes (decided), and the evaluated samples of cells given up on the source's detail:
            # the classical normal, as their cells' other samples
            forced = (state.detail | (np.asarray(given_up, dtype=bool) & decided)) & ~mask
            mask |= forced
            self.counts["detail_nodes"] += int(forced.sum())
            given = np.flatnonzero(np.asarray(given_up, dtype=bool) & ~decided)
            if len(given) and rays is not None:  # the classical bake's without a decision, cast once a sample
                self._cast(rays, coarse, texels, given[~rays.done[given]])
                decided[given] = mask[given] = True
                self.counts["given_up"] += len(given)
            elif len(given):
                take(given, *self._classical(coarse, texels, given, colors, base))
                self.counts["given_up"] += len(given)
            first = first[~decided[first]]
        if len(first):
            why, b = self._decide(coarse, texels, first, normals, valid, base, colors, values=estimable)
            take(first, why, b)
        rest = np.flatnonzero(~decided)
        if len(rest):
            found = mask if color_mask is None else mask | color_mask
            if given_up is not None:
                found = found & ~np.asarray(given_up, dtype=bool)  # found unfaithful by a decision, not given up
            if forced is not None:
                found = found & ~forced  # a detail cell's nodes are not unfaithful: no ring around them
            near = self._near(texels, np.flatnonzero(found), rest, side)
            ring = rest[near]
            if len(ring):  # f at their points is the bake's interpolation: half the estimate's room for its error
                take(ring, *self._decide(coarse, texels, ring, normals, valid, base, colors, values=values,
                                         share=0.25))
            check = self._check_pick(rest[~near])
            if len(check):
                why, b = self._decide(coarse, texels, check, normals, valid, base, colors)
                take(check, why, b)
                self.check["samples"] += len(check)
                self.check["missed"] += int(either(why).sum())
        self._seen += m
        self._rays = None  # the band is done
        out = normals.copy()
        np.copyto(out, classical, where=mask[:, None])  # a masked copy: no gather of the replaced rows
        out_colors = None
        if color_mask is not None:
            out_colors = colors.copy()
            out_colors[color_mask] = source_colors[color_mask]
            self.counts["color_replaced"] += int(color_mask.sum())
        self.counts["samples"] += m
        self.counts["decided"] += int(decided.sum())
        self.counts["replaced"] += int(mask.sum())
        for k in ("sdf", "angle", "invalid"):
            self.counts[k] += int(reasons[k].sum())
        if self.keep_baseline:
            self.baselines.append(base)
        self.seconds += time.perf_counter() - t0
        return HybridBand(out, mask, out_colors, color_mask)

    def summary(self) -> dict:
        """JSON-ready totals: thresholds, where it decided, counts per reason, share of samples replaced, |f| at
        the source (of the decided samples) and the lattice rule's check."""
        f = np.concatenate(self.f_abs) if self.f_abs else np.zeros(0)
        n = max(1, self.counts["samples"])
        c = self.check
        return {"sdf_tol": self.sdf_tol, "angle_deg": self.angle_deg, "color_tol": self.color_tol,
                "color_psnr": self.color_psnr, "color_within": self.color_within, "color_bits": self.color_bits,
                "decide": self.decide, **self.counts,
                "sample_fraction": self.counts["replaced"] / n,
                "color_sample_fraction": self.counts["color_replaced"] / n if self.decides_colours else None,
                "decided_fraction": self.counts["decided"] / n,
                "lattice_check": None if self.decide == "all" else {
                    "samples": c["samples"], "missed": c["missed"],
                    "missed_fraction": c["missed"] / c["samples"] if c["samples"] else None},
                "estimate_check": {**self.estimate, "missed_fraction": self.estimate["missed"] / self.estimate[
                    "samples"] if self.estimate["samples"] else None},
                "f_at_source": {"median": float(np.median(f)) if f.size else None,
                                "p95": float(np.percentile(f, 95)) if f.size else None,
                                "max": float(f.max()) if f.size else None},
                "seconds": self.seconds}

    def baseline(self) -> dict | None:
        """The kept classical bake over every call, concatenated in call order (None if not kept)."""
        if not self.keep_baseline or not self.baselines:
            return None
        b = self.baselines
        out = {k: np.concatenate([x[k] for x in b]) for k in ("normals", "points", "hit", "distance")}
        out["colors"] = None if b[0]["colors"] is None else np.concatenate([x["colors"] for x in b])
        out["fallback"] = int(sum(x["fallback"] for x in b))
        out["cage"] = b[0]["cage"]
        out["seconds"] = {k: float(sum(x["seconds"][k] for x in b)) for k in b[0]["seconds"]}
        return out

