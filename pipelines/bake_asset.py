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
from pathlib import Path
from typing import Callable

from neural_bake.constants import ADAPTIVE_TOLERANCE_DEG

__all__ = ["BakeAssetConfig", "bake_asset", "bake_config", "PRESETS", "MAPS", "FORMATS", "MODEL_ONLY_COARSE"]

MAPS = ("normal", "albedo", "vertex")
#: Files of the baked asset: asset.glb, asset.usd (a stage referencing the loose maps), asset.usdz (a package).
FORMATS = ("glb", "usd", "usdz")
#: The coarse mesh of a bake without a source mesh when the spec says decimate (nothing to decimate): the
#: model marched at this resolution (the finest level of a nested sequence).
MODEL_ONLY_COARSE = "march:128"


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
    """Hybrid bake: |f| at the source surface above this (unit frame) is not faithful (None: HYBRID_SDF_TOL)."""
    hybrid_angle: float | None = None
    """Hybrid bake: ∇f this many degrees off the source normal is not faithful (None: HYBRID_ANGLE_DEG)."""
    hybrid_color_tol: float | None = None
    """Hybrid bake with --texture-model: a neural colour this far (CIEDE2000 ΔE) from the source texture's at the same point takes the source's (None: HYBRID_COLOR_DELTA_E; inf: colours stay neural)."""
    hybrid_decide: str = "lattice"
    """Hybrid bake: decide at the samples the adaptive bake evaluates and around the unfaithful ones (lattice), or at every sample (all)."""
    adaptive: bool = True
    """Evaluate the fields on a coarse lattice per chart, refined where interpolation would exceed the tolerance."""
    tolerance_deg: float = ADAPTIVE_TOLERANCE_DEG
    """Adaptive bake: largest angle (degrees) between interpolated normals and what the fields give."""
    precision: str = "auto"
    """Hidden GEMMs of the networks: fp32, or auto (bfloat16 where measured faster and within 0.05° of float32)."""
    device: str | None = None
    """Torch device of the networks ("cpu", "cuda", …; None: the CPU); the texels follow them there."""


#: Bake presets (fields over the defaults), the names of :mod:`neural_bake.fit.presets`; what they cost:
#: BENCHMARKS.md.
PRESETS: dict[str, dict] = {
    "quick": {"coarse": "decimate:1000", "size": 512},
    "default": {"coarse": "decimate:2000", "size": 2048},
    "high": {"coarse": "decimate:5000", "size": 4096, "supersample": 2},
}


def bake_config(preset: str | None = None, **overrides) -> BakeAssetConfig:
    """A BakeAssetConfig from a preset name (:data:`PRESETS`) and field overrides; NeuralBakeError for an
    unknown preset or field."""
    from neural_bake.configs import preset_config
    from neural_bake.errors import NeuralBakeError

    cfg = preset_config(BakeAssetConfig, PRESETS, preset, overrides, what="bake")
    from neural_bake.limits import check_map_samples

    check_map_samples(cfg.size, cfg.supersample)  # before any texel is allocated
    _parse_formats(cfg.formats)
    for name, allowed in (("normal_space", ("tangent", "object")), ("padding", ("pull-push", "dilate", "none")),
                          ("bits", (8, 16)), ("hybrid_decide", ("lattice", "all"))):
        if getattr(cfg, name) not in allowed:
            raise NeuralBakeError(f"{name} {getattr(cfg, name)!r}: must be one of {', '.join(map(str, allowed))}",
                                  parameter=name)
    return cfg


