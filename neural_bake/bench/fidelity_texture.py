"""The texture rows of `neural-bake bench fidelity`: what a baked albedo keeps of an asset's texture.

For a textured asset with its fitted SDF and colour network, three albedo bakes onto one coarse mesh and UV
layout: the network alone, the hybrid colour rule at the default tolerances (where the network's colour is
more than ΔE :data:`~neural_bake.constants.HYBRID_COLOR_DELTA_E` from the source texture's, or beyond the
loss against a classical transfer that :data:`~neural_bake.constants.HYBRID_COLOR_WITHIN_DB` allows, the
source's), and
the classical transfer (rays to the source mesh, its texture there). Each is scored on its 8-bit sRGB map over
the covered texels against the source texture at each texel's closest source point, and the network's two
against the classical one: PSNR and SSIM (scikit-image, 7×7 windows, colour channels; the SSIM map averaged
over the covered texels, uncovered texels zero in both images). Each bake is timed, and its time given as a
ratio to the network alone's in the same run.
"""

from __future__ import annotations

import math
import time

import numpy as np

__all__ = ["albedo_scores", "srgb8", "texture_row", "feature_ssim", "dot_windows", "FEATURE_SSIM_FLOOR"]

#: SSIM a small feature's window must keep against the source for the feature to count as surviving: the hybrid
#: rule's ΔE 2 leaves SSIM above 0.98 on a flat-colour feature even if every texel were that far off, while a
#: blurred feature (its contrast spread over its neighbours, its peak lowered) scores well below.
FEATURE_SSIM_FLOOR = 0.95


def srgb8(linear: np.ndarray) -> np.ndarray:
    """A linear-RGB(A) map (H, W, ≥3) as the 8-bit sRGB values its PNG holds, floats in [0, 1], RGB only."""
    from ..io.colour import linear_to_srgb

    return np.round(np.clip(linear_to_srgb(np.asarray(linear, dtype=np.float64)[..., :3]), 0.0, 1.0) * 255) / 255


def albedo_scores(a: np.ndarray, b: np.ndarray, covered: np.ndarray) -> dict:
    """PSNR (dB) and SSIM of sRGB images ``a`` and ``b`` (H, W, 3) in [0, 1] over the ``covered`` (H, W) texels:
    ``{"psnr_db", "ssim"}`` (None when nothing is covered)."""
    from skimage.metrics import structural_similarity

    from ..bake.report import psnr

    covered = np.asarray(covered, dtype=bool)
    if not covered.any():
        return {"psnr_db": None, "ssim": None}
    a = np.where(covered[..., None], a, 0.0)
    b = np.where(covered[..., None], b, 0.0)
    _, full = structural_similarity(a, b, channel_axis=2, data_range=1.0, full=True)
    return {"psnr_db": psnr(a[covered], b[covered]), "ssim": float(np.mean(full[covered]))}


def dot_windows(size: int, diameter: float = 8.0) -> list[tuple[slice, slice]]:
    """The (rows, columns) windows of the ``dots`` sample's discs ``diameter`` texels across (in its default
    texture's texels), on a map of side ``size`` in the sample's own UV layout: twice the disc's diameter wide,
    centred on it (the dots are fixed in uv, so they scale with the map)."""
    from ..samples import Dots

    sample = Dots()
    k = float(size) / float(sample.texture_size)
    half = int(round(diameter * k))
    out = []
    for dot in sample.dots():
        if dot["diameter"] != diameter:
            continue
        x, y = dot["centre"][0] * k, dot["centre"][1] * k
        r0, c0 = int(round(y - half)), int(round(x - half))
        out.append((slice(r0, r0 + 2 * half), slice(c0, c0 + 2 * half)))
    return out


def feature_ssim(a: np.ndarray, b: np.ndarray, windows: list[tuple[slice, slice]]) -> list[float] | None:
    """SSIM of sRGB images ``a`` and ``b`` (H, W, 3) over each window (7×7 SSIM windows, colour channels); None
    when a window is smaller than 7 texels."""
    from skimage.metrics import structural_similarity

    if not windows or any(r.stop - r.start < 7 or c.stop - c.start < 7 for r, c in windows):
        return None
    return [float(structural_similarity(a[r, c], b[r, c], channel_axis=2, data_range=1.0)) for r, c in windows]


