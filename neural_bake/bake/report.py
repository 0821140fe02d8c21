"""Quality report of a bake: angular errors, colour PSNR, coverage, misses, seams, times; PNG error maps.

All errors are measured on what a renderer gets: the normal map is decoded at each texel sample with the
frame the renderer reconstructs (optionally after quantising it to the bit depth of the file), and
compared with the ground truth (analytic for the samples, else the fine mesh's normal at the closest
point), with ∇f itself (the encoding error), and — when given — with the classical baseline's normals.

A bake that streamed its texels (large maps) kept only a seeded uniform subsample of its samples
(:class:`~neural_bake.bake.baker.TexelSample`): the per-sample figures (errors, PSNR) are measured on it and
the report says so under ``"sampling"``; coverage, misses, seams and the error-map PNGs are computed over
all texels (the error maps by streaming the layout's bands again, without the networks).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from ..constants import DIRECTION_EPS, REPORT_LATTICE_SIDE, UV_MATCH_TOL
from ..errors import NeuralBakeError
from ..geometry import angular_error, interpolate_corners
from ..types import Mesh
from .maps import colors_to_normals, decode_tangent_space

__all__ = ["bake_report", "angular_error", "error_stats", "psnr", "seam_discontinuity", "decode_map"]

#: Angular errors at or above this many degrees are drawn white in the error maps.
ERROR_MAP_MAX_DEG = 10.0


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
    (nearest texel, the sample's own frame; quantised to ``bits`` first when given). Only the texels read
    are converted, so a 4k map costs no full-size float64 copy."""
    texel_values = np.asarray(normal_map)[texels.pixel[:, 0], texels.pixel[:, 1]]
    x = colors_to_normals(_quantise(texel_values, bits))
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
    seam = ((np.abs(uvv[a1] - uvv[a2]).max(axis=1) > UV_MATCH_TOL)
            | (np.abs(uvv[b1] - uvv[b2]).max(axis=1) > UV_MATCH_TOL))
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
            nn /= np.maximum(np.linalg.norm(nn, axis=1, keepdims=True), DIRECTION_EPS)
            tt = lerp(tangents[:, :3])
            tt /= np.maximum(np.linalg.norm(tt, axis=1, keepdims=True), DIRECTION_EPS)
            w = np.where(lerp(tangents[:, 3:]) < 0, -1.0, 1.0)
            n_obj = decode_tangent_space(x, tt, w * np.cross(nn, tt), nn, y_convention)
        col = None if albedo is None else sample_texture(albedo, uv, mesh.uv_policy)
        return n_obj, col

    n1, c1 = side(a1, b1)
    n2, c2 = side(a2, b2)
    out = {"edges": int(a1.size), "normal_deg": error_stats(angular_error(n1, n2))}
    out["color"] = error_stats(np.abs(c1 - c2).mean(axis=1)) if albedo is not None else error_stats([])
    return out


