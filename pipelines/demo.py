"""The README's first command: the main job end to end on a bundled sample.

samples -> fit a SIREN SDF -> fit a gradient-orthogonal texture MLP -> coarsen (decimate) -> unwrap ->
bake the neural normals and colours per texel -> GLB + maps + report, with the classical mesh-to-mesh bake
measured on the same texels. Only library calls; the CLI verb `neural-bake demo` is a thin wrapper.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

__all__ = ["DemoConfig", "run_demo"]


@dataclass
class DemoConfig:
    """Settings of :func:`run_demo`; the defaults take about 4 minutes on a 2-core CPU (3 min 46 s measured)."""

    sample: str = "bumpy_sphere"
    """Bundled sample to bake (see `neural-bake samples`)."""
    sdf_preset: str = "128x2"
    """SDF network preset (W x D)."""
    sdf_minutes: float = 2.5
    """Time budget of the SDF fit, minutes."""
    texture_preset: str = "fast"
    """Texture network preset."""
    texture_minutes: float = 1.0
    """Time budget of the texture fit, minutes."""
    coarse: str = "decimate:2000"
    """Coarse mesh spec (decimate:FACES, march:RESOLUTION, keep)."""
    size: int = 1024
    """Map side in texels."""
    seed: int = 0
    """Seed of the fits (same seed, same models)."""
    progress: bool = True
    """Progress bars on stderr during the fits."""
    report_views: int = 8
    """Turntable views of the HTML report (0: no report)."""


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
    return summary


def _demo(stage: Path, folder, mesh_path: Path, cfg: DemoConfig, log: Callable[[str], None]) -> dict:
    """The demo's steps, writing into the staging folder ``stage`` of ``folder`` (committed by the caller)."""
    from neural_bake.fit.metrics import sdf_metrics
    from neural_bake.fit.sdf import fit_sdf
    from neural_bake.fit.texture import fit_texture, texture_metrics
    from neural_bake.io.atomic import atomic_write_text
    from neural_bake.io.jsonio import dumps
    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.pipelines.bake_asset import BakeAssetConfig, bake_asset
    from neural_bake.samples.shapes import get_sample, unit_frame_normals

    t_all = time.perf_counter()
    mesh = load_mesh(mesh_path)
    log(f"[1/4] sample {cfg.sample}: {mesh_path.name}, {mesh.n_faces} faces, texture "
        f"{'x'.join(map(str, mesh.texture.shape[:2])) if mesh.texture is not None else 'none'}")

    log(f"[2/4] fitting the SDF ({cfg.sdf_preset}, {cfg.sdf_minutes:g} min budget)")
    sdf = fit_sdf(mesh, preset=cfg.sdf_preset, minutes=cfg.sdf_minutes, seed=cfg.seed, progress=cfg.progress)
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

    log(f"[3/4] fitting the texture ({cfg.texture_preset}, {cfg.texture_minutes:g} min budget, λ > 0)")
    tex = fit_texture(mesh, sdf_path, preset=cfg.texture_preset, minutes=cfg.texture_minutes, seed=cfg.seed,
                      progress=cfg.progress)
    tex_path = stage / "texture.safetensors"
    tex.save(tex_path)
    tex_q = texture_metrics(tex.model, mesh, sdf_path, delta=tex.delta, n=50_000)
    log(f"      {tex.steps} steps in {tex.seconds:.0f} s: surface PSNR {tex_q['surface_psnr']:.1f} dB")

    log(f"[4/4] baking onto a coarse mesh ({cfg.coarse}, {cfg.size}² maps)")
    report = bake_asset(str(mesh_path), str(sdf_path), folder, BakeAssetConfig(coarse=cfg.coarse, size=cfg.size),
                        texture_model=str(tex_path), log=lambda m: log("      " + m))
    summary = {
        "config": asdict(cfg),
        "sdf": {"steps": sdf.steps, "seconds": sdf.seconds, **sdf_q},
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

        index = write_asset_report(stage, ReportConfig(views=cfg.report_views), log=lambda m: None)
        summary["report"] = folder.shown(index)
    return summary
