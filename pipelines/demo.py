"""The README's first command: the main job end to end on a bundled sample.

samples -> fit a SIREN SDF -> distil a nested sequence (a coarse level, δ per level) -> fit a
texture MLP on the surface -> coarse mesh -> unwrap -> bake the fine level's normals and the colours at
the fine level's closest points per texel -> GLB + maps + report, with the classical mesh-to-mesh bake
measured on the same texels: the nested path of the README. Only library calls; the CLI verb
`neural-bake demo` is a thin wrapper.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

__all__ = ["DemoConfig", "run_demo"]


@dataclass
class DemoConfig:
    """Settings of :func:`run_demo`; the defaults take about 4 minutes on a 2-core CPU (BENCHMARKS.md)."""

    sample: str = "bumpy_sphere"
    """Bundled sample to bake (see `neural-bake samples`)."""
    sdf_preset: str = "128x2"
    """SDF preset: quick, default or high (192x3 for 2 minutes, 192x3 for 5, 256x4 for 10), or a network WxD of
    `fit sdf` (the demo's 128x2 at its 2.5-minute budget, which the bundled sample's figures were measured with)."""
    sdf_minutes: float = 2.5
    """Time budget of the SDF fit, minutes."""
    sdf_surface_normals: str = "face"
    """Normals the SDF fit's normal term targets (``SdfFitConfig.surface_normals``). "face", not the fit's
    default "vertex": the sample is a known smooth surface and the demo scores against it, where a face normal
    is an unbiased sample of that surface and the mesh's vertex normals blur its bumps (docs/findings.md)."""
    nested_levels: str = "32x1"
    """Coarse levels of the nested sequence, WIDTHxDEPTH coarse to fine, comma-separated."""
    nested_minutes: float = 0.5
    """Time budget of each coarse level's distillation, minutes."""
    nested_boxes: int = 2000
    """Box budget of the range-analysis certification of each level's δ (0: estimated δ only)."""
    texture_preset: str = "quick"
    """Texture preset: quick, default or high."""
    texture_minutes: float = 1.0
    """Time budget of the texture fit, minutes."""
    coarse: str = "decimate:2000"
    """Coarse mesh spec (decimate:FACES, level:I:RESOLUTION (the nested sequence's level I marched),
    march:RESOLUTION, keep); BENCHMARKS.md says why decimation is the default."""
    size: int = 1024
    """Map side in texels."""
    seed: int = 0
    """Seed of the fits (same seed, same models)."""
    progress: bool = True
    """Progress bars on stderr during the fits."""
    report_views: int = 8
    """Turntable views of the HTML report (0: no report)."""
    compare: bool = True
    """End with the classical bake of the same texels (classical/) and a page comparing both bakes (compare/)."""
    device: str | None = None
    """Torch device of the fits ("cpu", "cuda", …; None: the CPU)."""


def run_demo(out_dir, config: DemoConfig | None = None, *, log: Callable[[str], None] = print) -> dict:
    """Run the demo into ``out_dir`` (created if missing); return the summary it also writes as demo.json."""
    from neural_bake.io.outdir import OutputFolder
    from neural_bake.samples.generate import sample_path

    cfg = config or DemoConfig()
    out = Path(out_dir)
    out.absolute().parent.mkdir(parents=True, exist_ok=True)
    mesh_path = sample_path(cfg.sample)  # an unknown sample is refused before any work
    folder = OutputFolder(out)  # models, bake and summary are committed together
    with folder as stage:
        summary = _demo(stage, folder, mesh_path, cfg, log)
    log(f"done in {summary['seconds_total']:.0f} s: open {out / 'asset.glb'} in any glTF viewer; "
        f"figures in {out / 'report.json'} and {out / 'demo.json'}")
    if "report" in summary:
        log(f"check the bake by eye: {summary['report']}")
    if "comparison" in summary:
        log(f"the neural and the classical bake side by side: {summary['comparison']}")
    return summary


