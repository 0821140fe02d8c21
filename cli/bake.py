"""`neural-bake bake MESH --sdf MODEL -o OUT`: bake neural normals (and colours) onto a coarse mesh (thin verb).

Writes OUT/asset.glb, the loose maps, OUT/report.json and the error maps. Everything is first written into a
temporary folder inside OUT, then each file is moved into place (an atomic rename each) with report.json
last: a failed run leaves OUT as it was.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from pathlib import Path

import click

__all__ = ["command"]

MAPS = ("normal", "albedo", "vertex")


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
    from neural_bake.samples.shapes import SAMPLES, get_sample

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

    def normals(p):
        return sample.normal(mesh.frame.to_source(p))

    def colours(p):
        return sample.albedo(mesh.frame.to_source(p))

    return normals, colours, name


@click.command()
@click.argument("mesh", metavar="MESH", type=click.Path(dir_okay=False))
@click.option("--sdf", "sdf_path", required=True, metavar="MODEL", help="Fine SDF model file (kind 'sdf').")
@click.option("--texture-model", "tex_path", metavar="MODEL", default=None,
              help="Texture model file (kind 'texture'): bakes the albedo map.")
@click.option("--coarse", default="decimate:2000", show_default=True,
              help="Coarse mesh: decimate:FACES, decimate:RATIO, march:RESOLUTION or keep.")
@click.option("--maps", "maps_spec", default=None,
              help="What to bake, comma-separated: normal, albedo (needs --texture-model), vertex (per-vertex "
                   "GLB). Default: normal,albedo with a texture model, else normal.")
@click.option("--size", type=int, default=2048, show_default=True, help="Map side in texels.")
@click.option("--texture", metavar="IMG", default=None,
              help="Base-colour image for a mesh whose file names none (ground truth of the report).")
@click.option("--normal-space", type=click.Choice(["tangent", "object"]), default="tangent", show_default=True,
              help="Tangent-space (glTF) or object-space normal map.")
@click.option("--directx", is_flag=True, help="DirectX convention: green points down (-Y).")
@click.option("--bits", type=click.Choice(["8", "16"]), default="8", show_default=True,
              help="Bit depth of the loose PNG maps (the GLB always embeds 8-bit PNGs).")
@click.option("--exr", is_flag=True, help="Also write the maps as float EXR.")
@click.option("--supersample", type=int, default=1, show_default=True, help="s×s samples per texel.")
@click.option("--padding", type=click.Choice(["pull-push", "dilate", "none"]), default="pull-push",
              show_default=True, help="Edge padding of the charts.")
@click.option("--delta", type=float, default=None,
              help="Nesting band half-width δ (unit frame): texels with |f| > δ are flagged as misses "
                   "(default: the model file's δ, if any).")
@click.option("--baseline/--no-baseline", default=True, help="Also run the classical mesh-to-mesh bake.")
@click.option("--cage", type=float, default=None, help="Baseline ray distance (unit frame; default 0.05).")
@click.option("--truth", default="auto", show_default=True,
              help="Ground truth of the report: auto (analytic if MESH is a bundled sample), mesh, sample:NAME.")
@click.option("-o", "--output", "out", required=True, type=click.Path(file_okay=False), help="Output folder.")
def command(mesh, sdf_path, tex_path, coarse, maps_spec, size, texture, normal_space, directx, bits, exr,
            supersample, padding, delta, baseline, cage, truth, out):
    """Bake the neural normals (and colours) of MESH's fitted fields onto a coarse mesh; write a GLB, maps
    and a quality report into OUT."""
    import numpy as np

    from neural_bake.bake.baker import Baker, bake_vertices, coarse_mesh, parse_coarse
    from neural_bake.bake.export import export_glb, export_vertex_ply
    from neural_bake.bake.fields import load_field
    from neural_bake.bake.report import bake_report
    from neural_bake.errors import NeuralBakeError
    from neural_bake.io.atomic import atomic_write_text
    from neural_bake.io.images import write_image
    from neural_bake.io.mesh_io import load_mesh

    t_start = time.perf_counter()
    if maps_spec is None:
        maps_spec = "normal,albedo" if tex_path else "normal"
    maps = _parse_maps(maps_spec)
    parse_coarse(coarse)
    if size < 1 or size > 16384:
        raise NeuralBakeError(f"--size {size}: must be between 1 and 16384")
    if "albedo" in maps and tex_path is None:
        raise NeuralBakeError("--maps albedo needs --texture-model MODEL (or drop albedo from --maps)")
    if delta is not None and not delta > 0:
        raise NeuralBakeError(f"--delta {delta}: must be a positive distance")
    if truth not in ("auto", "mesh") and not truth.startswith("sample:"):
        raise NeuralBakeError(f"--truth {truth!r}: expected auto, mesh or sample:NAME")
    out_dir = Path(out)
    if out_dir.exists() and not out_dir.is_dir():
        raise NeuralBakeError(f"-o {out}: exists and is not a folder")
    if not out_dir.parent.is_dir():
        raise NeuralBakeError(f"-o {out}: folder {out_dir.parent} does not exist")

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    sdf = load_field(sdf_path, "sdf", argument="--sdf")
    tex = load_field(tex_path, "texture", argument="--texture-model") if tex_path else None
    fine = load_mesh(mesh, texture)
    timings["load"] = time.perf_counter() - t0
    coarse_m, coarse_info = coarse_mesh(fine, coarse, sdf)
    timings["coarse"] = coarse_info["seconds"]
    click.echo(f"coarse mesh ({coarse}): {coarse_info['faces']} faces, {coarse_info['vertices']} vertices")

    created = not out_dir.exists()
    out_dir.mkdir(exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=".bake-", dir=out_dir))
    ok = False
    try:
        written: list[str] = []
        report: dict = {"mesh": str(mesh), "sdf": str(sdf_path), "texture_model": tex_path, "coarse": coarse_info,
                        "maps": maps}
        texel_maps = [m for m in maps if m in ("normal", "albedo")]
        if texel_maps:
            t0 = time.perf_counter()
            baker = Baker(coarse_m, size, supersample=supersample, normal_space=normal_space,
                          y_convention="directx" if directx else "opengl",
                          padding=None if padding == "none" else padding)
            timings["prepare"] = time.perf_counter() - t0
            res = baker.bake(sdf, tex if "albedo" in maps else None, delta=delta)
            click.echo(f"baked {res.stats['texels_covered']} texels of {size}x{size} in {res.stats['seconds']['bake']:.1f} s"
                       f" ({res.stats['invalid_gradients']} zero gradients, {res.stats['miss_texels']} texels off the band)")
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
            export_glb(stage / "asset.glb", baker.mesh, normal_map=res.normal_map if gltf_normals else None,
                       albedo=res.albedo, tangents=baker.tangents)
            written.append("asset.glb")
            timings["write"] = time.perf_counter() - t0
            base = None
            if baseline and baker.texels is not None:
                from neural_bake.bake.baseline import baseline_bake

                base = baseline_bake(baker.mesh, fine, baker.texels, cage=cage)
                click.echo(f"baseline (mesh-to-mesh rays): {base['seconds']['total']:.1f} s, "
                           f"{base['fallback']} closest-point fallbacks")
            if baker.texels is not None:
                normals_fn, colours_fn, sample_name = _sample_truth(mesh, baker.mesh, truth)
                rep = bake_report(res, baker, truth=normals_fn, fine=None if normals_fn else fine,
                                  truth_colors=colours_fn, baseline=base, bits=nbits, timings=timings,
                                  out_dir=stage)
                if sample_name:
                    rep["truth"] = f"analytic ({sample_name} sample)"
                written += rep.pop("files", [])
                report.update(rep)
            else:
                report["bake"] = res.stats
                report["note"] = "map too large for the per-sample report (streamed); errors not measured"
        if "vertex" in maps:
            t0 = time.perf_counter()
            vb = bake_vertices(coarse_m, sdf, tex)
            colors = None if vb["colors"] is None else np.clip(vb["colors"][:, :3], 0, 1)
            export_glb(stage / "vertex.glb", coarse_m, normals=vb["normals"], vertex_colors=colors)
            export_vertex_ply(stage / "vertex.ply", coarse_m, normals=vb["normals"], vertex_colors=colors)
            written += ["vertex.glb", "vertex.ply"]
            report["vertex"] = {"vertices": coarse_m.n_vertices, "invalid_gradients": vb["invalid"],
                                "seconds": time.perf_counter() - t0}
        timings["total"] = time.perf_counter() - t_start
        report["seconds_total"] = timings["total"]
        report["files"] = written + ["report.json"]
        atomic_write_text(stage / "report.json", json.dumps(_finite(report), indent=2, default=_json_default) + "\n")
        for name in written + ["report.json"]:  # each move is an atomic rename; the report comes last
            (stage / name).replace(out_dir / name)
        ok = True
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        if created and not ok:
            shutil.rmtree(out_dir, ignore_errors=True)
    summary = report.get("vs_truth_deg") or {}
    if summary.get("median") is not None:
        line = f"normal error vs truth: median {summary['median']:.2f}°, p95 {summary['p95']:.2f}°"
        b = report.get("baseline", {}).get("vs_truth_deg")
        if b:
            line += f" (baseline median {b['median']:.2f}°, p95 {b['p95']:.2f}°)"
        click.echo(line)
    click.echo(f"wrote {out_dir}/: {', '.join(written + ['report.json'])}")


def _finite(o):
    """JSON has no NaN or infinity: such floats become None (e.g. the PSNR of identical colours)."""
    if isinstance(o, float):
        return o if o == o and abs(o) != float("inf") else None
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    return o


def _json_default(o):
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    return str(o)
