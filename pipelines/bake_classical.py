"""The classical bake of a neural bake's texels, as a bake folder of its own (for `compare` and the demo).

Reads a neural bake's output folder (its ``report.json`` names the source mesh, the map size and the
supersampling; its ``asset.glb`` holds the coarse mesh and UV layout), bakes the source onto the same coarse
mesh, layout and texels with the classical mesh-to-mesh rays (:func:`neural_bake.bake.classical.classical_bake`),
and writes OUT/asset.glb, the maps, the error maps and OUT/report.json, measured by the same report against
the same ground truth. Only library calls; OUT is committed as a unit.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

__all__ = ["bake_classical"]


def bake_classical(neural_folder, out, *, cage: float | None = None, log: Callable[[str], None] = print) -> dict:
    """Bake the classical counterpart of the bake in ``neural_folder`` into folder ``out``; return its report.

    Raises :class:`~neural_bake.view.meshes.ViewError` (one line naming the folder) for a folder that is not
    a bake, and NeuralBakeError for a source mesh that cannot be read.
    """
    import numpy as np

    from neural_bake.bake.classical import classical_bake
    from neural_bake.bake.export import export_glb
    from neural_bake.bake.report import bake_report
    from neural_bake.errors import NeuralBakeError
    from neural_bake.io.asset import read_asset, shading_mesh
    from neural_bake.io.atomic import atomic_write_text
    from neural_bake.io.images import write_image
    from neural_bake.io.jsonio import dumps
    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.io.outdir import OutputFolder
    from neural_bake.view.comparison import read_bake
    from neural_bake.view.meshes import view_mesh_from_glb
    from neural_bake.view.report import source_of

    from neural_bake.bake.job import sample_truth

    t_start = time.perf_counter()
    neural_folder = Path(neural_folder)
    neural = read_bake(neural_folder)
    src, why = source_of(neural_folder, neural)
    if src is None:
        raise NeuralBakeError(f"{neural_folder}: {why}")
    bake = neural.get("bake") or {}
    size = bake.get("size") or [None]
    if not isinstance(size[0], int):
        raise NeuralBakeError(f"{neural_folder / 'report.json'}: no map size (bake.size) to bake the same texels")
    with OutputFolder(out) as stage:
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        fine = load_mesh(src)
        asset = read_asset(src, fine)
        reference = fine if asset.corner_normals is None else shading_mesh(fine, asset.corner_normals)
        glb = view_mesh_from_glb(neural_folder / "asset.glb")
        # the neural bake's coarse mesh and UV layout, in the source's unit frame (the GLB is in its frame)
        coarse = glb.without_maps().to_mesh(fine.frame, source=str(neural_folder / "asset.glb"))
        timings["load"] = time.perf_counter() - t0
        log(f"classical bake of {src.name} onto the neural bake's coarse mesh ({coarse.n_faces} faces, "
            f"{size[0]}² maps)")
        result, baker = classical_bake(coarse, reference, int(size[0]), supersample=int(bake.get("supersample") or 1),
                                       cage=cage)
        timings.update({k: v for k, v in result.stats["seconds"].items()})
        t0 = time.perf_counter()
        write_image(stage / "normal.png", result.normal_map, colour="data")
        written = ["normal.png"]
        if result.albedo is not None:
            write_image(stage / "albedo.png", result.albedo, colour="srgb")
            written.append("albedo.png")
        export_glb(stage / "asset.glb", baker.mesh, normal_map=result.normal_map, albedo=result.albedo,
                   tangents=baker.tangents)
        written.append("asset.glb")
        timings["write"] = time.perf_counter() - t0
        normals_fn, colours_fn, sample_name = sample_truth(str(src), baker.mesh, "auto")
        rep = bake_report(result, baker, truth=normals_fn, fine=None if normals_fn else reference,
                          truth_colors=colours_fn, timings=timings, out_dir=stage)
        if sample_name:
            rep["truth"] = f"analytic ({sample_name} sample)"
        written += rep.pop("files", [])
        report = {"method": "classical", "mesh": str(src), "coarse": {"from": str(neural_folder / "asset.glb"),
                  "faces": int(baker.mesh.n_faces), "vertices": int(baker.mesh.n_vertices)},
                  "maps": ["normal"] + (["albedo"] if result.albedo is not None else []), **rep}
        report["seconds_total"] = time.perf_counter() - t_start
        report["files"] = written + ["report.json"]
        atomic_write_text(stage / "report.json", dumps(report))
    med = (report.get("vs_truth_deg") or {}).get("median")
    if med is not None:
        log(f"classical bake: normal error vs truth median {med:.2f}°, "
            f"{int(np.sum(result.coverage))} texels, {report['seconds_total']:.1f} s")
    return report