def bake_asset(mesh, sdf_path, out, config: BakeAssetConfig | None = None, *, texture_model=None,
               coarse_mesh=None, log: Callable[[str], None] = print) -> dict:
    """Bake ``mesh`` (a file) with the SDF model ``sdf_path`` (and ``texture_model``) into folder ``out``.

    ``mesh`` None bakes from the model alone: the coarse mesh is the model marched (``config.coarse`` march or
    level; a decimate spec becomes :data:`MODEL_ONLY_COARSE`, keep is refused), there is no hybrid fallback and
    no classical baseline, and the report measures the map against ∇f of the finest level.

    ``out`` is a path (committed as a unit when the bake succeeds) or an entered
    :class:`~neural_bake.io.outdir.OutputFolder` whose set the bake is part of (the caller commits it).

    Writes OUT/asset.glb (coarse mesh, tangents, baseColorTexture, normalTexture; ``config.formats`` adds
    OUT/asset.usd and OUT/asset.usdz), the loose maps, error maps and OUT/report.json; returns the report. ``log`` receives one-line progress messages.
    ``coarse_mesh``: a ``(Mesh, info)`` pair made earlier (by the batch's coarse stage, from ``config.coarse``)
    to bake onto instead of making it here.
    Raises NeuralBakeError (one line) for bad input, before anything is written.
    """
    import numpy as np

    from neural_bake.bake.baker import Baker, bake_vertices
    from neural_bake.mesh.coarse import parse_coarse
    from neural_bake.mesh.coarse import coarse_mesh as make_coarse_mesh
    from neural_bake.bake.export import export_glb, export_vertex_ply
    from neural_bake.bake.report import bake_report
    from neural_bake.errors import MeshError, NeuralBakeError
    from neural_bake.io.asset import read_asset, shading_mesh
    from neural_bake.io.atomic import atomic_write_text
    from neural_bake.io.images import write_image
    from neural_bake.io.jsonio import dumps
    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.io.outdir import OutputFolder
    from neural_bake.limits import check_map_samples

    cfg = config or BakeAssetConfig()
    coarse, size, texture, normal_space, directx = cfg.coarse, cfg.size, cfg.texture, cfg.normal_space, cfg.directx
    bits, exr, supersample, padding, delta = cfg.bits, cfg.exr, cfg.supersample, cfg.padding, cfg.delta
    baseline, cage, truth, maps_spec = cfg.baseline, cfg.cage, cfg.truth, cfg.maps
    report_samples = cfg.report_samples
    tex_path = texture_model
    t_start = time.perf_counter()
    if maps_spec is None:
        maps_spec = "normal,albedo" if tex_path else "normal"
    maps = _parse_maps(maps_spec)
    formats = _parse_formats(cfg.formats)
    if "usd" in formats or "usdz" in formats:
        from neural_bake.io.usd import import_pxr

        import_pxr()  # usd-core missing: one line saying how to install it, before any work
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
    check_map_samples(size, supersample)  # the map's side and samples, named by parameter
    if "albedo" in maps and tex_path is None:
        raise NeuralBakeError("--maps albedo needs --texture-model MODEL (or drop albedo from --maps)")
    if delta is not None and not delta > 0:
        raise NeuralBakeError(f"--delta {delta}: must be a positive distance")
    if isinstance(report_samples, bool) or int(report_samples) != report_samples or report_samples < 1:
        raise NeuralBakeError(f"report_samples {report_samples!r}: must be a positive integer")
    from neural_bake.constants import HYBRID_ANGLE_DEG, HYBRID_COLOR_DELTA_E, HYBRID_SDF_TOL

    hybrid_tol = HYBRID_SDF_TOL if cfg.hybrid_tol is None else cfg.hybrid_tol
    hybrid_angle = HYBRID_ANGLE_DEG if cfg.hybrid_angle is None else cfg.hybrid_angle
    hybrid_color_tol = HYBRID_COLOR_DELTA_E if cfg.hybrid_color_tol is None else cfg.hybrid_color_tol
    if not hybrid_tol > 0:
        raise NeuralBakeError(f"--hybrid-tol {hybrid_tol}: must be a positive distance")
    if not 0 < hybrid_angle <= 180:
        raise NeuralBakeError(f"--hybrid-angle {hybrid_angle}: must be in (0, 180] degrees")
    if not hybrid_color_tol > 0:
        raise NeuralBakeError(f"--hybrid-color-tol {hybrid_color_tol}: must be a positive ΔE (inf: colours stay neural)")
    from neural_bake.bake.adaptive import AdaptiveOptions

    adaptive = AdaptiveOptions(tolerance_deg=cfg.tolerance_deg) if cfg.adaptive else None
    if cfg.precision not in ("fp32", "auto"):
        raise NeuralBakeError(f"precision must be fp32 or auto, got {cfg.precision!r}", parameter="precision")
    if truth not in ("auto", "mesh") and not truth.startswith("sample:"):
        raise NeuralBakeError(f"--truth {truth!r}: expected auto, mesh or sample:NAME")
    if truth.startswith("sample:"):
        from neural_bake.samples.shapes import get_sample

        try:  # an unknown name is refused before any work
            get_sample(truth.split(":", 1)[1])
        except NeuralBakeError as exc:
            raise NeuralBakeError(f"--truth {truth}: {exc}") from None
    nested = isinstance(out, OutputFolder)
    folder = out if nested else OutputFolder(out)
    out_dir = folder.out
    with contextlib.nullcontext(folder.stage) if nested else folder as stage:  # lock, leftovers, staging
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        sdf_file = _load_field(sdf_path, "--sdf", "sdf", cfg.device)
        sdf = _sdf_for(sdf_file, coarse)
        tex = _load_field(tex_path, "--texture-model", "texture", cfg.device) if tex_path else None
        if delta is None and sdf.delta is None and tex is not None and tex.delta is not None:
            delta = tex.delta  # the band the texture was fitted in: where neural attribute mapping is valid
            log(f"nesting band δ = {delta:g} (unit frame) from {Path(tex_path).name}")
        fine = reference = asset = None
        keep = parse_coarse(coarse)[0] == "keep"
        sdf_check: dict = {"passed": None, "note": "no source mesh to check the SDF against"}
        if mesh is not None:
            fine = load_mesh(mesh, texture)
            if truth.startswith("sample:"):
                _sample_truth(mesh, fine, truth)  # a mesh that is not the sample is refused before the bake
            asset = read_asset(mesh, fine)
            # the asset's own shading (its vertex normals, split at hard edges) is the normals' reference, when it has one
            reference = fine if asset.corner_normals is None else shading_mesh(fine, asset.corner_normals)
            from neural_bake.bake.agreement import check_sdf_describes_mesh

            sdf_check = check_sdf_describes_mesh(fine, sdf, force=cfg.force, option="--force")
            if not sdf_check["passed"]:
                log(f"--force: baking an SDF that fails the mesh check (frames differ by "
                    f"{sdf_check['frame_mismatch']:.3g}, median |f| on the mesh {sdf_check['median_abs_f']:.4g})")
        timings["load"] = time.perf_counter() - t0
        if tex is not None:  # a texture model of another object is refused like an SDF of another mesh
            from neural_bake.fields import check_texture_matches_sdf

            sdf_check["texture"] = check_texture_matches_sdf(tex, sdf_file, force=cfg.force, option="--force",
                                                             sdf_name=Path(sdf_path).name)
        try:
            coarse_m, coarse_info = (coarse_mesh if coarse_mesh is not None
                                     else make_coarse_mesh(reference if keep else fine, coarse, sdf_file))
        except NeuralBakeError as exc:
            if mesh is not None:
                raise
            raise NeuralBakeError(f"{sdf_path}: no surface to bake from the model alone ({exc})") from None
        timings["coarse"] = coarse_info["seconds"]
        log(f"coarse mesh ({coarse}): {coarse_info['faces']} faces, {coarse_info['vertices']} vertices")
        if any(m in maps for m in ("normal", "albedo")) and coarse_m.uv is not None:
            _check_uv_area(mesh, coarse_m.uv, size)

        written: list[str] = []
        report: dict = {"mesh": None if mesh is None else str(mesh), "sdf": folder.shown(sdf_path),
                        "texture_model": tex_path and folder.shown(tex_path), "coarse": coarse_info, "maps": maps,
                        "sdf_check": sdf_check}
        texel_maps = [m for m in maps if m in ("normal", "albedo")]
        if texel_maps:
            t0 = time.perf_counter()
            baker = Baker(coarse_m, size, supersample=supersample, normal_space=normal_space,
                          y_convention="directx" if directx else "opengl",
                          padding=None if padding == "none" else padding, cache_texels=cfg.cache_texels)
            timings["prepare"] = time.perf_counter() - t0
            hybrid = None
            # colours follow the hybrid rule where a texture is baked and the source has one to take colours from
            colour_tol = hybrid_color_tol if (tex is not None and "albedo" in maps and reference is not None
                                              and reference.uv is not None and reference.texture is not None
                                              and np.isfinite(hybrid_color_tol)) else None
            if cfg.hybrid and ("normal" in maps or colour_tol is not None) and reference is not None:
                from neural_bake.bake.hybrid import HybridFallback

                hybrid = HybridFallback(reference, sdf, sdf_tol=hybrid_tol, angle_deg=hybrid_angle, cage=cage,
                                        keep_baseline=baseline and baker.cache, decide=cfg.hybrid_decide,
                                        color_tol=colour_tol)
            res = baker.bake(sdf, tex if "albedo" in maps else None, delta=delta, report_samples=int(report_samples),
                             hybrid=hybrid, adaptive=adaptive, precision=cfg.precision,
                             texture_at="point" if keep else "surface")
            if res.stats["texels_covered"] == 0:
                raise MeshError(f"{mesh}: the coarse mesh's UV layout covers no texel of the {size}x{size} map")
            if hybrid is not None:
                log(f"hybrid bake: {res.stats['hybrid_texels']} texels ({100 * res.stats['hybrid_fraction']:.1f} %) "
                    f"took the classical normal (|f| at the source > {hybrid_tol:g} or ∇f > {hybrid_angle:g}° off)")
                hs = hybrid.summary()
                if colour_tol is not None:
                    log(f"hybrid colours: {res.stats['hybrid_color_texels']} texels "
                        f"({100 * res.stats['hybrid_color_fraction']:.1f} %) took the source texture's colour "
                        f"(ΔE > {colour_tol:g})")
                if hs["lattice_check"] is not None and hs["decided_fraction"] < 1:
                    c = hs["lattice_check"]
                    log(f"hybrid decided at {100 * hs['decided_fraction']:.1f} % of the samples (the evaluated ones and "
                        f"around the unfaithful); a full decision at {c['samples']} others sampled found "
                        f"{c['missed']} more")
            log(f"baked {res.stats['texels_covered']} texels of {size}x{size} in {res.stats['seconds']['bake']:.1f} s"
                       f" ({res.stats['invalid_gradients']} zero gradients, {res.stats['miss_texels']} texels off the band)")
            prec = res.stats["precision"]
            log(f"precision: {prec['sdf']} ({prec['sdf_reason']})")
            control = res.stats.get("error_control")
            if control is not None and res.stats["adaptive"] is not None:
                log(f"adaptive evaluation: {100 * res.stats['evaluated_fraction']:.1f} % of the texel samples evaluated; "
                    f"against a full evaluation at {control['samples']} sampled: median "
                    f"{control['angle_deg']['median'] or 0:.4f}°, max {control['angle_deg']['max'] or 0:.4f}°")
            t0 = time.perf_counter()
            nbits = int(bits)
            if "normal" in maps:
                write_image(stage / "normal.png", res.normal_map, colour="data", bits=nbits)
                written.append("normal.png")
                if exr:
                    write_image(stage / "normal.exr", res.normal_map, colour="data", bits=32)
                    written.append("normal.exr")
            if res.albedo is not None:
                write_image(stage / "albedo.png", res.albedo, colour="srgb", bits=nbits)
                written.append("albedo.png")
                if exr:
                    write_image(stage / "albedo.exr", res.albedo, colour="linear", bits=32)
                    written.append("albedo.exr")
            # a glTF normalTexture is tangent space, +Y up: an object-space or DirectX map stays loose
            gltf_normals = "normal" in maps and normal_space == "tangent" and not directx
            # onto the asset itself, the GLB keeps what was not baked: its base colour, normal, AO/roughness/metal
            kept_maps = asset.maps if keep else {}
            albedo_out = res.albedo if res.albedo is not None or not keep else fine.texture
            if "glb" in formats:
                # the 8-bit PNGs just written are what the GLB embeds: their bytes, not a second encoding
                png_files = {} if nbits != 8 else {
                    **({"normal_map": stage / "normal.png"} if gltf_normals else {}),
                    **({"albedo": stage / "albedo.png"} if res.albedo is not None and albedo_out is res.albedo
                       else {})}
                export_glb(stage / "asset.glb", baker.mesh, normal_map=res.normal_map if gltf_normals else None,
                           albedo=albedo_out, tangents=baker.tangents, material_maps=kept_maps,
                           same_image=None if asset is None else asset.same_image,
                           material_factors=None if asset is None else asset.factors, png_files=png_files)
                written.append("asset.glb")
            for fmt in ("usd", "usdz"):  # the same mesh and maps; the stage references the loose PNGs
                if fmt in formats:
                    from neural_bake.bake.usd_export import export_usd

                    export_usd(stage / f"asset.{fmt}", baker.mesh,
                               base_colour=stage / "albedo.png" if res.albedo is not None else None,
                               normal_map=stage / "normal.png" if gltf_normals else None)
                    written.append(f"asset.{fmt}")
            if keep:
                report["kept"] = {
                    "vertex_normals": "the asset's" if asset.corner_normals is not None else "computed",
                    "uv": "the asset's" if fine.uv is not None else "unwrapped",
                    "maps": sorted((["base_colour"] if res.albedo is None and fine.texture is not None else [])
                                   + [k for k in kept_maps if not (k == "normal" and gltf_normals)])}
            timings["write"] = time.perf_counter() - t0
            base = base_fn = None
            if baseline and reference is not None:
                from neural_bake.bake.baseline import baseline_bake, raycasting_scene

                if res.normals is not None:  # every texel sample in memory: one baseline bake of them all
                    base = hybrid.baseline() if hybrid is not None else None  # the hybrid's, if it kept it
                    if base is None:
                        base = baseline_bake(baker.mesh, reference, baker.texels, cage=cage)
                    log(f"baseline (mesh-to-mesh rays): {base['seconds']['total']:.1f} s, "
                        f"{base['fallback']} closest-point fallbacks")
                else:  # streamed: the report runs it on its sampled texels and band by band for the error map
                    scene = raycasting_scene(reference)

                    def base_fn(texels):
                        return baseline_bake(baker.mesh, reference, texels, cage=cage, scene=scene)

            normals_fn, colours_fn, sample_name = (None, None, None) if mesh is None else \
                _sample_truth(mesh, baker.mesh, truth)
            rep = bake_report(res, baker, truth=normals_fn, fine=None if normals_fn else reference,
                              truth_colors=colours_fn, baseline=base, baseline_fn=base_fn, bits=nbits,
                              timings=timings, out_dir=stage)
            if sample_name:
                rep["truth"] = f"analytic ({sample_name} sample)"
            if mesh is None:
                rep["truth"] = ("none: no source mesh; the map is measured against ∇f of the finest level "
                                "(vs_gradient_deg), and there is no classical baseline")
            every = rep.get("baseline", {}).get("all_texels")
            if every:
                log(f"baseline (mesh-to-mesh rays) over all {every['samples']} samples: {every['seconds']:.1f} s, "
                    f"{every['fallback']} closest-point fallbacks")
            if rep["sampling"]["sampled"]:
                log(f"report: {rep['sampling']['note']}")
            written += rep.pop("files", [])
            if hybrid is not None:
                rep.setdefault("hybrid", {}).update(hybrid.summary())
            report.update(rep)
            report["warnings"] = _fidelity_warnings(report, coarse)
            for w in report["warnings"]:
                log(f"warning: {w}")
        if "vertex" in maps:
            t0 = time.perf_counter()
            vb = bake_vertices(coarse_m, sdf, tex, texture_at="point" if keep else "surface")
            colors = None if vb["colors"] is None else np.clip(vb["colors"][:, :3], 0, 1)
            export_glb(stage / "vertex.glb", coarse_m, normals=vb["normals"], vertex_colors=colors)
            export_vertex_ply(stage / "vertex.ply", coarse_m, normals=vb["normals"], vertex_colors=colors)
            written += ["vertex.glb", "vertex.ply"]
            report["vertex"] = {"vertices": coarse_m.n_vertices, "invalid_gradients": vb["invalid"],
                                "seconds": time.perf_counter() - t0}
        timings["total"] = time.perf_counter() - t_start
        report["seconds_total"] = timings["total"]
        report["files"] = written + ["report.json"]
        atomic_write_text(stage / "report.json", dumps(report))
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


    return report


