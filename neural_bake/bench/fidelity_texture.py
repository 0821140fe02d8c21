"""The texture rows of `neural-bake bench fidelity`: what a baked albedo keeps of an asset's texture.

For a textured asset with its fitted SDF and colour network, three albedo bakes onto one coarse mesh and UV
layout: the network alone, the hybrid colour rule at the default tolerance (where the network's colour is
more than ΔE :data:`~neural_bake.constants.HYBRID_COLOR_DELTA_E` from the source texture's, the source's), and
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

__all__ = ["albedo_scores", "srgb8", "texture_row"]


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


def _closest_source_colours(baker, reference) -> tuple[np.ndarray, np.ndarray]:
    """(linear colours (M, C) of ``reference``'s texture at the closest point of every texel sample of
    ``baker``, the samples' (M, 2) texel rows and columns)."""
    from ..bake.baseline import closest_surface
    from ..geometry import interpolate_corners
    from ..io.colour import sample_texture

    tx = baker.texels
    pts = np.asarray(tx.points, dtype=np.float64)
    if reference.frame != baker.mesh.frame:
        pts = reference.frame.to_unit(baker.mesh.frame.to_source(pts))
    close = closest_surface(reference, pts)
    uv = interpolate_corners(reference.uv, close["face"], close["bary"])
    return sample_texture(reference.texture, uv, reference.uv_policy).astype(np.float64), np.asarray(tx.pixel)


def texture_row(inputs, coarse, *, size: int, keep: bool, log=None) -> dict:
    """The texture row of one asset: ``inputs`` a :class:`~neural_bake.bake.job.BakeInputs` with a texture
    field and a textured source, ``coarse`` the coarse mesh (unwrapped here once when it has no UVs, so the
    three bakes share one layout), ``size`` the map side, ``keep`` the coarse mesh is the source itself.

    Returns ``{"psnr_db", "ssim"}`` of the network alone (``network_*``), the hybrid (``hybrid_*``, with
    ``hybrid_color_pct``: the share of covered texels that took the source's colour) and the classical
    transfer (``classical_*``) against the source texture at the closest points; the network's two against
    the classical one (``*_vs_classical_*``); seconds of each bake (``*_bake_s``) and their ratios to the
    network alone's (``*_time_ratio``).
    """
    from ..bake.adaptive import AdaptiveOptions
    from ..bake.classical import classical_bake
    from ..bake.job import bake_maps
    from ..constants import HYBRID_ANGLE_DEG, HYBRID_COLOR_DELTA_E, HYBRID_SDF_TOL
    from ..io.colour import linear_to_srgb
    from ..mesh.unwrap import unwrap

    say = log or (lambda s: None)
    if coarse.uv is None:
        coarse = unwrap(coarse, resolution=int(size))
    maps, baked, seconds = {}, {}, {}
    for label, tol in (("network", math.inf), ("hybrid", HYBRID_COLOR_DELTA_E)):
        say(f"albedo bake, {label}: {size}²")
        t0 = time.perf_counter()
        baked[label] = bake_maps(inputs, coarse, maps=["albedo"], size=int(size), cache_texels=True,
                                 report_samples=1, keep=keep, hybrid_tol=HYBRID_SDF_TOL, hybrid_angle=HYBRID_ANGLE_DEG,
                                 hybrid_color_tol=tol, adaptive=AdaptiveOptions())
        seconds[label] = time.perf_counter() - t0
        maps[label] = srgb8(baked[label].result.albedo)
    say(f"albedo bake, classical transfer: {size}²")
    t0 = time.perf_counter()
    classical, _ = classical_bake(coarse, inputs.reference, int(size))
    seconds["classical"] = time.perf_counter() - t0
    maps["classical"] = srgb8(classical.albedo)
    baker = baked["network"].baker
    covered = np.asarray(baked["network"].result.coverage, dtype=bool)
    truth, pix = _closest_source_colours(baker, inputs.reference)
    source = np.zeros((*covered.shape, 3))
    source[pix[:, 0], pix[:, 1]] = np.clip(linear_to_srgb(truth[:, :3]), 0.0, 1.0)
    row: dict = {"size": int(size), "texels": int(covered.sum())}
    for label in ("network", "hybrid", "classical"):
        s = albedo_scores(maps[label], source, covered)
        row[f"{label}_psnr_db"], row[f"{label}_ssim"] = s["psnr_db"], s["ssim"]
    for label in ("network", "hybrid"):
        s = albedo_scores(maps[label], maps["classical"], covered)
        row[f"{label}_vs_classical_psnr_db"], row[f"{label}_vs_classical_ssim"] = s["psnr_db"], s["ssim"]
    stats = baked["hybrid"].result.stats
    row["hybrid_color_pct"] = 100.0 * float(stats.get("hybrid_color_fraction", 0.0))
    for label in ("network", "hybrid", "classical"):
        row[f"{label}_bake_s"] = seconds[label]
    for label in ("hybrid", "classical"):
        row[f"{label}_time_ratio"] = seconds[label] / seconds["network"] if seconds["network"] > 0 else None
    return row
