"""Quality report of a bake: angular errors, colour PSNR, coverage, misses, seams, times; PNG error maps.

All errors are measured on what a renderer gets: the normal map is decoded at each texel sample with the
frame the renderer reconstructs (optionally after quantising it to the bit depth of the file), and
compared with the ground truth (analytic for the samples, else the fine mesh's normal at the closest
point), with ∇f itself (the encoding error), and — when given — with the classical baseline's normals.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import NeuralBakeError
from ..types import Mesh
from .maps import colors_to_normals, decode_tangent_space

__all__ = ["bake_report", "angular_error", "error_stats", "psnr", "seam_discontinuity", "decode_map"]

#: Angular errors at or above this many degrees are drawn white in the error maps.
ERROR_MAP_MAX_DEG = 10.0


def angular_error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles in degrees (M,) between unit vectors a and b (M, 3), float64; zero vectors give 180°."""
    d = np.einsum("ij,ij->i", np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return np.degrees(np.arccos(np.clip(d, -1.0, 1.0)))


def error_stats(err: np.ndarray) -> dict:
    """Median, mean, 95th percentile and max of an error array (None for an empty one)."""
    err = np.asarray(err, dtype=np.float64)
    if err.size == 0:
        return {"median": None, "mean": None, "p95": None, "max": None, "count": 0}
    return {
        "median": float(np.median(err)),
        "mean": float(err.mean()),
        "p95": float(np.percentile(err, 95)),
        "max": float(err.max()),
        "count": int(err.size),
    }


def psnr(a: np.ndarray, b: np.ndarray, peak: float = 1.0) -> float | None:
    """Peak signal-to-noise ratio in dB of two arrays in [0, peak]; inf when equal, None when empty."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.size == 0:
        return None
    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(peak**2 / mse))


def _quantise(image: np.ndarray, bits: int | None) -> np.ndarray:
    if bits is None:
        return np.asarray(image, dtype=np.float64)
    levels = float(2**bits - 1)
    return np.round(np.clip(image, 0.0, 1.0) * levels) / levels


def decode_map(normal_map: np.ndarray, texels, normal_space: str = "tangent", y_convention: str = "opengl",
               bits: int | None = None) -> np.ndarray:
    """Object-space unit normals (M, 3) a renderer reads from ``normal_map`` at the texel samples
    (nearest texel, the sample's own frame; quantised to ``bits`` first when given)."""
    nm = _quantise(normal_map, bits)
    x = colors_to_normals(nm[texels.pixel[:, 0], texels.pixel[:, 1]])
    if normal_space == "object":
        return x
    return decode_tangent_space(x, texels.tangent, texels.bitangent, texels.normal, y_convention)


def seam_discontinuity(
    mesh: Mesh,
    tangents: np.ndarray,
    normal_map: np.ndarray,
    albedo: np.ndarray | None = None,
    *,
    normal_space: str = "tangent",
    y_convention: str = "opengl",
    samples_per_edge: int = 3,
) -> dict:
    """Differences across UV seams: the same 3-D edge in two charts, read from both sides.

    ``mesh`` is split at seams (``Baker.mesh``) with per-vertex ``tangents`` (V, 4). Each seam edge is
    sampled at ``samples_per_edge`` interior points; on each side the maps are read bilinearly at that
    side's UV and the normal decoded with that side's frame. Returns ``{"edges", "normal_deg": stats,
    "color": stats of the mean absolute RGB difference (linear)}``.
    """
    from ..io.colour import sample_texture
    from ..mesh.tangents import vertex_normals, vertex_uv

    uvv = vertex_uv(mesh)
    vn = vertex_normals(mesh)
    _, pos_id = np.unique(np.round(mesh.vertices, 9), axis=0, return_inverse=True)
    pos_id = pos_id.reshape(-1)
    f = mesh.faces
    ea = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])  # corner indices of each directed face edge
    eb = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    pa, pb = pos_id[ea], pos_id[eb]
    key = np.stack([np.minimum(pa, pb), np.maximum(pa, pb)], axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    order = np.argsort(inv, kind="stable")
    two = cnt[inv[order]] == 2
    order = order[two]
    first, second = order[0::2], order[1::2]
    # orient the second side like the first (same 3-D start point)
    same = pa[first] == pa[second]
    a1, b1 = ea[first], eb[first]
    a2 = np.where(same, ea[second], eb[second])
    b2 = np.where(same, eb[second], ea[second])
    seam = (np.abs(uvv[a1] - uvv[a2]).max(axis=1) > 1e-9) | (np.abs(uvv[b1] - uvv[b2]).max(axis=1) > 1e-9)
    a1, b1, a2, b2 = a1[seam], b1[seam], a2[seam], b2[seam]
    if a1.size == 0:
        return {"edges": 0, "normal_deg": error_stats([]), "color": error_stats([])}
    ts = (np.arange(samples_per_edge) + 1.0) / (samples_per_edge + 1.0)

    def side(a, b):
        t = np.repeat(ts[None, :], len(a), axis=0).reshape(-1, 1)
        a, b = np.repeat(a, len(ts)), np.repeat(b, len(ts))
        lerp = lambda v: (1 - t) * v[a] + t * v[b]  # noqa: E731
        uv = lerp(uvv)
        x = colors_to_normals(sample_texture(normal_map, uv, mesh.uv_policy))
        if normal_space == "object":
            n_obj = x
        else:
            nn = lerp(vn)
            nn /= np.maximum(np.linalg.norm(nn, axis=1, keepdims=True), 1e-12)
            tt = lerp(tangents[:, :3])
            tt /= np.maximum(np.linalg.norm(tt, axis=1, keepdims=True), 1e-12)
            w = np.where(lerp(tangents[:, 3:]) < 0, -1.0, 1.0)
            n_obj = decode_tangent_space(x, tt, w * np.cross(nn, tt), nn, y_convention)
        col = None if albedo is None else sample_texture(albedo, uv, mesh.uv_policy)
        return n_obj, col

    n1, c1 = side(a1, b1)
    n2, c2 = side(a2, b2)
    out = {"edges": int(a1.size), "normal_deg": error_stats(angular_error(n1, n2))}
    out["color"] = error_stats(np.abs(c1 - c2).mean(axis=1)) if albedo is not None else error_stats([])
    return out


def _error_image(err: np.ndarray, texels, shape, max_deg: float = ERROR_MAP_MAX_DEG) -> np.ndarray:
    img = np.zeros((*shape, 1))
    flat = texels.pixel[:, 0] * shape[1] + texels.pixel[:, 1]
    acc = np.bincount(flat, weights=err * texels.weight, minlength=shape[0] * shape[1])
    img[..., 0] = (acc / max_deg).reshape(shape)
    return np.clip(img, 0.0, 1.0)


def bake_report(
    result,
    baker,
    *,
    truth: Callable[[np.ndarray], np.ndarray] | None = None,
    fine: Mesh | None = None,
    truth_colors: Callable[[np.ndarray], np.ndarray] | None = None,
    baseline: dict | None = None,
    bits: int | None = 8,
    timings: dict | None = None,
    out_dir: str | Path | None = None,
) -> dict:
    """The quality report of ``result`` (a :class:`BakeResult`) baked by ``baker`` (its texels cached).

    - ``truth``: callable, unit-frame points (M, 3) -> ground-truth unit normals (M, 3) (analytic);
      otherwise ``fine`` (the high-resolution mesh): its interpolated normal at the closest point.
    - ``truth_colors``: callable points -> linear RGB (M, 3); otherwise ``fine``'s texture at the closest
      point (when it has one). Colour PSNR is measured on sRGB-encoded values (what the file holds).
    - ``baseline``: :func:`baseline_bake`'s result on the same texels: its errors and time beside ours.
    - ``bits``: quantise the normal map to this many bits before decoding (the PNG's depth; None: float).
    - ``timings``: extra stage times (seconds) to list, e.g. loading, coarse mesh, export.
    - ``out_dir``: if given, writes ``error_normal.png`` (angle to ground truth, white = 10°+),
      ``error_baseline.png`` and ``miss.png`` there (atomically) and lists them under ``"files"``.

    Returns a JSON-ready dict. Angles are in degrees.
    """
    from ..io.colour import linear_to_srgb

    tx = baker.texels
    if tx is None or result.normals is None:
        raise NeuralBakeError("bake_report: needs the per-sample values (bake with keep_samples=True and a cached "
                              "Baker, i.e. cache_texels=True)")
    decoded = decode_map(result.normal_map, tx, baker.normal_space, baker.y_convention, bits)
    rep: dict = {"bake": result.stats, "bits": bits}
    valid = result.valid
    rep["vs_gradient_deg"] = error_stats(angular_error(decoded[valid], result.normals[valid]))
    rep["invalid_gradients"] = int((~valid).sum())
    rep["coverage"] = float(np.mean(result.coverage))
    rep["texels_covered"] = int(np.sum(result.coverage))
    rep["miss_texels"] = int(np.sum(result.miss))
    rep["miss_fraction"] = float(np.sum(result.miss) / max(1, np.sum(result.coverage)))
    truth_n = truth_c = None
    closest = None
    if truth is not None:
        truth_n = np.asarray(truth(tx.points), dtype=np.float64)
        rep["truth"] = "analytic"
    elif fine is not None:
        from .baseline import closest_surface

        pts = tx.points if fine.frame == baker.mesh.frame else fine.frame.to_unit(baker.mesh.frame.to_source(tx.points))
        closest = closest_surface(fine, pts)
        truth_n = closest["normals"]
        rep["truth"] = "fine mesh, closest point"
    if truth_colors is not None:
        truth_c = np.asarray(truth_colors(tx.points), dtype=np.float64)
    elif closest is not None and fine.uv is not None and fine.texture is not None:
        from ..io.colour import sample_texture

        uv = np.einsum("mk,mkc->mc", closest["bary"], np.asarray(fine.uv)[closest["face"]])
        truth_c = sample_texture(fine.texture, uv, fine.uv_policy).astype(np.float64)
    err = None
    if truth_n is not None:
        err = angular_error(decoded, truth_n)
        rep["vs_truth_deg"] = error_stats(err)
        rep["gradient_vs_truth_deg"] = error_stats(angular_error(result.normals, truth_n))
        rep["geometric_vs_truth_deg"] = error_stats(angular_error(tx.normal, truth_n))
    if result.albedo is not None and truth_c is not None:
        k = min(3, truth_c.shape[1])
        ours = linear_to_srgb(result.albedo[tx.pixel[:, 0], tx.pixel[:, 1], :k].astype(np.float64))
        rep["color_psnr_db"] = psnr(_quantise(ours, bits), linear_to_srgb(truth_c[:, :k]))
    rep["seams"] = seam_discontinuity(
        baker.mesh, baker.tangents, result.normal_map, result.albedo,
        normal_space=baker.normal_space, y_convention=baker.y_convention,
    )
    base_err = None
    if baseline is not None:
        b: dict = {"seconds": baseline["seconds"], "fallback": baseline["fallback"], "cage": baseline["cage"]}
        if truth_n is not None:
            base_err = angular_error(baseline["normals"], truth_n)
            b["vs_truth_deg"] = error_stats(base_err)
        if baseline.get("colors") is not None and truth_c is not None:
            k = min(3, truth_c.shape[1])
            b["color_psnr_db"] = psnr(linear_to_srgb(baseline["colors"][:, :k]), linear_to_srgb(truth_c[:, :k]))
        rep["baseline"] = b
    rep["seconds"] = {**result.stats.get("seconds", {}), **(timings or {})}
    if out_dir is not None:
        from ..io.images import write_image

        out_dir = Path(out_dir)
        files = []
        if err is not None:
            write_image(out_dir / "error_normal.png", _error_image(err, tx, result.coverage.shape), colour="data")
            files.append("error_normal.png")
        if base_err is not None:
            write_image(out_dir / "error_baseline.png", _error_image(base_err, tx, result.coverage.shape), colour="data")
            files.append("error_baseline.png")
        write_image(out_dir / "miss.png", result.miss.astype(np.float32), colour="data")
        files.append("miss.png")
        rep["files"] = files
        rep["error_map_scale_deg"] = ERROR_MAP_MAX_DEG
    return rep