def _check_uv_area(path, uv, size: int) -> None:
    """MeshError if a mesh's own UV layout ((F, 3, 2) per-corner UVs) covers less than one texel of the map."""
    import numpy as np

    from neural_bake.errors import MeshError

    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 3, 2)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area = 0.5 * float(np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum())
    if not area * size * size >= 1.0:
        raise MeshError(f"{path}: its UV layout covers {area:.3g} of the UV square, less than one texel of the "
                        f"{size}x{size} map; bake with --coarse decimate or march, which unwrap a new layout")


def _load_field(path, option: str, want: str, device=None):
    """The field file given to ``option``: an SDF or nested sequence (``want="sdf"``) or a texture field, its
    networks on ``device``."""
    from neural_bake.errors import ModelFileError
    from neural_bake.fields import NestedSequence, SdfField, TextureField, load_field

    if not Path(path).exists():
        raise ModelFileError(f"{option} {path}: no such model file")
    field = load_field(path, device=device)
    types, expected = ((SdfField, NestedSequence), "an SDF (kind 'sdf' or a nested sequence)") if want == "sdf" \
        else ((TextureField,), "a texture field (kind 'texture')")
    if not isinstance(field, types):
        raise ModelFileError(f"{option} {path}: a {type(field).__name__} file, expected {expected}")
    return field