def _demo(stage: Path, folder, mesh_path: Path, cfg: DemoConfig, log: Callable[[str], None]) -> dict:
    """The demo's steps, writing into the staging folder ``stage`` of ``folder`` (committed by the caller)."""
    from neural_bake.fit.metrics import sdf_metrics
    from neural_bake.fit.nested import fit_nested, nested_config
    from neural_bake.fit.sdf import fit_sdf
    from neural_bake.fit.texture import fit_texture, texture_metrics
    from neural_bake.io.atomic import atomic_write_text
    from neural_bake.io.jsonio import dumps
    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.pipelines.bake_asset import BakeAssetConfig, bake_asset
    from neural_bake.samples.shapes import get_sample, unit_frame_normals

    t_all = time.perf_counter()
    mesh = load_mesh(mesh_path)
    log(f"[1/5] sample {cfg.sample}: {mesh_path.name}, {mesh.n_faces} faces, texture "
        f"{'x'.join(map(str, mesh.texture.shape[:2])) if mesh.texture is not None else 'none'}")

    log(f"[2/5] fitting the SDF ({cfg.sdf_preset}, {cfg.sdf_minutes:g} min budget)")
    sdf = fit_sdf(mesh, preset=cfg.sdf_preset, minutes=cfg.sdf_minutes, seed=cfg.seed, progress=cfg.progress,
                  device=cfg.device, surface_normals=cfg.sdf_surface_normals)
    sdf_path = stage / "sdf.safetensors"
    sdf.save(sdf_path)
    sample = get_sample(cfg.sample)
    sdf_q = sdf_metrics(sdf.model, mesh, n=50_000, resolution=128,
                        truth_normal=unit_frame_normals(sample, mesh.frame))
    log(f"      {sdf.steps} steps in {sdf.seconds:.0f} s: Chamfer-L1 {sdf_q['chamfer_l1']:.4f}, Hausdorff "
        f"{sdf_q['hausdorff']:.4f} (unit frame)")
    log(f"      median normal error {sdf_q['normal_truth_median_deg']:.2f}° against the analytic surface "
        f"(the mesh's own faces: {sdf_q['mesh_normal_truth_median_deg']:.2f}°), "
        f"{sdf_q['normal_median_deg']:.2f}° against the faces")

    log(f"[3/5] distilling the nested sequence ({cfg.nested_levels}, {cfg.nested_minutes:g} min per level)")
    seq = fit_nested(sdf, nested_config(levels=cfg.nested_levels, minutes=cfg.nested_minutes, steps=1_000_000,
                                        seed=cfg.seed, certify=cfg.nested_boxes > 0,
                                        max_boxes=max(cfg.nested_boxes, 1), stability_samples=(1_000, 10_000),
                                        progress=cfg.progress), mesh=mesh)
    nested_path = stage / "nested.safetensors"
    seq.save(nested_path)
    for i, info in enumerate(seq.levels_info):
        log(f"      level {i} ({info['width']}x{info['depth']}): δ = {info['delta']:.4f} ({info['delta_source']})")

    log(f"[4/5] fitting the texture ({cfg.texture_preset}, {cfg.texture_minutes:g} min budget; the bake reads it at "
        f"the closest points of f = 0, at most level 0's δ away)")
    tex = fit_texture(mesh, seq, preset=cfg.texture_preset, minutes=cfg.texture_minutes, seed=cfg.seed,
                      progress=cfg.progress, device=cfg.device or "cpu")
    tex_path = stage / "texture.safetensors"
    tex.save(tex_path)
    tex_q = texture_metrics(tex.field(), mesh, seq, delta=tex.delta, n=50_000)
    log(f"      {tex.steps} steps in {tex.seconds:.0f} s: surface PSNR {tex_q['surface_psnr']:.1f} dB")

    from neural_bake.io.usd import USD_INSTALL, usd_available

    formats = "glb,usd,usdz" if usd_available() else "glb"  # the USD beside the GLB when usd-core is there
    log(f"[5/5] baking the nested sequence onto a coarse mesh ({cfg.coarse}, {cfg.size}² maps; {formats})")
    if formats == "glb":
        log(f"      no USD: {USD_INSTALL} adds asset.usd and asset.usdz")
    # force: the sequence was fitted on this very mesh; a short budget's rough fit is baked and reported, with
    # the mesh check's figures in the report, rather than refused
    report = bake_asset(str(mesh_path), str(nested_path), folder,
                        BakeAssetConfig(coarse=cfg.coarse, size=cfg.size, force=True, formats=formats),
                        texture_model=str(tex_path), log=lambda m: log("      " + m))
    summary = {
        "config": asdict(cfg),
        "sdf": {"steps": sdf.steps, "seconds": sdf.seconds, "distance_error": sdf.distance_error, **sdf_q},
        "nested": {"levels": [f"{i['width']}x{i['depth']}" for i in seq.levels_info], "deltas": seq.deltas,
                   "delta_sources": [i.get("delta_source") for i in seq.levels_info], "steps": seq.iterations},
        "texture": {"steps": tex.steps, "seconds": tex.seconds, "delta": tex.delta,
                    **{k: v for k, v in tex_q.items() if isinstance(v, (int, float, str))}},
        "bake": {k: report.get(k) for k in ("vs_truth_deg", "vs_gradient_deg", "coarse_vs_truth_deg", "baseline",
                                            "albedo_psnr", "coverage", "seconds_total") if k in report},
        "seconds_total": time.perf_counter() - t_all,
        "outputs": sorted({p.name for p in stage.iterdir() if not p.name.startswith(".")} | {"demo.json"}),
    }
    atomic_write_text(stage / "demo.json", dumps(summary))
    if cfg.report_views > 0:  # the HTML report is part of the set: written before the commit
        from neural_bake.view.report import ReportConfig, write_asset_report

        index = write_asset_report(stage, ReportConfig(views=cfg.report_views), log=lambda m: None,
                                   name=folder.out)
        summary["report"] = folder.shown(index)
    if cfg.compare:  # the classical bake of the same coarse mesh, layout and texels, then both on one page
        from neural_bake.pipelines.bake_classical import bake_classical
        from neural_bake.view.comparison import CompareConfig, write_comparison

        log("      classical bake of the same texels (mesh-to-mesh rays) and the comparison page")
        bake_classical(stage, stage / "classical", log=lambda m: log("      " + m))
        index = write_comparison([stage, stage / "classical"], stage / "compare",
                                 CompareConfig(views=max(1, cfg.report_views)), names=["neural", "classical"],
                                 log=lambda m: None)
        summary["comparison"] = folder.shown(index)
    return summary