def _closest_source_colours(baker, reference, keep: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(linear colours (M, C) of ``reference``'s texture at the closest point of every texel sample of
    ``baker``, the samples' (M, 2) texel rows and columns). With ``keep`` (the baked mesh is ``reference``
    itself: :func:`~neural_bake.bake.baseline.same_surface`) each sample is its own closest point, on its own
    face: where two faces coincide (boards back to back) a closest-point search would pick either."""
    from ..bake.baseline import closest_surface, same_surface
    from ..geometry import interpolate_corners
    from ..io.colour import sample_texture

    tx = baker.texels
    if keep and same_surface(baker.mesh, reference):
        face, bary = np.asarray(tx.face, dtype=np.int64), np.asarray(tx.bary)
    else:
        pts = np.asarray(tx.points, dtype=np.float64)
        if reference.frame != baker.mesh.frame:
            pts = reference.frame.to_unit(baker.mesh.frame.to_source(pts))
        close = closest_surface(reference, pts)
        face, bary = close["face"], close["bary"]
    uv = interpolate_corners(reference.uv, face, bary)
    return sample_texture(reference.texture, uv, reference.uv_policy).astype(np.float64), np.asarray(tx.pixel)


def texture_row(inputs, coarse, *, size: int, keep: bool, log=None,
                features: list[tuple[slice, slice]] | None = None) -> dict:
    """The texture row of one asset: ``inputs`` a :class:`~neural_bake.bake.job.BakeInputs` with a texture
    field and a textured source, ``coarse`` the coarse mesh (unwrapped here once when it has no UVs, so the
    three bakes share one layout), ``size`` the map side, ``keep`` the coarse mesh is the source itself,
    ``features``: windows (rows, columns) of the map holding small features (e.g. :func:`dot_windows`), scored
    one by one: the row then has ``network_feature_ssim_min`` and ``hybrid_feature_ssim_min`` (the worst
    window's SSIM against the source) and ``network_features_survive`` / ``hybrid_features_survive`` (every
    window at least :data:`FEATURE_SSIM_FLOOR`).

    Returns ``{"psnr_db", "ssim"}`` of the network alone (``network_*``), the hybrid (``hybrid_*``, with
    ``hybrid_color_pct``: the share of covered texels that took the source's colour) and the classical
    transfer (``classical_*``) against the source texture at the closest points; the network's two against
    the classical one (``*_vs_classical_*``); seconds of each bake (``*_bake_s``) and their ratios to the
    network alone's (``*_time_ratio``).
    """
    from ..bake.adaptive import AdaptiveOptions
    from ..bake.classical import classical_bake
    from ..bake.job import bake_maps
    from ..constants import HYBRID_ANGLE_DEG, HYBRID_COLOR_DELTA_E, HYBRID_COLOR_WITHIN_DB, HYBRID_SDF_TOL
    from ..io.colour import linear_to_srgb
    from ..mesh.unwrap import unwrap

    say = log or (lambda s: None)
    if coarse.uv is None:
        coarse = unwrap(coarse, resolution=int(size))
    maps, baked, seconds = {}, {}, {}
    for label, tol, within in (("network", math.inf, None), ("hybrid", HYBRID_COLOR_DELTA_E, HYBRID_COLOR_WITHIN_DB)):
        say(f"albedo bake, {label}: {size}²")
        t0 = time.perf_counter()
        baked[label] = bake_maps(inputs, coarse, maps=["albedo"], size=int(size), cache_texels=True,
                                 report_samples=1, keep=keep, hybrid_tol=HYBRID_SDF_TOL, hybrid_angle=HYBRID_ANGLE_DEG,
                                 hybrid_color_tol=tol, hybrid_color_within=within, adaptive=AdaptiveOptions())
        seconds[label] = time.perf_counter() - t0
        maps[label] = srgb8(baked[label].result.albedo)
    say(f"albedo bake, classical transfer: {size}²")
    t0 = time.perf_counter()
    classical, _ = classical_bake(coarse, inputs.reference, int(size))
    seconds["classical"] = time.perf_counter() - t0
    maps["classical"] = srgb8(classical.albedo)
    baker = baked["network"].baker
    covered = np.asarray(baked["network"].result.coverage, dtype=bool)
    truth, pix = _closest_source_colours(baker, inputs.reference, keep)
    source = np.zeros((*covered.shape, 3))
    source[pix[:, 0], pix[:, 1]] = np.clip(linear_to_srgb(truth[:, :3]), 0.0, 1.0)
    row: dict = {"size": int(size), "texels": int(covered.sum())}
    for label in ("network", "hybrid", "classical"):
        s = albedo_scores(maps[label], source, covered)
        row[f"{label}_psnr_db"], row[f"{label}_ssim"] = s["psnr_db"], s["ssim"]
    for label in ("network", "hybrid"):
        s = albedo_scores(maps[label], maps["classical"], covered)
        row[f"{label}_vs_classical_psnr_db"], row[f"{label}_vs_classical_ssim"] = s["psnr_db"], s["ssim"]
    if features:
        for label in ("network", "hybrid"):
            scores = feature_ssim(maps[label], source, features)
            row[f"{label}_feature_ssim_min"] = None if scores is None else min(scores)
            row[f"{label}_features_survive"] = None if scores is None else min(scores) >= FEATURE_SSIM_FLOOR
    stats = baked["hybrid"].result.stats
    row["hybrid_color_pct"] = 100.0 * float(stats.get("hybrid_color_fraction", 0.0))
    for label in ("network", "hybrid", "classical"):
        row[f"{label}_bake_s"] = seconds[label]
    for label in ("hybrid", "classical"):
        row[f"{label}_time_ratio"] = seconds[label] / seconds["network"] if seconds["network"] > 0 else None
    return row