def _sdf_for(field, coarse: str):
    """The SdfField to bake: a nested sequence gives its fine f with the band δ of the level the coarse mesh
    is marched from (``level:I:RES``), else of its coarsest level (the widest band)."""
    from neural_bake.mesh.coarse import parse_coarse
    from neural_bake.fields import to_sdf_field

    kind, value = parse_coarse(coarse)
    return to_sdf_field(field, band_level=value[0] if kind == "level" else 0)


def _fidelity_warnings(report: dict, coarse: str) -> list[str]:
    """One-line warning on what the normal map gives: the coarse mesh is the source itself (then its own normals
    are the reference and no map beats them), or the map does not beat the coarse mesh's own normals (median
    angle to the truth)."""
    if coarse == "keep":
        return [f"--coarse keep: the map is baked onto the source mesh itself, so it can at best reproduce the "
                f"asset's own normals (map median {(report.get('vs_truth_deg') or {}).get('median') or 0:.2f}° off them)"]
    out = []
    ours, own = (report.get(k) or {} for k in ("vs_truth_deg", "geometric_vs_truth_deg"))
    if ours.get("median") is not None and own.get("median") is not None and ours["median"] >= own["median"]:
        out.append(f"the normal map (median {ours['median']:.2f}°) does not beat the coarse mesh's own normals "
                   f"(median {own['median']:.2f}°)")
    return out


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
    from neural_bake.errors import NeuralBakeError

    maps = [m.strip() for m in spec.split(",") if m.strip()]
    bad = [m for m in maps if m not in MAPS]
    if bad or not maps:
        raise NeuralBakeError(f"--maps {spec!r}: unknown map {bad[0] if bad else '(none)'!r} (choose from {', '.join(MAPS)})")
    return maps


def _sample_truth(path: str, mesh, choice: str):
    """(normals(points) callable, colours callable, name) of an analytic sample the mesh is, or Nones."""
    import numpy as np

    from neural_bake.errors import NeuralBakeError
    from neural_bake.samples.shapes import SAMPLES, get_sample, unit_frame_normals

    if choice == "mesh":
        return None, None, None
    name = choice.split(":", 1)[1] if choice.startswith("sample:") else Path(path).stem
    if name not in SAMPLES:
        if choice.startswith("sample:"):
            get_sample(name)  # raises naming the known samples
        return None, None, None
    sample = get_sample(name)
    src = mesh.frame.to_source(mesh.vertices[:: max(1, mesh.n_vertices // 500)])
    tol = 0.02 * float(np.ptp(mesh.frame.to_source(mesh.vertices), axis=0).max())
    if np.abs(sample.sdf(src)).max() > tol:
        if choice.startswith("sample:"):
            raise NeuralBakeError(f"--truth {choice}: {path} is not the {name} sample (vertices off its surface)")
        return None, None, None

    normals = unit_frame_normals(sample, mesh.frame)

    def colours(p):
        return sample.albedo(mesh.frame.to_source(p))

    return normals, colours, name
