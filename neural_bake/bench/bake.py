"""`neural-bake bench bake`: texel throughput, and error against time for neural and classical baking.

Two tables, measured in the same run:

- ``throughput``: a tangent-space normal map of 1024² and 2048² texels (quick: 256², 512²) from a (256, 3)
  SIREN (random initialisation: the cost of a bake does not depend on the weights) on the bumpy sphere
  decimated to 2,000 faces. Columns: set-up time (unwrap, tangent frames, rasterisation), bake time with
  GEMM normals, texels per second, and the same bake with autograd normals (what a user would otherwise
  write) and the speed-up. Target: 2048² in ≤ 60 s.
- ``error vs time``: the bumpy sphere sample with its ANALYTIC normal field as the SDF field (no trained
  model needed), baked onto decimated coarse meshes of several face counts at several map sizes; the
  angular error (degrees) of the 8-bit map as a renderer decodes it against the analytic normals, beside
  the coarse geometry alone and the classical mesh-to-mesh baseline (open3d rays to the 16k-face sample
  mesh) on the same texels, with both times. ``sdf_model=PATH`` adds rows for a trained SDF model file.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from .common import bytecode_note, last_error_line, load_note, machine_info, run_command

__all__ = ["run"]


def _bumpy():
    from ..io.mesh_io import load_mesh
    from ..samples.generate import sample_path
    from ..samples.shapes import get_sample

    sample = get_sample("bumpy_sphere")
    return sample, load_mesh(sample_path("bumpy_sphere"))


def _analytic_field(sample, frame):
    from ..fields import SdfField
    from ..samples.shapes import unit_frame_normals

    def fn(p):
        return torch.as_tensor(sample.implicit(frame.to_source(p.cpu().numpy())) * frame.scale, dtype=p.dtype)

    normals = unit_frame_normals(sample, frame)

    def grad(p):
        return torch.as_tensor(normals(p.cpu().numpy()), dtype=p.dtype)

    return SdfField(fn, grad, name="bumpy_sphere analytic")


def _stats(err):
    return float(np.median(err)), float(np.percentile(err, 95))


def run(
    quick: bool = False,
    *,
    sizes=None,
    faces=None,
    map_sizes=None,
    throughput_faces: int = 2000,
    autograd: bool = True,
    sdf_model: str | None = None,
    seed: int = 0,
    anchor: bool = True,
    anchor_sizes=None,
    anchor_model=None,
    anchor_mesh=None,
    blender_python=None,
    repeats: int | None = None,
) -> dict:
    """Run the benchmark; returns the result dict (see :mod:`neural_bake.bench.common`).

    Args:
        quick: 256² and 512² throughput maps; coarse meshes of 500 and 2,000 faces at 128² and 256²
            (well under two minutes on an idle 2-core CPU).
        sizes: throughput map sizes (default 1024, 2048).
        faces: coarse face counts of the error table (default 500, 2000, 8000).
        map_sizes: map sizes of the error table (default 256, 512, 1024).
        throughput_faces: face count of the throughput table's coarse mesh.
        autograd: also time the autograd-normals bake in the throughput table.
        sdf_model: a trained SDF model file of the bumpy sphere: extra error rows with its ∇f.
        seed: seed of the random (256, 3) network.
        anchor: run the ``against the anchor`` table (:func:`_anchor`).
        anchor_sizes: its map sizes (default 2048, 4096; quick: 256, 512).
        anchor_model: a (256, 3) SDF model file of the anchor mesh (Spot when the reference data is there,
            else the bumpy sphere sample), or an SDF field; default a randomly initialised (256, 3) SIREN.
        anchor_mesh: another mesh file as the anchor (its SDF: ``anchor_model``), e.g. a mesh of the data folder,
            so the anchor and user's command tables can be read on every asset.
        blender_python: the Python interpreter with ``bpy`` for the Blender rows of the anchor table
            (default: :func:`neural_bake.bench.blender.find_python`); without one the rows are skipped with a note.
        repeats: rounds of the user's command table (our command, then Blender's script, in turn; each figure
            the best of its rounds, with the range); default 3, quick 1.
    """
    from ..bake.baker import Baker
    from ..bake.baseline import baseline_bake
    from ..bake.report import decode_map
    from ..fields import SdfField, load_sdf_field
    from ..geometry import angular_error
    from ..mesh.decimate import decimate
    from ..nets.siren import Siren

    sizes = sizes or ([256, 512] if quick else [1024, 2048])
    faces = faces or ([500, 2000] if quick else [500, 2000, 8000])
    map_sizes = map_sizes or ([128, 256] if quick else [256, 512, 1024])
    sample, fine = _bumpy()
    notes = [
        "timings: one run per row, no repetition",
        "throughput: (256, 3) SIREN with random initialisation (a bake's cost does not depend on the weights)",
    ]

    # -- throughput ------------------------------------------------------------------------------------
    model = Siren(256, 3, generator=torch.Generator().manual_seed(seed))
    gemm_field = SdfField.from_model(model, name="(256,3) GEMM")
    auto_field = SdfField(model, name="(256,3) autograd")  # a plain callable: autograd normals
    coarse = decimate(fine, faces=throughput_faces)
    rows = []
    for size in sizes:
        t0 = time.perf_counter()
        baker = Baker(coarse, size)
        setup = time.perf_counter() - t0
        res = baker.bake(gemm_field)
        s = res.stats
        row = {
            "map": f"{size}²",
            "texels": s["texels_covered"],
            "setup s": setup,
            "bake s": s["seconds"]["bake"],
            "∇f s": s["seconds"]["sdf"],
            "texels/s": s["texels_covered"] / s["seconds"]["bake"],
            "total s": setup + s["seconds"]["bake"],
        }
        if autograd:
            res_a = baker.bake(auto_field)
            row["autograd bake s"] = res_a.stats["seconds"]["bake"]
            row["speed-up"] = row["autograd bake s"] / row["bake s"]
        rows.append(row)
        del baker, res
    if 2048 in sizes:
        r = rows[sizes.index(2048)]
        notes.append(f"target: 2048² tangent-space map from (256, 3) in ≤ 60 s: {r['total s']:.1f} s "
                     f"({'met' if r['total s'] <= 60 else 'NOT met'})")

    # -- error vs time ---------------------------------------------------------------------------------
    fields = [("analytic ∇f", _analytic_field(sample, fine.frame))]
    if sdf_model:
        fields.append(("model ∇f", load_sdf_field(sdf_model)))
    err_rows = []
    for nf in faces:
        t0 = time.perf_counter()
        cm = decimate(fine, faces=nf)
        t_dec = time.perf_counter() - t0
        for size in map_sizes:
            t0 = time.perf_counter()
            baker = Baker(cm, size)
            setup = time.perf_counter() - t0
            tx = baker.texels
            truth = sample.normal(fine.frame.to_source(tx.points))
            geo = angular_error(tx.normal, truth)
            base = baseline_bake(baker.mesh, fine, tx)
            b_err = angular_error(base["normals"], truth)
            for label, field in fields:
                res = baker.bake(field)
                decoded = decode_map(res.normal_map, tx, bits=8)
                ours = angular_error(decoded, truth)
                vs_field = angular_error(decoded, res.normals)  # the map against the field's own ∇f
                err_rows.append({
                    "faces": cm.n_faces,
                    "map": f"{size}²",
                    "field": label,
                    "ours med°": _stats(ours)[0],
                    "ours p95°": _stats(ours)[1],
                    "map vs ∇f med°": _stats(vs_field)[0],
                    "ours s": setup + t_dec + res.stats["seconds"]["bake"],
                    "baseline med°": _stats(b_err)[0],
                    "baseline p95°": _stats(b_err)[1],
                    "baseline s": setup + t_dec + base["seconds"]["total"],
                    "geometry med°": _stats(geo)[0],
                })
    worst = max((r["map vs ∇f med°"] for r in err_rows), default=None)
    if worst is not None:
        notes.append(f"target: median angular error of the baked map against the SDF's ∇f ≤ 2° (bumpy sphere): "
                     f"worst row {worst:.2f}° ({'met' if worst <= 2 else 'NOT met'})")
    notes.append("error vs time: bumpy sphere sample; truth = its analytic normal at the radial projection "
                 "of each texel point; errors of the 8-bit map as decoded by a renderer; times include "
                 "decimation and set-up (unwrap, tangents, rasterisation) for both methods; 'map vs ∇f' = the decoded "
                 "8-bit map against the baked field's own unit ∇f at the same texel points")
    notes.append("with the analytic field, 'ours' measures the baking machinery (encoding, quantisation, "
                 "frames, filtering), not a fitted network; pass sdf_model=PATH for a trained one")
    anchor_rows, command_rows = [], []
    if anchor:
        a_sizes = anchor_sizes or ([256, 512] if quick else [2048, 4096])
        coarse_meshes: dict = {}
        anchor_rows = _anchor(a_sizes, anchor_model, seed, notes, quick=quick, blender_python=blender_python,
                              keep_coarse=coarse_meshes, mesh=anchor_mesh)
        rounds = (1 if quick else 3) if repeats is None else int(repeats)
        command_rows = _command(a_sizes, anchor_model, seed, notes, anchor_rows, repeats=rounds,
                                blender_meshes=coarse_meshes, blender_python=blender_python, mesh=anchor_mesh)
    notes.append(load_note())
    tables = {"throughput": rows, "error vs time": err_rows}
    if anchor:
        tables["against the anchor"] = anchor_rows
        tables["the user's command"] = command_rows
    return {
        "name": "bake",
        "title": "bake: texel throughput and error against time (neural vs mesh-to-mesh baseline)",
        "machine": machine_info(),
        "quick": quick,
        "tables": tables,
        "notes": notes,
    }


def _anchor_mesh(mesh=None):
    """(name, fine mesh): ``mesh`` (a mesh file) when given, else Spot from the reference data folder when
    present (:func:`neural_bake.bench.common.data_folder`), else the bumpy sphere sample."""
    name, _, fine = _anchor_source(mesh)
    return name, fine


def _anchor_source(mesh=None):
    """(name, mesh file, fine mesh) of :func:`_anchor_mesh` (the file a user's command reads)."""
    import warnings
    from pathlib import Path

    from ..io.mesh_io import load_mesh
    from .common import data_folder

    if mesh is not None:
        return Path(mesh).stem, Path(mesh), load_mesh(mesh)
    data = data_folder()
    obj = data / "spot" / "spot_triangulated.obj" if data is not None else None
    if obj is not None and obj.is_file():
        png = obj.with_name("spot_texture.png")
        with warnings.catch_warnings():  # its four UVs outside [0, 1]: wrapped, as the data README says
            warnings.simplefilter("ignore")
            return "spot", obj, load_mesh(obj, png if png.is_file() else None)
    from ..samples.generate import sample_path

    return "bumpy_sphere", sample_path("bumpy_sphere"), _bumpy()[1]


def _splat_map(normals: np.ndarray, texels, size: int) -> tuple[slice, np.ndarray]:
    """The rows a band of texels covers and its object-space normal map there ((rows, size, 3) in [0, 1]) of
    per-sample unit ``normals`` (the baseline's), averaged per texel and renormalised."""
    from ..bake.maps import splat

    pix = np.asarray(texels.pixel)
    r0, r1 = int(pix[:, 0].min()), int(pix[:, 0].max()) + 1
    vec, _ = splat(normals, pix, texels.weight, (size, size), rows=(r0, r1), average=True)
    norm = np.linalg.norm(vec, axis=2, keepdims=True)
    vec = np.divide(vec, norm, out=np.zeros_like(vec), where=norm > 0)
    return slice(r0, r1), (vec + 1.0) * 0.5


def _anchor(sizes, model_path, seed: int, notes: list, *, quick: bool, blender_python=None,
            keep_coarse: dict | None = None, mesh=None) -> list[dict]:
    """Our bake (full / adaptive × fp32 / auto) beside the open3d mesh-to-mesh baseline and Blender's Cycles
    "selected to active" bake of the same texels, every map decoded by the same decoder (object space, 8
    bits) at the same seeded 2^18 texel samples.

    Columns: bake seconds (the map from the texels: evaluation, interpolation, splatting, padding; set-up of
    unwrap, frames and rasterisation apart, also where a map too large to cache rasterises its texels band by
    band during the bake, for our bakes and the open3d one alike), evaluated share of the samples, median and p95 angle
    of the decoded 8-bit map to the decoded map of the full float32 evaluation at the samples, and median
    angle to the source mesh's normal where the classical bake's ray lands (quality vs source).

    Blender runs in its own process (:mod:`neural_bake.bench.blender`) on the same coarse mesh, UVs and vertex
    normals (the source's vertex normals too), twice per size: tangent space (margin 16), its map decoded with Blender's own MikkTSpace frames,
    and object space, decoded exactly as ours. Its rows add the whole script's wall (``whole script s``:
    interpreter start-up, import of bpy, scene set-up, bake, map out) beside its bake seconds.
    ``keep_coarse``: filled with {size: (the coarse mesh with its UVs, the source mesh)} when Blender ran, for the
    user's command table's own Blender rounds. ``mesh``: the anchor's mesh file (:func:`_anchor_mesh`).
    """
    from ..bake.adaptive import AdaptiveOptions
    from ..bake.baker import Baker
    from ..bake.baseline import baseline_bake, raycasting_scene
    from ..bake.report import decode_map
    from ..constants import ADAPTIVE_TOLERANCE_DEG
    from ..fields import SdfField, load_sdf_field
    from ..geometry import angular_error
    from ..mesh.decimate import decimate
    from ..nets.siren import Siren
    from . import blender

    name, fine = _anchor_mesh(mesh)
    coarse = decimate(fine, faces=2000)
    if isinstance(model_path, SdfField):
        field, label = model_path, f"{name}, SDF {model_path.name}"
    elif model_path:
        field = load_sdf_field(model_path)
        label = f"{name}, SDF {model_path}"
    else:
        field = SdfField.from_model(Siren(256, 3, generator=torch.Generator().manual_seed(seed)), name="(256,3) random")
        label = f"{name}, a randomly initialised (256,3) SIREN (its normals vary far faster than a fitted one's)"
    net = field.model
    arch = "an analytic field" if net is None else f"({net.width},{net.depth})"
    have_bpy, why_bpy = blender.available(blender_python)
    why_bpy = (f"{why_bpy} (CPU, 1 sample per texel, margin 16, its own process)" if have_bpy else
               f"not run: {why_bpy}; {blender.SETUP_HINT} (or pass blender_python=PATH)")
    notes.append(f"against the anchor: {label}, decimated to {coarse.n_faces} faces; object-space maps decoded "
                 f"at the same 2^18 seeded texel samples; Blender Cycles: {why_bpy}")
    if have_bpy:
        notes.append("Blender rows: the same coarse mesh, UVs and vertex normals, the source's normals; tangent space "
                     "decoded with Blender's own MikkTSpace frames, object space as ours; set-up s: its scene (both meshes); "
                     "whole script s: its process from start to the map out (interpreter, import of bpy, set-up, bake)")
    notes.append("bake s: the map from the texels; set-up s: unwrap, frames and the texels' rasterisation (also "
                 "where a map too large to cache rasterises band by band during the bake, ours and open3d's alike)")
    rows = []
    scene = raycasting_scene(fine)
    for size in sizes:
        t0 = time.perf_counter()
        baker = Baker(coarse, size, normal_space="object")
        setup = time.perf_counter() - t0
        variants = [("full", None, "fp32"), ("adaptive", AdaptiveOptions(), "fp32"), ("adaptive", AdaptiveOptions(), "auto")]
        if not quick:
            variants.append(("full", None, "auto"))
            # what a looser tolerance buys: four times the default
            loose = AdaptiveOptions(tolerance_deg=4 * ADAPTIVE_TOLERANCE_DEG)
            variants.append((f"adaptive {loose.tolerance_deg:g}°", loose, "fp32"))
        results = {}
        for kind, adaptive, precision in variants:
            res = baker.bake(field, keep_samples=False, adaptive=adaptive, precision=precision, seed=seed)
            results[(kind, precision)] = res
        ref = results[("full", "fp32")].sample  # the same samples for every bake (seeded, band-independent)
        tx = ref.texels
        base = baseline_bake(baker.mesh, fine, tx, cage=None, scene=scene)
        source = base["normals"]

        full_map = decode_map(results[("full", "fp32")].normal_map, tx, normal_space="object", bits=8)

        def score(normal_map):
            dec = decode_map(normal_map, tx, normal_space="object", bits=8)
            vs_full = angular_error(dec, full_map)
            vs_source = angular_error(dec, source)
            return (float(np.median(vs_full)), float(np.percentile(vs_full, 95)), float(np.median(vs_source)))

        for (kind, precision), res in results.items():
            st = res.stats
            med, p95, src = score(res.normal_map)
            # texels streamed band by band (maps too large to cache) are rasterised during the bake: set-up
            streamed = st["seconds"]["rasterize"] - baker.timings.get("rasterize", 0.0)
            rows.append({"map": f"{size}²", "method": f"ours {kind} {precision}",
                         "precision used": st["precision"]["sdf"], "bake s": st["seconds"]["bake"] - streamed,
                         "set-up s": setup + streamed, "evaluated": st["evaluated_fraction"],
                         "vs full fp32 med°": med, "vs full fp32 p95°": p95, "vs source med°": src})
        # the classical bake of every texel, timed band by band, its map splatted the same way
        t0 = time.perf_counter()
        base_map = np.full((size, size, 3), 0.5, dtype=np.float32)
        bands, streamed = iter(baker.bands()), 0.0
        while True:
            t1 = time.perf_counter()
            band = next(bands, None)
            streamed += time.perf_counter() - t1  # rasterisation of a streamed band: set-up, as for ours
            if band is None:
                break
            b = baseline_bake(baker.mesh, fine, band, cage=None, scene=scene)
            if len(b["normals"]):
                band_rows, part = _splat_map(b["normals"], band, size)
                cov = band.coverage[band_rows, :, None]
                base_map[band_rows] = np.where(cov, part, base_map[band_rows])
        t_base = time.perf_counter() - t0 - streamed
        med, p95, src = score(base_map)
        rows.append({"map": f"{size}²", "method": "open3d mesh-to-mesh", "precision used": "fp64",
                     "bake s": t_base, "set-up s": setup + streamed, "evaluated": None, "vs full fp32 med°": med,
                     "vs full fp32 p95°": p95, "vs source med°": src})
        n_blender = 0
        if have_bpy and keep_coarse is not None:
            keep_coarse[size] = (baker.mesh, fine)
        for space in ("tangent", "object") if have_bpy else ():
            try:
                cyc = blender.cycles_bake(baker.mesh, fine, size, normal_space=space, margin=16,
                                          python=blender_python)
            except blender.BlenderError as exc:  # a bpy that imports but cannot bake here: say so, keep the rest
                notes.append(f"Blender Cycles {space} bake failed at {size}²: {exc}")
                continue
            dec = blender.decode_samples(cyc, tx, bits=8)
            vs_full, vs_source = angular_error(dec, full_map), angular_error(dec, source)
            t = cyc.timings
            rows.append({"map": f"{size}²", "method": f"Blender {t['version']} Cycles {space}", "precision used": "fp32",
                         "bake s": t["bake"], "set-up s": t["setup"], "evaluated": None,
                         "vs full fp32 med°": float(np.median(vs_full)),
                         "vs full fp32 p95°": float(np.percentile(vs_full, 95)),
                         "vs source med°": float(np.median(vs_source)), "whole script s": t["whole"]})
            n_blender += 1
        for r in rows[-(len(results) + 1 + n_blender):]:
            r["÷ open3d s"] = r["bake s"] / t_base if t_base > 0 else None
        full_src = next(r["vs source med°"] for r in rows if r["map"] == f"{size}²" and r["method"] == "ours full fp32")
        best = next(r for r in rows if r["map"] == f"{size}²" and r["method"] == "ours adaptive auto")
        budget = {2048: 3.0, 4096: 12.0}.get(size)
        if budget is not None:
            notes.append(f"target: {size}² from (256,3) in ≤ {budget:g} s: adaptive auto {best['bake s']:.1f} s "
                         f"from {arch} ({'met' if best['bake s'] <= budget else 'NOT met'})")
        if size == 2048:
            notes.append(f"target: 2048² median angle to the full float32 evaluation ≤ 0.1°: "
                         f"{best['vs full fp32 med°']:.3f}° ({'met' if best['vs full fp32 med°'] <= 0.1 else 'NOT met'})")
        delta = abs(best["vs source med°"] - full_src)
        notes.append(f"target: {size}² quality vs source unchanged within 0.05° median: adaptive auto "
                     f"{best['vs source med°']:.3f}° vs full fp32 {full_src:.3f}° (|Δ| {delta:.3f}°, "
                     f"{'met' if delta <= 0.05 else 'NOT met'})")
    for r in rows:  # the table's columns are its first row's keys
        r.setdefault("whole script s", None)
    return rows


#: The stages of the user's command shown per row (report.json seconds; "bake" holds hybrid and maps).
_COMMAND_STAGES = ("load", "coarse", "prepare", "bake", "write")


def _command(sizes, model_path, seed: int, notes: list, anchor_rows: list[dict], *, repeats: int = 1,
             blender_meshes: dict | None = None, blender_python=None, mesh=None) -> list[dict]:
    """What a user runs: ``neural-bake bake MESH --sdf MODEL --coarse decimate:2000 --maps normal --size N
    --no-baseline -o OUT`` with every other setting at its default (hybrid on, adaptive, precision auto), as its
    own process: wall seconds, the stages of its report, beside Blender's whole script and bake (the same coarse
    mesh and UVs as the anchor table's). ``repeats`` rounds per size, our command then Blender's script
    (``blender_meshes``: {size: (coarse mesh, source)} from :func:`_anchor`; without it, the anchor table's one
    Blender run), so both meet the machine in the same states; the wall and bake figures are each the best of
    the rounds, with the range beside them, the other stages those of the fastest round. Targets: the bake
    stage no slower than Blender's bake, the wall at most twice Blender's whole script. ``mesh``: the anchor's
    mesh file (:func:`_anchor_source`)."""
    import json
    import os
    import tempfile
    from pathlib import Path

    from ..fields import SdfField, save_model
    from ..nets.siren import Siren
    from . import blender as blender_mod

    name, mesh_file, fine = _anchor_source(mesh)
    rows: list[dict] = []

    def spread(values):
        return f"{min(values):.1f}–{max(values):.1f}" if len(values) > 1 else None

    with tempfile.TemporaryDirectory(prefix="nb-bench-bake-") as tmp:
        force: list[str] = []
        if isinstance(model_path, (str, os.PathLike)) and model_path:
            model = Path(model_path)
        else:  # the anchor table's network as a model file (a random one does not describe the mesh: --force)
            net = model_path.model if isinstance(model_path, SdfField) else \
                Siren(256, 3, generator=torch.Generator().manual_seed(seed))
            model = Path(tmp) / "anchor.sdf"
            save_model(net, model, kind="sdf", frame=fine.frame.to_dict())
            force = ["--force"]
        for size in sizes:
            out = Path(tmp) / f"bake-{size}"
            args = ["bake", str(mesh_file), "--sdf", str(model), "--coarse", "decimate:2000", "--maps", "normal",
                    "--size", str(size), "--no-baseline", *force, "-o", str(out)]
            ours: list[tuple[float, dict]] = []
            repeat: list[tuple[float, dict]] = []
            cycles: list[dict] = []

            def attempt(extra, args=args, size=size, out=out):
                wall, proc = run_command([*args, *extra])
                if proc.returncode != 0:
                    notes.append(f"the user's command at {size}² failed: {last_error_line(proc)}")
                    return None
                return wall, json.loads((out / "report.json").read_text())

            for _ in range(max(1, int(repeats))):
                first = attempt(["--no-layout-cache"])  # a first bake of the asset: decimated and unwrapped
                if first is None:
                    break
                ours.append(first)
                for _ in range(2):  # the same bake again, from the layout cache (an empty cache: filled by the first)
                    again = attempt([])
                    if again is not None and (again[1].get("coarse") or {}).get("cached"):
                        repeat.append(again)
                        break
                if blender_meshes and size in blender_meshes:
                    coarse_mesh, source = blender_meshes[size]
                    try:
                        cycles.append(blender_mod.cycles_bake(coarse_mesh, source, size, normal_space="tangent",
                                                              margin=16, python=blender_python).timings)
                    except blender_mod.BlenderError as exc:
                        notes.append(f"Blender Cycles tangent bake failed at {size}² in the command rounds: {exc}")
                        blender_meshes = None
            if not ours:
                continue

            def command_row(runs, method, size=size):
                wall, rep = min(runs, key=lambda t: t[0])
                sec = rep.get("seconds") or {}
                bake = rep.get("bake") or {}
                bakes = [(r.get("seconds") or {}).get("bake") for _, r in runs]
                bakes = [b for b in bakes if b is not None]
                row = {"map": f"{size}²", "method": method, "wall s": wall,
                       **{f"{k} s": sec.get(k) for k in _COMMAND_STAGES},
                       "preload s": sum(((rep.get("preload") or {}).get("seconds") or {}).values()) or None,
                       "hybrid s": (bake.get("seconds") or {}).get("hybrid"),
                       "evaluated": bake.get("evaluated_fraction"),
                       "vs source med°": (rep.get("vs_truth_deg") or {}).get("median"),
                       "vs source p95°": (rep.get("vs_truth_deg") or {}).get("p95"),
                       "rounds": len(runs), "wall range s": spread([w for w, _ in runs]),
                       "bake range s": spread(bakes)}
                row["bake s"] = min(bakes) if bakes else None
                return row

            row = command_row(ours, "neural-bake bake (defaults, hybrid on): a first bake")
            rows.append(row)
            wall = row["wall s"]
            if repeat:
                rows.append(command_row(repeat, "the same bake again (coarse mesh and layout from the cache)"))
            if cycles:
                blender = {"method": f"Blender {cycles[0]['version']} Cycles tangent",
                           "whole script s": min(t["whole"] for t in cycles), "bake s": min(t["bake"] for t in cycles),
                           "wall range s": spread([t["whole"] for t in cycles]),
                           "bake range s": spread([t["bake"] for t in cycles]), "rounds": len(cycles)}
            else:
                blender = next((r for r in anchor_rows if r["map"] == f"{size}²" and "Cycles tangent" in r["method"]),
                               None)
            if blender is not None:
                rows.append({"map": f"{size}²", "method": f"{blender['method']} (whole script)",
                             "wall s": blender["whole script s"], "bake s": blender["bake s"],
                             **{k: blender.get(k) for k in ("rounds", "wall range s", "bake range s")}})
                ok_bake = row["bake s"] is not None and row["bake s"] <= blender["bake s"]
                ok_wall = wall <= 2 * blender["whole script s"]
                notes.append(f"target: the user's command at {size}² (a first bake): bake stage {row['bake s'] or 0:.1f} s "
                             f"against Blender's bake {blender['bake s']:.1f} s ({'met' if ok_bake else 'NOT met'}); "
                             f"wall {wall:.1f} s against 2 × Blender's whole script "
                             f"{2 * blender['whole script s']:.1f} s ({'met' if ok_wall else 'NOT met'}); best of "
                             f"{len(ours)} rounds taken in turn")
    notes.append(f"the user's command: {name}, `neural-bake bake --coarse decimate:2000 --maps normal --no-baseline` "
                 "as its own process (start-up and imports in its wall), stages from its report.json; a first bake "
                 "(--no-layout-cache: the coarse mesh decimated and unwrapped) and the same bake again (both from "
                 "the layout cache); rounds: our two commands and Blender's script in turn, wall and bake the best "
                 "of the rounds (range beside), the other stages the fastest round's; preload s: the source mesh "
                 "read, decimated and unwrapped in a forked process beside torch's import (load s holds any wait "
                 "for it; coarse s is then this process's own, none)")
    notes.append(bytecode_note())
    for r in rows:
        for k in ("wall s", *(f"{k} s" for k in _COMMAND_STAGES), "preload s", "hybrid s", "evaluated", "vs source med°",
                  "vs source p95°", "rounds", "wall range s", "bake range s"):
            r.setdefault(k, None)
    return rows