class _ErrorImage:
    """A (H, W) float32 error map accumulated band by band: each texel gets the weighted mean of its
    samples' errors over ``max_deg`` (a texel's samples all lie in one band), clipped to [0, 1]."""

    def __init__(self, shape: tuple[int, int], max_deg: float = ERROR_MAP_MAX_DEG, step: int = 1):
        self.step = int(step)
        self.img = np.zeros((-(-shape[0] // self.step), -(-shape[1] // self.step)), dtype=np.float32)
        self.max_deg = max_deg

    def add(self, err: np.ndarray, texels) -> None:
        """Add ``err`` (one per sample of ``texels``) at the samples' texels; with a lattice ``step``, only
        samples of lattice texels (:func:`on_lattice`) are given, each at its block's pixel."""
        pix = np.asarray(texels.pixel) // self.step
        if len(pix) == 0:
            return
        w = self.img.shape[1]
        r0, r1 = int(pix[:, 0].min()), int(pix[:, 0].max()) + 1
        flat = (pix[:, 0] - r0) * w + pix[:, 1]
        acc = np.bincount(flat, weights=err * texels.weight, minlength=(r1 - r0) * w)
        self.img[r0:r1] += (acc / self.max_deg).reshape(r1 - r0, w)

    def image(self) -> np.ndarray:
        return np.clip(self.img, 0.0, 1.0)[:, :, None]


class _Truth:
    """Ground-truth normals (and colours) at any texel samples: analytic callables, or the fine mesh's at
    the closest point (its ray-casting scene built once). ``hidden``, after each call with the fine mesh:
    (M,) bool, the samples whose closest point lies on a face buried in another of its shells
    (:func:`~neural_bake.mesh.shells.buried_faces`): inside the solid, never seen; ``face``: (M,) the fine
    mesh's face at each closest point; both None for analytic truth."""

    def __init__(self, baker, truth, fine, truth_colors):
        self.baker, self.truth, self.fine, self.truth_colors = baker, truth, fine, truth_colors
        self.label = "analytic" if truth is not None else "fine mesh, closest point" if fine is not None else None
        self._scene = self._buried = None
        self.hidden: np.ndarray | None = None
        self.face: np.ndarray | None = None

    def __call__(self, texels, colours: bool = True):
        """(normals (M, 3) or None, linear colours (M, C) or None) at ``texels``' points."""
        from ..mesh.shells import buried_faces
        from .baseline import closest_surface, raycasting_scene

        pts = texels.points
        normals = cols = closest = None
        self.hidden = self.face = None
        if self.truth is not None:
            normals = np.asarray(self.truth(pts), dtype=np.float64)
        elif self.fine is not None:
            fine, frame = self.fine, self.baker.mesh.frame
            if self._scene is None:
                self._scene, self._buried = raycasting_scene(fine), buried_faces(fine)
            q = pts if fine.frame == frame else fine.frame.to_unit(frame.to_source(pts))
            closest = closest_surface(fine, q, scene=self._scene)
            normals = closest["normals"]
            self.hidden = self._buried[closest["face"]]
            self.face = closest["face"]
        if not colours:
            return normals, None
        if self.truth_colors is not None:
            cols = np.asarray(self.truth_colors(pts), dtype=np.float64)
        elif closest is not None and self.fine.uv is not None and self.fine.texture is not None:
            from ..io.colour import sample_texture

            fine = self.fine
            uv = interpolate_corners(fine.uv, closest["face"], closest["bary"])
            cols = sample_texture(fine.texture, uv, fine.uv_policy).astype(np.float64)
        return normals, cols


def _median_ci95(err: np.ndarray) -> list[float] | None:
    """Distribution-free 95 % confidence interval of the median of the population ``err`` was drawn from
    uniformly (order statistics n/2 ± 1.96·√n/2)."""
    n = err.size
    if n == 0:
        return None
    k = 1.96 * np.sqrt(n) / 2.0
    lo, hi = max(0, int(np.floor(n / 2.0 - k)) - 1), min(n - 1, int(np.ceil(n / 2.0 + k)))
    part = np.partition(err, (lo, hi))
    return [float(part[lo]), float(part[hi])]


#: Report entries measured on the texel samples the report holds (a subsample for a streamed bake).
SAMPLED_FIGURES = ("vs_gradient_deg", "vs_truth_deg", "gradient_vs_truth_deg", "geometric_vs_truth_deg",
                   "faces_vs_truth_deg",
                   "neural_vs_truth_deg", "hybrid.replaced_vs_truth_deg", "color_psnr_db", "neural_color_psnr_db", "baseline.vs_truth_deg", "baseline.color_psnr_db", "baseline.seconds",
                   "baseline.fallback")


def bake_report(
    result,
    baker,
    *,
    truth: Callable[[np.ndarray], np.ndarray] | None = None,
    fine: Mesh | None = None,
    truth_colors: Callable[[np.ndarray], np.ndarray] | None = None,
    baseline: dict | None = None,
    baseline_fn: Callable[[object], dict] | None = None,
    bits: int | None = 8,
    timings: dict | None = None,
    out_dir: str | Path | None = None,
) -> dict:
    """The quality report of ``result`` (a :class:`BakeResult`) baked by ``baker``.

    Per-sample figures are measured on all texel samples when the bake kept them (a cached Baker), else on
    ``result.sample`` (a streamed bake's seeded uniform subsample); ``"sampling"`` says which
    (``{"samples": N, "of": M, "seed", "sampled": [entries measured on the N], "note"}``, with the median's
    95 % confidence interval ``median_ci95`` added to each sampled error entry when N < M). A map wider than
    :data:`~neural_bake.constants.REPORT_LATTICE_SIDE` is compared with the truth and the baseline on the
    lattice of one texel in each k×k block (``"lattice_step"`` k; the texel at a seeded position in its block:
    :func:`on_lattice`), and its error maps are drawn at that lattice, a pixel per block. Coverage, misses,
    invalid-gradient counts, seams and the masks cover every texel.

    - ``truth``: callable, unit-frame points (M, 3) -> ground-truth unit normals (M, 3) (analytic);
      otherwise ``fine`` (the high-resolution mesh): its interpolated normal at the closest point. Samples
      whose closest point of ``fine`` lies on a face buried in another of its shells (inside the solid, never
      seen: :func:`~neural_bake.mesh.shells.buried_faces`) are counted in ``"hidden_texels"`` and left out of
      every figure against the truth and the baseline and of the error maps.
      ``"faces_vs_truth_deg"`` (with ``fine``): ``fine``'s own face normals at the same closest points against
      its interpolated ones, the error of any field whose zero set is ``fine``'s surface (its exact SDF's):
      0 for a flat-shaded mesh, above 0 where the file shades away from its geometry (smoothed hard edges).
    - ``truth_colors``: callable points -> linear RGB (M, 3); otherwise ``fine``'s texture at the closest
      point (when it has one). Colour PSNR is measured on sRGB-encoded values (what the file holds).
    - ``baseline``: :func:`baseline_bake`'s result on the texels the report measures (``baker.texels``, or
      ``result.sample.texels``); or ``baseline_fn``: texel set -> that result, which the report calls on
      those texels and, for a streamed bake with ``out_dir``, on every band for the baseline's error map
      (then ``baseline["all_texels"]`` holds its time and fallbacks over all M samples).
    - ``bits``: quantise the normal map to this many bits before decoding (the PNG's depth; None: float).
    - ``timings``: extra stage times (seconds) to list, e.g. loading, coarse mesh, export.
    - ``out_dir``: if given, writes ``error_normal.png`` (angle to ground truth, white = 10°+),
      ``error_baseline.png``, ``miss.png`` and (a hybrid bake) ``hybrid.png`` (white: the texels that took
      the classical normal; ``hybrid_color.png``: the source texture's colour) there (atomically) and lists
      them under ``"files"``.

    A hybrid bake (``result.hybrid``) adds ``"hybrid"`` (samples and texels that took the classical normal,
    their share of the covered texels, their error; texels that took the source's colour) and
    ``"neural_vs_truth_deg"`` (∇f alone; ``"neural_color_psnr_db"``: the texture network alone; both over the
    samples the fields were evaluated or interpolated at, not those of cells given up to the classical bake).

    Returns a JSON-ready dict. Angles are in degrees.
    """
    from ..io.colour import linear_to_srgb

    if baseline is not None and baseline_fn is not None:
        raise NeuralBakeError("bake_report: give baseline or baseline_fn, not both")
    full = baker.texels is not None and result.normals is not None
    step = lattice_step(result.coverage.shape)
    pick = None
    if full:
        tx, normals, valid, total = baker.texels, result.normals, result.valid, len(result.normals)
        replaced, neural = result.replaced, result.neural
        neural_colors = getattr(result, "neural_colors", None)
        if step > 1:  # a large map: the lattice of its texels (constants.REPORT_LATTICE_SIDE)
            pick = on_lattice(tx, step)
            tx = _texel_subset(tx, pick)
            normals, valid = normals[pick], valid[pick]
            replaced, neural, neural_colors = (None if a is None else a[pick] for a in (replaced, neural, neural_colors))
            baseline = _baseline_subset(baseline, pick)
    elif getattr(result, "sample", None) is not None:
        smp = result.sample
        tx, normals, valid, total = smp.texels, smp.normals, smp.valid, smp.total
        replaced, neural, neural_colors = smp.replaced, smp.neural, None
    else:
        raise NeuralBakeError("bake_report: needs the per-sample values (a cached Baker with keep_samples=True, "
                              "or a streamed bake with report_samples > 0)")
    n = len(normals)
    sampled = n < total
    stats = (lambda e: {**error_stats(e), "median_ci95": _median_ci95(np.asarray(e, dtype=np.float64))}) if sampled \
        else error_stats
    decoded = decode_map(result.normal_map, tx, baker.normal_space, baker.y_convention, bits)
    rep: dict = {"bake": result.stats, "bits": bits}
    rep["vs_gradient_deg"] = stats(angular_error(decoded[valid], normals[valid]))
    rep["invalid_gradients"] = int(result.stats.get("invalid_gradients", int((~valid).sum())))
    rep["coverage"] = float(np.mean(result.coverage))
    rep["texels_covered"] = int(np.sum(result.coverage))
    rep["miss_texels"] = int(np.sum(result.miss))
    rep["miss_fraction"] = float(np.sum(result.miss) / max(1, np.sum(result.coverage)))
    ground = _Truth(baker, truth, fine, truth_colors)
    truth_n, truth_c = ground(tx)
    # the fine mesh's own face normals there: what its exact SDF's gradient is on its surface
    own_faces = None if ground.face is None else np.asarray(fine.face_normals, dtype=np.float64)[ground.face]
    if ground.label:
        rep["truth"] = ground.label
    if ground.hidden is not None and ground.hidden.any():
        # samples whose nearest source surface is buried in another shell: never seen, left out of every figure
        # against the truth and the baseline and of the error maps
        rep["hidden_texels"] = int(ground.hidden.sum())
        keep = np.flatnonzero(~ground.hidden)
        tx, decoded, normals, valid, truth_n = _texel_subset(tx, keep), decoded[keep], normals[keep], valid[keep], \
            truth_n[keep]
        truth_c = None if truth_c is None else truth_c[keep]
        own_faces = None if own_faces is None else own_faces[keep]
        replaced, neural, neural_colors = (None if a is None else a[keep] for a in (replaced, neural, neural_colors))
        baseline = _baseline_subset(baseline, keep)
        n = len(keep)
    err = None
    if truth_n is not None:
        err = angular_error(decoded, truth_n)
        rep["vs_truth_deg"] = stats(err)
        rep["gradient_vs_truth_deg"] = stats(angular_error(normals, truth_n))
        rep["geometric_vs_truth_deg"] = stats(angular_error(tx.normal, truth_n))
        if own_faces is not None:
            rep["faces_vs_truth_deg"] = stats(angular_error(own_faces, truth_n))
        if neural is not None:  # a hybrid bake: what ∇f alone would have given, where it was evaluated or
            # interpolated (not at the texels of cells given up to the classical bake: NaN)
            known = np.isfinite(neural).all(axis=1)
            rep["neural_vs_truth_deg"] = stats(angular_error(neural[known], truth_n[known]))
    if result.hybrid is not None:
        rep["hybrid"] = {k: result.stats.get(k) for k in ("hybrid_samples", "hybrid_texels", "hybrid_fraction",
                                                          "hybrid_color_texels", "hybrid_color_fraction")
                         if k in result.stats}
        if replaced is not None and err is not None and replaced.any():
            rep["hybrid"]["replaced_vs_truth_deg"] = stats(err[replaced])
    if result.albedo is not None and truth_c is not None:
        k = min(3, truth_c.shape[1])
        ours = linear_to_srgb(result.albedo[tx.pixel[:, 0], tx.pixel[:, 1], :k].astype(np.float64))
        rep["color_psnr_db"] = psnr(_quantise(ours, bits), linear_to_srgb(truth_c[:, :k]))
        neural_c = neural_colors if full else None
        if neural_c is not None:  # a hybrid bake that decided colours: what the texture network alone gives
            known = np.isfinite(neural_c).all(axis=1)  # (not at given-up cells' texels)
            rep["neural_color_psnr_db"] = psnr(
                _quantise(linear_to_srgb(neural_c[known, :k].astype(np.float64)), bits),
                linear_to_srgb(truth_c[known, :k]))
    rep["seams"] = seam_discontinuity(
        baker.mesh, baker.tangents, result.normal_map, result.albedo,
        normal_space=baker.normal_space, y_convention=baker.y_convention,
    )
    if baseline_fn is not None:
        baseline = baseline_fn(tx)
    base_err = None
    if baseline is not None:
        b: dict = {"seconds": baseline["seconds"], "fallback": baseline["fallback"], "cage": baseline["cage"],
                   "samples": n}
        if truth_n is not None:
            base_err = angular_error(baseline["normals"], truth_n)
            b["vs_truth_deg"] = stats(base_err)
        if baseline.get("colors") is not None and truth_c is not None:
            k = min(3, truth_c.shape[1])
            # quantised as its map would store it, like the bake's own colours above
            b["color_psnr_db"] = psnr(_quantise(linear_to_srgb(baseline["colors"][:, :k].astype(np.float64)), bits),
                                      linear_to_srgb(truth_c[:, :k]))
        rep["baseline"] = b
    rep["seconds"] = {**result.stats.get("seconds", {}), **(timings or {})}
    measured = [k for k in SAMPLED_FIGURES if _has(rep, k)]
    if pick is not None:
        note = (f"one texel of each {step}×{step} block, at a seeded position ({n} of {total} texel samples): "
                f"{', '.join(measured)} and the error maps; all other figures over every texel")
    elif sampled:
        note = (f"sampled {n} of {total} texel samples (uniform, seed {result.sample.seed}): "
                f"{', '.join(measured)}; all other figures and the error maps over every texel")
    else:
        note = f"all {total} texel samples"
    rep["sampling"] = {
        "samples": n,
        "of": total,
        "seed": result.sample.seed if not full else None,
        "lattice_step": step if pick is not None else None,
        "sampled": measured if sampled else [],
        "note": note,
    }
    if out_dir is not None:
        from ..io.images import write_image

        out_dir = Path(out_dir)
        shape = result.coverage.shape
        err_img = _ErrorImage(shape, step=step) if truth_n is not None else None
        # the baseline's map needs its normals at every (lattice) texel: all of them cached, or baseline_fn per band
        base_img = _ErrorImage(shape, step=step) if base_err is not None and (full or baseline_fn is not None) \
            else None
        if full:
            if err_img is not None:
                err_img.add(err, tx)
            if base_img is not None:
                base_img.add(base_err, tx)
        elif err_img is not None:
            every = _stream_error_maps(result, baker, ground, baseline_fn, bits, err_img, base_img)
            if every is not None and "baseline" in rep:
                rep["baseline"]["all_texels"] = every
        files = []
        if err_img is not None:
            write_image(out_dir / "error_normal.png", err_img.image(), colour="data", fast=True)
            files.append("error_normal.png")
        if base_img is not None:
            write_image(out_dir / "error_baseline.png", base_img.image(), colour="data", fast=True)
            files.append("error_baseline.png")
        write_image(out_dir / "miss.png", result.miss.astype(np.float32), colour="data", fast=True)
        files.append("miss.png")
        if result.hybrid is not None:
            write_image(out_dir / "hybrid.png", result.hybrid.astype(np.float32), colour="data", fast=True)
            files.append("hybrid.png")
        if getattr(result, "hybrid_color", None) is not None:
            write_image(out_dir / "hybrid_color.png", result.hybrid_color.astype(np.float32), colour="data", fast=True)
            files.append("hybrid_color.png")
        rep["files"] = files
        rep["error_map_scale_deg"] = ERROR_MAP_MAX_DEG
    return rep


def lattice_step(shape: tuple[int, int]) -> int:
    """The report's lattice step of a map of ``shape`` (H, W): 1 up to
    :data:`~neural_bake.constants.REPORT_LATTICE_SIDE`, else ceil(side / it)."""
    return max(1, -(-max(int(shape[0]), int(shape[1])) // REPORT_LATTICE_SIDE))


def _block_offsets(pix: np.ndarray, step: int, seed: int) -> np.ndarray:
    """(N,) int64: for each texel of ``pix`` (N, 2) (rows, columns), the position (row × step + column) within its
    ``step``×``step`` block of the texel the block's lattice takes: a seeded hash of the block, drawn once per
    block of the rows ``pix`` spans (not per texel) and read for each texel."""
    from .baker import sample_keys

    if len(pix) == 0:
        return np.zeros(0, dtype=np.int64)
    br, bc = pix[:, 0] // step, pix[:, 1] // step
    r0, n_cols = int(br.min()), int(bc.max()) + 1
    rows = np.arange(r0, int(br.max()) + 1, dtype=np.int64)
    blocks = (rows[:, None] * np.int64(1 << 31) + np.arange(n_cols, dtype=np.int64)[None, :]).reshape(-1)
    table = (sample_keys(blocks, seed) % np.uint64(step * step)).astype(np.int64).reshape(len(rows), n_cols)
    return table[br - r0, bc]


def lattice_offsets(pixels: np.ndarray, step: int, seed: int = 0) -> np.ndarray:
    """(N, 2) int64: the (row, column) within its ``step``×``step`` block of the texel each block's lattice
    takes, for the blocks of ``pixels`` (N, 2) (texel rows and columns): a seeded pseudo-random position per
    block, the same whichever texels ask."""
    off = _block_offsets(np.asarray(pixels, dtype=np.int64), step, seed)
    return np.stack([off // step, off % step], axis=1)


def on_lattice(texels, step: int, seed: int = 0) -> np.ndarray:
    """Indices of the samples of ``texels`` on the report's lattice: in each ``step``×``step`` block of texels,
    the texel at a seeded pseudo-random position (:func:`lattice_offsets`), so every texel is as likely to be
    measured whatever else lies on a regular lattice (an adaptive bake's evaluated nodes do: rows and columns
    of even multiples)."""
    pix = np.asarray(texels.pixel, dtype=np.int64)
    return np.flatnonzero((pix[:, 0] % step) * step + pix[:, 1] % step == _block_offsets(pix, step, seed))


def _texel_subset(texels, pick: np.ndarray):
    """The :class:`~neural_bake.mesh.texels.TexelSet` of the samples ``pick`` of ``texels`` (its coverage kept)."""
    import dataclasses

    from .baker import _TEXEL_FIELDS

    return dataclasses.replace(texels, **{k: np.take(np.asarray(getattr(texels, k)), pick, axis=0)
                                          for k in _TEXEL_FIELDS})


def _baseline_subset(baseline: dict | None, pick: np.ndarray) -> dict | None:
    """A :func:`baseline_bake` result on the samples ``pick`` of the texels it was run on."""
    if baseline is None:
        return None
    return {**baseline, **{k: None if baseline.get(k) is None else baseline[k][pick]
                           for k in ("normals", "colors", "points", "hit", "distance")}}


def _has(rep: dict, key: str) -> bool:
    head, _, tail = key.partition(".")
    return head in rep and (not tail or tail in rep[head])


def _stream_error_maps(result, baker, ground: _Truth, baseline_fn, bits, err_img: _ErrorImage,
                       base_img: _ErrorImage | None) -> dict | None:
    """Error maps of a streamed bake over every texel: the layout's bands rasterised again (no network
    evaluation), the final map decoded and compared with the truth (and the baseline run) band by band.
    Returns the baseline's totals over all samples (or None without ``baseline_fn``)."""
    seconds, fallback, count = 0.0, 0, 0
    step = err_img.step
    for band in baker.bands():
        if step > 1:
            band = _texel_subset(band, on_lattice(band, step))
        if band.n_samples == 0:
            continue
        truth_n, _ = ground(band, colours=False)
        seen = 1.0 if ground.hidden is None else (~ground.hidden).astype(np.float64)  # hidden samples: no error
        decoded = decode_map(result.normal_map, band, baker.normal_space, baker.y_convention, bits)
        err_img.add(angular_error(decoded, truth_n) * seen, band)
        if baseline_fn is not None and base_img is not None:
            b = baseline_fn(band)
            base_img.add(angular_error(b["normals"], truth_n) * seen, band)
            seconds += b["seconds"]["total"]
            fallback += b["fallback"]
            count += band.n_samples
    if baseline_fn is None:
        return None
    return {"samples": count, "seconds": seconds, "fallback": fallback,
            "samples_per_second": count / seconds if seconds > 0 else None}
