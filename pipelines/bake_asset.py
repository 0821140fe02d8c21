"""Bake one asset: fine mesh + fitted fields -> coarse mesh, maps, GLB and quality report in a folder.

The job behind `neural-bake bake` and the demo: load, coarsen (decimate / march / keep), unwrap, bake the
neural normals (and colours) per texel and per vertex, run the classical mesh-to-mesh baseline on the same
texels, measure errors, and write everything. The output folder is committed as a unit
(:class:`neural_bake.io.outdir.OutputFolder`): files are written into a staging folder beside it, which
replaces the old folder in one exchange at the end; a failed or killed run leaves the output folder as it
was, and a second run into the same folder fails at once naming the first.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from typing import Callable

from neural_bake.constants import ADAPTIVE_TOLERANCE_DEG, HYBRID_DETAIL_SIDE

from neural_bake.bake.job import FORMATS, MAPS, MODEL_ONLY_COARSE

__all__ = ["BakeAssetConfig", "bake_asset", "bake_config", "check_config", "PRESETS", "MAPS", "FORMATS",
           "MODEL_ONLY_COARSE"]


@dataclass
class BakeAssetConfig:
    """Settings of :func:`bake_asset`; one line per field (the CLI options mirror them)."""

    coarse: str = "decimate:2000"
    """Coarse mesh: decimate:FACES, decimate:RATIO, march:RESOLUTION, level:I:RESOLUTION (a nested sequence's level I marched) or keep."""
    maps: str | None = None
    """Comma-separated maps: normal, albedo (needs a texture model), vertex; None: normal[,albedo]."""
    formats: str = "glb"
    """Comma-separated asset files of the baked maps: glb, usd (a stage beside the loose maps), usdz (usd and usdz need the extra usd)."""
    size: int = 2048
    """Map side in texels."""
    texture: str | None = None
    """Base-colour image for a mesh whose file names none (ground truth of the report)."""
    normal_space: str = "tangent"
    """"tangent" (glTF, per-texel TBN) or "object" normal map."""
    directx: bool = False
    """DirectX convention: green points down (-Y)."""
    bits: int = 8
    """Bit depth of the loose PNG maps (the GLB embeds 8-bit PNGs)."""
    exr: bool = False
    """Also write the maps as float EXR."""
    supersample: int = 1
    """s×s samples per texel."""
    padding: str = "pull-push"
    """Edge padding of the charts: pull-push, dilate or none."""
    delta: float | None = None
    """Nesting band half-width δ (unit frame) for the miss map; None: the model file's δ, if any."""
    baseline: bool = True
    """Also run the classical mesh-to-mesh bake (open3d rays) on the same texels."""
    cage: float | None = None
    """Baseline ray distance (unit frame; None: 0.05)."""
    truth: str = "auto"
    """Ground truth of the report: auto (analytic if the mesh is a bundled sample), mesh, sample:NAME."""
    cache_texels: bool | None = None
    """Keep every texel sample in memory (report over all of them); False streams them band by band (report
    on a seeded uniform subsample); None: cache up to 2**23 samples (2048² with supersample 2)."""
    report_samples: int = 1 << 18
    """Texel samples a streamed bake keeps for the report's per-sample errors (uniform, seed 0)."""
    force: bool = False
    """Bake even when the SDF does not describe the mesh (frames differ, or median |f| on its surface too large)."""
    hybrid: bool = True
    """Texels where the neural field is not faithful take the classical mesh-to-mesh normal (hybrid bake)."""
    hybrid_tol: float | None = None
    """Hybrid bake: |f| at the source surface above this (unit frame) is not faithful (None: 0.01, constants.HYBRID_SDF_TOL)."""
    hybrid_angle: float | None = None
    """Hybrid bake: ∇f this many degrees off the source normal is not faithful (None: 5, constants.HYBRID_ANGLE_DEG)."""
    hybrid_color_tol: float | None = None
    """Hybrid bake with --texture-model: a neural colour this far (CIEDE2000 ΔE) from the source texture's at the same point takes the source's (None: 2, constants.HYBRID_COLOR_DELTA_E; inf: no ΔE rule; colours stay neural when hybrid_color_within is inf too)."""
    hybrid_color_psnr: float | None = None
    """Hybrid bake with --texture-model: a neural colour whose PSNR against the source texture's at the same point (sRGB, dB) is below this takes the source's, so the colours' PSNR against the source is at least this (None: no such rule)."""
    hybrid_color_within: float | None = None
    """Hybrid bake with --texture-model: the dB of PSNR the colours may lose against a classical transfer into the same map: the neural colours closest to the source texture's are kept while their summed squared difference stays within that share of the map's quantisation noise, the rest take the source's (None: 0, constants.HYBRID_COLOR_WITHIN_DB: a neural colour stays only where the map stores the transfer's value; inf: no such rule)."""
    hybrid_decide: str = "lattice"
    """Hybrid bake: decide at the samples the adaptive bake evaluates and around the unfaithful ones (lattice), or at every sample (all)."""
    hybrid_detail: int = HYBRID_DETAIL_SIDE
    """Hybrid bake without an albedo map: a lattice cell at most this many texels wide whose fields vary too fast to interpolate, with the classical rays hitting the source at all its nodes, takes the classical normal (0: never; constants.HYBRID_DETAIL_SIDE)."""
    adaptive: bool = True
    """Evaluate the fields on a coarse lattice per chart, refined where interpolation would exceed the tolerance."""
    tolerance_deg: float = ADAPTIVE_TOLERANCE_DEG
    """Adaptive bake: largest angle (degrees) between interpolated normals and what the fields give."""
    precision: str = "auto"
    """Hidden GEMMs of the networks: fp32, or auto (bfloat16 where measured faster and within 0.05° of float32)."""
    device: str | None = None
    """Torch device of the networks ("cpu", "cuda", …; None: the CPU); the texels follow them there."""
    layout_cache: bool = True
    """Reuse the coarse mesh and UV layout an earlier run made from the same mesh (or model), coarse spec and size, kept in layouts/ of the cache folder ($NEURAL_BAKE_CACHE_DIR, else $XDG_CACHE_HOME/neural_bake or ~/.cache/neural_bake); no: make them anew and keep nothing."""


#: Bake presets (fields over the defaults), the names of :mod:`neural_bake.fit.presets`; what they cost:
#: BENCHMARKS.md.
PRESETS: dict[str, dict] = {
    "quick": {"coarse": "decimate:1000", "size": 512},
    "default": {"coarse": "decimate:2000", "size": 2048},
    "high": {"coarse": "decimate:5000", "size": 4096, "supersample": 2},
}


def bake_config(preset: str | None = None, **overrides) -> BakeAssetConfig:
    """A BakeAssetConfig from a preset name (:data:`PRESETS`) and field overrides, checked
    (:func:`check_config`); NeuralBakeError for an unknown preset or field or a bad value."""
    from neural_bake.configs import preset_config

    cfg = preset_config(BakeAssetConfig, PRESETS, preset, overrides, what="bake")
    check_config(cfg)
    return cfg


def check_config(cfg: BakeAssetConfig) -> None:
    """Every setting of ``cfg`` checked, before any work or allocation: NeuralBakeError naming the parameter."""
    from neural_bake.errors import NeuralBakeError
    from neural_bake.limits import check_map_samples

    check_map_samples(cfg.size, cfg.supersample)  # before any texel is allocated
    _parse_formats(cfg.formats)
    if cfg.maps is not None:
        _parse_maps(cfg.maps)
    for name, allowed in (("normal_space", ("tangent", "object")), ("padding", ("pull-push", "dilate", "none")),
                          ("bits", (8, 16)), ("hybrid_decide", ("lattice", "all")), ("precision", ("fp32", "auto"))):
        if getattr(cfg, name) not in allowed:
            raise NeuralBakeError(f"{name} {getattr(cfg, name)!r}: must be one of {', '.join(map(str, allowed))}",
                                  parameter=name)
    d = cfg.hybrid_detail
    if isinstance(d, bool) or not isinstance(d, int) or d < 0:
        raise NeuralBakeError(f"hybrid_detail {d!r}: must be a whole number of texels ≥ 0 (0: never)",
                              parameter="hybrid_detail")
    if cfg.delta is not None and not cfg.delta > 0:
        raise NeuralBakeError(f"delta {cfg.delta}: must be a positive distance", parameter="delta")
    r = cfg.report_samples
    if isinstance(r, bool) or int(r) != r or r < 1:
        raise NeuralBakeError(f"report_samples {r!r}: must be a positive integer", parameter="report_samples")
    tol, angle, colour, within = _hybrid_tolerances(cfg)
    if not tol > 0:
        raise NeuralBakeError(f"hybrid_tol {tol}: must be a positive distance", parameter="hybrid_tol")
    if not 0 < angle <= 180:
        raise NeuralBakeError(f"hybrid_angle {angle}: must be in (0, 180] degrees", parameter="hybrid_angle")
    if not colour > 0:
        raise NeuralBakeError(f"hybrid_color_tol {colour}: must be a positive ΔE (inf: no ΔE rule)",
                              parameter="hybrid_color_tol")
    if not within >= 0:
        raise NeuralBakeError(f"hybrid_color_within {within}: must be a number of dB ≥ 0 (inf: no such rule)",
                              parameter="hybrid_color_within")
    p = cfg.hybrid_color_psnr
    if p is not None and not (isinstance(p, (int, float)) and not isinstance(p, bool) and 0 < p < float("inf")):
        raise NeuralBakeError(f"hybrid_color_psnr {p!r}: must be a positive number of dB", parameter="hybrid_color_psnr")
    if cfg.adaptive:
        from neural_bake.bake.adaptive_options import AdaptiveOptions

        AdaptiveOptions(tolerance_deg=cfg.tolerance_deg)  # names tolerance_deg
    truth = cfg.truth
    if truth not in ("auto", "mesh") and not truth.startswith("sample:"):
        raise NeuralBakeError(f"truth {truth!r}: expected auto, mesh or sample:NAME", parameter="truth")
    if truth.startswith("sample:"):
        from neural_bake.samples.shapes import get_sample

        try:  # an unknown name is refused before any work
            get_sample(truth.split(":", 1)[1])
        except NeuralBakeError as exc:
            raise NeuralBakeError(f"truth {truth}: {exc}", parameter="truth") from None
    from neural_bake.mesh.coarse import parse_coarse

    parse_coarse(cfg.coarse)


def bake_asset(mesh, sdf_path, out, config: BakeAssetConfig | None = None, *, texture_model=None,
               coarse_mesh=None, log: Callable[[str], None] = print) -> dict:
    """Bake ``mesh`` (a file) with the SDF model ``sdf_path`` (and ``texture_model``) into folder ``out``.

    The steps of :mod:`neural_bake.bake.job` in one output folder: load → coarse → bake → write → report.
    ``mesh`` None bakes from the model alone: the coarse mesh is the model marched (``config.coarse`` march or
    level; a decimate spec becomes :data:`MODEL_ONLY_COARSE`, keep is refused), there is no hybrid fallback and
    no classical baseline, and the report measures the map against ∇f of the finest level.

    ``out`` is a path (committed as a unit when the bake succeeds) or an entered
    :class:`~neural_bake.io.outdir.OutputFolder` whose set the bake is part of (the caller commits it).

    Writes OUT/asset.glb (coarse mesh, tangents, baseColorTexture, normalTexture; ``config.formats`` adds
    OUT/asset.usd and OUT/asset.usdz), the loose maps, error maps and OUT/report.json; returns the report.
    ``log`` receives one-line progress messages. ``coarse_mesh``: a ``(Mesh, info)`` pair made earlier (by the
    batch's coarse stage, from ``config.coarse``) to bake onto instead of making it here.
    Raises NeuralBakeError (one line) for bad input, before anything is written.
    """
    from neural_bake.errors import NeuralBakeError
    from neural_bake.mesh.coarse import parse_coarse

    cfg = config or BakeAssetConfig()
    check_config(cfg)
    t_start = time.perf_counter()
    maps = _parse_maps(cfg.maps if cfg.maps is not None else ("normal,albedo" if texture_model else "normal"))
    if "albedo" in maps and texture_model is None:
        raise NeuralBakeError("maps albedo: needs a texture model file, and none is given (or drop albedo from maps)",
                              parameter="maps")
    formats = _parse_formats(cfg.formats)
    if "usd" in formats or "usdz" in formats:
        from neural_bake.io.usd import import_pxr

        import_pxr()  # usd-core missing: one line saying how to install it, before any work
    coarse, truth = cfg.coarse, cfg.truth
    kind = parse_coarse(coarse)[0]
    if mesh is None:
        if kind == "keep":
            raise NeuralBakeError(f"coarse {coarse!r}: keep bakes onto the source mesh, and none is given; use "
                                  f"march:RESOLUTION or level:I:RESOLUTION", parameter="coarse")
        if truth.startswith("sample:"):
            raise NeuralBakeError(f"truth {truth!r}: compares a source mesh with a sample, and none is given",
                                  parameter="truth")
        if kind == "decimate":
            log(f"no source mesh: the coarse mesh is the model marched ({MODEL_ONLY_COARSE}), not {coarse}")
            coarse = MODEL_ONLY_COARSE
    keep = kind == "keep"
    from neural_bake.bake import preload as preloading
    from neural_bake.geometry import raycasting_prefetched

    # the source mesh is read, decimated and unwrapped in a forked process while torch is imported here
    # (before any thread starts); None where that is not safe, and the bake does it itself
    pre = None if mesh is None or coarse_mesh is not None else preloading.start(
        str(mesh), texture_image=cfg.texture, coarse=coarse,
        layout_size=cfg.size if any(m in maps for m in ("normal", "albedo")) else None,
        layout_cache=bool(cfg.layout_cache))
    try:
        # rays will be cast: their library loads while the bake loads, coarsens and rasterises
        with raycasting_prefetched() if mesh is not None and (cfg.hybrid or cfg.baseline) \
                else contextlib.nullcontext():
            return _bake_in_folder(mesh, sdf_path, out, cfg, maps, formats, coarse, keep, texture_model,
                                   coarse_mesh, t_start, log, pre)
    finally:
        if pre is not None:
            pre.close()


def _bake_in_folder(mesh, sdf_path, out, cfg: BakeAssetConfig, maps, formats, coarse: str, keep: bool,
                    texture_model, coarse_mesh, t_start: float, log, pre=None) -> dict:
    """:func:`bake_asset`'s steps in its output folder (its settings checked)."""
    from neural_bake.bake import job
    from neural_bake.io.atomic import atomic_write_text
    from neural_bake.io.jsonio import dumps
    from neural_bake.io.outdir import OutputFolder

    truth = cfg.truth
    nested = isinstance(out, OutputFolder)
    folder = out if nested else OutputFolder(out)
    with contextlib.nullcontext(folder.stage) if nested else folder as stage:  # lock, leftovers, staging
        texel_maps = any(m in maps for m in ("normal", "albedo"))
        if texel_maps:  # its pages fault in on another core while it loads
            job.reserve_heap(cfg.size, cfg.supersample)
        inputs = job.load_inputs(mesh, sdf_path, texture_model, coarse=coarse, texture_image=cfg.texture,
                                 truth=truth, delta=cfg.delta, device=cfg.device, force=cfg.force, log=log,
                                 preload=pre)
        timings: dict[str, float] = {"load": inputs.seconds}
        layouts = None
        if cfg.layout_cache:
            from neural_bake.mesh.layout_cache import LayoutCache

            layouts = LayoutCache()
        coarse_m, coarse_info = job.make_coarse(inputs, coarse, coarse_mesh, cache=layouts)
        # a decimation the preloading process made cost this process nothing (its seconds: report["preload"])
        preloaded = inputs.preloaded is not None and inputs.preloaded.made(coarse_m)
        timings["coarse"] = 0.0 if preloaded else coarse_info["seconds"]
        log(f"coarse mesh ({coarse}): {coarse_info['faces']} faces, {coarse_info['vertices']} vertices"
            + (" (from the layout cache)" if coarse_info.get("cached") else ""))
        if texel_maps and coarse_m.uv is not None:
            job.check_uv_area(mesh, coarse_m.uv, cfg.size)
        written: list[str] = []
        report: dict = {"mesh": None if mesh is None else str(mesh), "sdf": folder.shown(sdf_path),
                        "texture_model": texture_model and folder.shown(texture_model), "coarse": coarse_info,
                        "maps": maps, "sdf_check": inputs.sdf_check,
                        "preload": None if pre is None else pre.summary()}
        if texel_maps:
            baked = _bake_texels(inputs, coarse_m, cfg, maps=maps, keep=keep, log=log, layouts=layouts)
            timings["prepare"] = baked.seconds

            def write():
                t0 = time.perf_counter()
                out = job.write_maps(stage, baked, inputs, maps=maps, formats=formats, bits=cfg.bits, exr=cfg.exr,
                                     normal_space=cfg.normal_space, directx=cfg.directx, keep=keep)
                return out, time.perf_counter() - t0

            # the maps are written while the report measures them: PNG and EXR encoding release the
            # interpreter lock, and the report's own work is mostly single-threaded
            ((files, kept), write_s), (rep, report_files) = _beside(
                write, lambda: job.report_maps(stage, baked, inputs, baseline=cfg.baseline, cage=cfg.cage,
                                               truth=truth, bits=cfg.bits, timings=timings, coarse=coarse, log=log))
            timings["write"] = rep["seconds"]["write"] = write_s
            written += files + report_files
            if kept is not None:
                report["kept"] = kept
            report.update(rep)
            for w in report["warnings"]:
                log(f"warning: {w}")
        if "vertex" in maps:
            files, report["vertex"] = job.bake_vertex_colours(stage, inputs, coarse_m, keep=keep)
            written += files
        timings["total"] = time.perf_counter() - t_start
        report["seconds_total"] = timings["total"]
        report["files"] = written + ["report.json"]
        atomic_write_text(stage / "report.json", dumps(report))
    _log_summary(report, mesh, folder.out, written, log)
    return report


def _beside(first: Callable, second: Callable) -> tuple:
    """(``first()``, ``second()``), ``first`` run in a worker thread while ``second`` runs here. Both have
    finished when this returns or raises; an error of ``second`` is raised before one of ``first``."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="bake-write") as pool:  # leaving it waits
        pending = pool.submit(first)
        other = second()
        return pending.result(), other


def _bake_texels(inputs, coarse_m, cfg: BakeAssetConfig, *, maps: list[str], keep: bool, log, layouts=None):
    """The texel maps (:func:`neural_bake.bake.job.bake_maps`) with the config's settings, and what they did
    said in ``log``."""
    from neural_bake.bake import job
    from neural_bake.bake.adaptive_options import AdaptiveOptions

    hybrid_tol, hybrid_angle, hybrid_color_tol, hybrid_color_within = _hybrid_tolerances(cfg)
    baked = job.bake_maps(
        inputs, coarse_m, maps=maps, size=cfg.size, supersample=cfg.supersample, normal_space=cfg.normal_space,
        directx=cfg.directx, padding=cfg.padding, cache_texels=cfg.cache_texels, report_samples=cfg.report_samples,
        keep=keep, hybrid=cfg.hybrid, hybrid_tol=hybrid_tol, hybrid_angle=hybrid_angle,
        hybrid_color_tol=hybrid_color_tol, hybrid_color_psnr=cfg.hybrid_color_psnr,
        hybrid_color_within=hybrid_color_within, bits=cfg.bits, hybrid_decide=cfg.hybrid_decide,
        hybrid_detail=cfg.hybrid_detail, cage=cfg.cage, keep_baseline=cfg.baseline,
        adaptive=AdaptiveOptions(tolerance_deg=cfg.tolerance_deg) if cfg.adaptive else None,
        precision=cfg.precision, layout_cache=layouts)
    res, hybrid, size = baked.result, baked.hybrid, cfg.size
    if hybrid is not None:
        hs = hybrid.summary()
        adaptive_stats = res.stats.get("adaptive") or {}
        sourced, rim = adaptive_stats.get("cells_source_detail") or {}, adaptive_stats.get("rim", 0)
        log(f"hybrid bake: {res.stats['hybrid_texels']} texels ({100 * res.stats['hybrid_fraction']:.1f} %) "
            f"took the classical normal (|f| at the source > {hybrid_tol:g} or ∇f > {hybrid_angle:g}° off"
            + (f"; or in one of {hs['detail_cells']} cells too fine for the lattice" if hs["detail_cells"] else "")
            + (f"; or in one of {sum(sourced.values())} cells where the source has finer detail" if sourced else "")
            + (f"; or {rim} samples next to given-up cells" if rim else "")
            + ")")
        if baked.colour_tol is not None or baked.colour_psnr is not None or baked.colour_within is not None:
            rules = ([f"ΔE > {baked.colour_tol:g}"] if baked.colour_tol is not None else []) + (
                [f"PSNR < {baked.colour_psnr:g} dB"] if baked.colour_psnr is not None else []) + (
                [f"beyond {baked.colour_within:g} dB of a classical transfer: {hs['color_within_replaced']} texels"]
                if baked.colour_within is not None else [])
            log(f"hybrid colours: {res.stats['hybrid_color_texels']} texels "
                f"({100 * res.stats['hybrid_color_fraction']:.1f} %) took the source texture's colour "
                f"({' or '.join(rules)})")
        if hs["lattice_check"] is not None and hs["decided_fraction"] < 1:
            c = hs["lattice_check"]
            log(f"hybrid decided at {100 * hs['decided_fraction']:.1f} % of the samples (the evaluated ones and "
                f"around the unfaithful); a full decision at {c['samples']} others sampled found "
                f"{c['missed']} more")
        e = hs["estimate_check"]
        if e["estimated"]:
            log(f"hybrid: f at the source estimated to first order at {e['estimated']} samples (short rays); "
                f"evaluated at {e['samples']} of them as a check, {e['missed']} estimated wrongly")
    log(f"baked {res.stats['texels_covered']} texels of {size}x{size} in {res.stats['seconds']['bake']:.1f} s"
        f" ({res.stats['invalid_gradients']} zero gradients, {res.stats['miss_texels']} texels off the band)")
    prec = res.stats["precision"]
    log(f"precision: {prec['sdf']} ({prec['sdf_reason']})")
    control = res.stats.get("error_control")
    if control is not None and res.stats["adaptive"] is not None:
        ad = res.stats["adaptive"]
        faces = 100 * ad["face_nodes"] / max(1, ad["samples"])
        log(f"adaptive evaluation: {100 * res.stats['evaluated_fraction']:.1f} % of the texel samples evaluated "
            f"(of which {faces:.1f} % at points inside faces, from which "
            f"{100 * ad['face_interpolated'] / max(1, ad['samples']):.1f} % were interpolated); "
            f"against a full evaluation at {control['samples']} sampled: median "
            f"{control['angle_deg']['median'] or 0:.4f}°, max {control['angle_deg']['max'] or 0:.4f}°")
    return baked


def _hybrid_tolerances(cfg: BakeAssetConfig) -> tuple[float, float, float, float]:
    """The hybrid's (|f| tolerance, angle, colour ΔE, colour dB within the classical transfer): the config's, or
    the library's defaults where None."""
    from neural_bake.constants import HYBRID_ANGLE_DEG, HYBRID_COLOR_DELTA_E, HYBRID_COLOR_WITHIN_DB, HYBRID_SDF_TOL

    return (HYBRID_SDF_TOL if cfg.hybrid_tol is None else cfg.hybrid_tol,
            HYBRID_ANGLE_DEG if cfg.hybrid_angle is None else cfg.hybrid_angle,
            HYBRID_COLOR_DELTA_E if cfg.hybrid_color_tol is None else cfg.hybrid_color_tol,
            HYBRID_COLOR_WITHIN_DB if cfg.hybrid_color_within is None else cfg.hybrid_color_within)


def _log_summary(report: dict, mesh, out_dir, written: list[str], log) -> None:
    """The bake's closing lines: the map's error (against ∇f without a source mesh) and the files written."""
    summary = report.get("vs_truth_deg") or {}
    grad = report.get("vs_gradient_deg") or {}
    if mesh is None and grad.get("median") is not None:
        log(f"normal map vs ∇f of the finest level (no source mesh, no baseline): median {grad['median']:.2f}°, "
            f"p95 {grad['p95']:.2f}°")
    if summary.get("median") is not None:
        line = f"normal error vs truth: median {summary['median']:.2f}°, p95 {summary['p95']:.2f}°"
        b = report.get("baseline", {}).get("vs_truth_deg")
        if b:
            line += f" (baseline median {b['median']:.2f}°, p95 {b['p95']:.2f}°)"
        sampling = report.get("sampling") or {}
        if sampling.get("sampled"):
            line += f" on {sampling['samples']} sampled of {sampling['of']} texel samples"
        log(line)
    log(f"wrote {out_dir}/: {', '.join(written + ['report.json'])}")


def _parse_formats(spec) -> list[str]:
    """The asset formats of a ``formats`` spec ("glb,usd"); NeuralBakeError naming ``formats`` otherwise."""
    from neural_bake.errors import NeuralBakeError

    names = [m.strip() for m in str(spec).split(",") if m.strip()]
    bad = [m for m in names if m not in FORMATS]
    if bad or not names:
        raise NeuralBakeError(f"formats {spec!r}: unknown format {bad[0] if bad else '(none)'!r} (choose from "
                              f"{', '.join(FORMATS)})", parameter="formats")
    return list(dict.fromkeys(names))


def _parse_maps(spec: str) -> list[str]:
    """The maps of a ``maps`` spec ("normal,albedo"); NeuralBakeError naming ``maps`` otherwise."""
    from neural_bake.errors import NeuralBakeError

    maps = [m.strip() for m in spec.split(",") if m.strip()]
    bad = [m for m in maps if m not in MAPS]
    if bad or not maps:
        raise NeuralBakeError(f"maps {spec!r}: unknown map {bad[0] if bad else '(none)'!r} (choose from "
                              f"{', '.join(MAPS)})", parameter="maps")
    return maps
