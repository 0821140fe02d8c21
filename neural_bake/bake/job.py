"""The bake of an asset as steps that return data: load → coarse → bake → write → report.

- :func:`load_inputs`: the source mesh (and its asset: shading normals, kept maps), the SDF and texture
  model files, and the checks that they describe the same object (:class:`BakeInputs`).
- :func:`make_coarse`: the coarse mesh the maps are baked onto (:func:`neural_bake.mesh.coarse.coarse_mesh`);
  it and its UV layout can be kept between runs (:mod:`neural_bake.mesh.layout_cache`).
- :func:`bake_maps`: the texel maps (:class:`~neural_bake.bake.baker.Baker`) with the hybrid's replacements
  (:class:`TexelBake`); :func:`bake_vertex_colours`: the per-vertex bake.
- :func:`write_maps`: the loose maps and the asset files (GLB, USD, USDZ) into a folder.
- :func:`report_maps`: the quality report (:func:`~neural_bake.bake.report.bake_report`) with the classical
  baseline and the fidelity warnings.

:func:`neural_bake.pipelines.bake_asset.bake_asset` chains them inside one output folder and says what each
found. Errors are :class:`~neural_bake.errors.NeuralBakeError` naming the file or the parameter.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..constants import HYBRID_DETAIL_SIDE
from ..errors import MeshError, ModelFileError, NeuralBakeError
from ..types import Mesh

if TYPE_CHECKING:
    from ..fields import NestedSequence, SdfField, TextureField
    from ..io.asset import Asset
    from ..mesh.layout_cache import LayoutCache
    from .baker import Baker, BakeResult
    from .hybrid import HybridFallback
    from .preload import Preload, PreloadedSource

__all__ = ["BakeInputs", "TexelBake", "load_inputs", "make_coarse", "coarse_of_source", "read_source", "bake_maps",
           "bake_vertex_colours", "write_maps", "report_maps", "sample_truth", "FORMATS", "MAPS", "MODEL_ONLY_COARSE"]

#: The maps a bake makes: the texel maps (normal, albedo) and the per-vertex bake.
MAPS = ("normal", "albedo", "vertex")
#: Files of the baked asset: asset.glb, asset.usd (a stage referencing the loose maps), asset.usdz (a package).
FORMATS = ("glb", "usd", "usdz")
#: The coarse mesh of a bake without a source mesh when the spec says decimate (nothing to decimate): the
#: model marched at this resolution (the finest level of a nested sequence).
MODEL_ONLY_COARSE = "march:128"


@dataclass
class BakeInputs:
    """What a bake reads: the source mesh (None: a bake from the model alone), its asset and shading
    reference, the model files' fields and the checks made on them."""

    mesh_path: str | None
    sdf_path: str
    sdf_file: SdfField | NestedSequence
    """The SDF model file's field."""
    sdf: SdfField
    """The SdfField baked (a nested sequence's fine f with its band δ)."""
    texture: TextureField | None
    delta: float | None
    """The band δ of the miss map (given, the SDF's, or the texture's)."""
    fine: Mesh | None = None
    reference: Mesh | None = None
    """The normals' (and colours') reference: the source mesh with its own shading normals, when it has them."""
    asset: Asset | None = None
    """The source's asset (maps, factors, corner normals), or None."""
    sdf_check: dict = field(default_factory=dict)
    seconds: float = 0.0
    preloaded: PreloadedSource | None = None
    """What a preloading process made of the source mesh (:mod:`.preload`), or None."""


@dataclass
class TexelBake:
    """The texel maps of a bake: the Baker (layout, tangents, texels), its result, the hybrid fallback that
    ran (or None) and the colour rules it used (ΔE tolerance, least PSNR in dB, dB within the classical
    transfer: None where not used)."""

    baker: Baker
    result: BakeResult
    hybrid: HybridFallback | None
    colour_tol: float | None
    seconds: float = 0.0
    colour_psnr: float | None = None
    colour_within: float | None = None


def load_field(path, parameter: str, want: str, device=None) -> Any:
    """The field file given as ``parameter`` (named by errors): an SDF or nested sequence (``want="sdf"``) or a
    texture field, its networks on ``device``."""
    from ..fields import NestedSequence, SdfField, TextureField
    from ..fields import load_field as _load

    if not Path(path).exists():
        raise ModelFileError(f"{parameter} {path}: no such model file", parameter=parameter)
    f = _load(path, device=device)
    types, expected = ((SdfField, NestedSequence), "an SDF (kind 'sdf' or a nested sequence)") if want == "sdf" \
        else ((TextureField,), "a texture field (kind 'texture')")
    if not isinstance(f, types):
        raise ModelFileError(f"{parameter} {path}: a {type(f).__name__} file, expected {expected}",
                             parameter=parameter)
    return f


def sdf_for(sdf_file, coarse: str):
    """The SdfField to bake: a nested sequence gives its fine f with the band δ of the level the coarse mesh
    is marched from (``level:I:RES``), else of its coarsest level (the widest band)."""
    from ..fields import to_sdf_field
    from ..mesh.coarse import parse_coarse

    kind, value = parse_coarse(coarse)
    return to_sdf_field(sdf_file, band_level=value[0] if kind == "level" else 0)


def load_inputs(mesh_path: str | None, sdf_path: str, texture_path: str | None, *, coarse: str,
                texture_image: str | None = None, truth: str = "auto", delta: float | None = None,
                device=None, force: bool = False, log: Callable[[str], None] = print,
                preload: Preload | None = None) -> BakeInputs:
    """Read what a bake needs (:class:`BakeInputs`): the model files, the source mesh and its asset, and
    check that the SDF describes the mesh and the texture the SDF (``force``: bake anyway, said in ``log``).
    ``truth`` "sample:NAME" refuses a mesh that is not that sample. ``preload``: a process reading the source mesh
    (:mod:`.preload`), waited for once the model files are read; what it made is kept in ``inputs.preloaded``
    (the mesh is read here when it failed)."""
    from .agreement import check_sdf_describes_mesh

    t0 = time.perf_counter()
    sdf_file = load_field(sdf_path, "sdf", "sdf", device)
    sdf = sdf_for(sdf_file, coarse)
    tex = load_field(texture_path, "texture_model", "texture", device) if texture_path else None
    if delta is None and sdf.delta is None and tex is not None and tex.delta is not None:
        delta = tex.delta  # the band the texture was fitted in: where neural attribute mapping is valid
        log(f"nesting band δ = {delta:g} (unit frame) from {Path(texture_path).name}")
    inputs = BakeInputs(mesh_path=mesh_path, sdf_path=sdf_path, sdf_file=sdf_file, sdf=sdf, texture=tex, delta=delta,
                        sdf_check={"passed": None, "note": "no source mesh to check the SDF against"})
    preloaded = preload.result() if preload is not None and mesh_path is not None else None
    inputs.preloaded = preloaded
    if mesh_path is not None:
        if preloaded is not None:
            from .preload import reissue_warnings

            fine, asset, reference = preloaded.fine, preloaded.asset, preloaded.reference
            reissue_warnings(fine)
        else:
            fine, asset, reference = read_source(mesh_path, texture_image)
        if truth.startswith("sample:"):
            sample_truth(mesh_path, fine, truth)  # a mesh that is not the sample is refused before the bake
        inputs.fine, inputs.reference, inputs.asset = fine, reference, asset
        inputs.sdf_check = check_sdf_describes_mesh(fine, sdf, force=force, option="--force")
        if not inputs.sdf_check["passed"]:
            c = inputs.sdf_check
            log(f"--force: baking an SDF that fails the mesh check (frames differ by "
                f"{c['frame_mismatch']:.3g}, median |f| on the mesh {c['median_abs_f']:.4g})")
    inputs.seconds = time.perf_counter() - t0
    if tex is not None:  # a texture model of another object is refused like an SDF of another mesh
        from ..fields import check_texture_matches_sdf

        inputs.sdf_check["texture"] = check_texture_matches_sdf(tex, sdf_file, force=force, option="--force",
                                                                sdf_name=Path(sdf_path).name)
    return inputs


def read_source(mesh_path: str, texture_image: str | None = None) -> tuple[Mesh, Any, Mesh]:
    """(the source mesh, its asset, the normals' reference): the mesh with its own shading normals (split at hard
    edges) when its asset has them, else the mesh itself. Torch-free (:mod:`.preload` runs it too)."""
    from ..io.asset import read_asset, shading_mesh
    from ..io.mesh_io import load_mesh

    fine = load_mesh(mesh_path, texture_image)
    asset = read_asset(mesh_path, fine)
    return fine, asset, fine if asset.corner_normals is None else shading_mesh(fine, asset.corner_normals)


def make_coarse(inputs: BakeInputs, coarse: str, made: tuple[Mesh, dict] | None = None,
                cache: LayoutCache | None = None) -> tuple[Mesh, dict]:
    """The coarse mesh of the bake and its info: ``made`` (a pair made earlier, e.g. by a batch's coarse
    stage), the decimation a preloading process made (``inputs.preloaded``, :mod:`.preload`: the same call
    there, with the same spec and cache), or :func:`coarse_of_source` of the source (``keep``: its shading
    reference) or of the model (no source mesh)."""
    from ..mesh.coarse import parse_coarse

    if made is not None:
        return made
    if inputs.preloaded is not None and inputs.preloaded.coarse is not None:
        return inputs.preloaded.coarse
    source = inputs.reference if parse_coarse(coarse)[0] == "keep" else inputs.fine
    return coarse_of_source(source, coarse, cache=cache, sdf_file=inputs.sdf_file, sdf_path=inputs.sdf_path,
                            mesh_path=inputs.mesh_path)


def coarse_of_source(source: Mesh | None, coarse: str, *, cache: LayoutCache | None = None, sdf_file=None,
                     sdf_path: str | None = None, mesh_path: str | None = None) -> tuple[Mesh, dict]:
    """:func:`~neural_bake.mesh.coarse.coarse_mesh` of ``source`` (None: of the model ``sdf_file``, read from
    ``sdf_path``; ``mesh_path`` None says there is no source mesh). ``cache``: a decimated or marched mesh is
    read from it when an earlier run made it from the same source mesh (and, to march, model file) and spec,
    else made and stored (``info["cached"]`` says which; ``info["seconds"]`` is this run's)."""
    from ..mesh.coarse import coarse_mesh, parse_coarse
    from ..mesh.layout_cache import mesh_digest

    kind = parse_coarse(coarse)[0]

    def make() -> tuple[Mesh, dict]:
        try:
            return coarse_mesh(source, coarse, sdf_file)
        except NeuralBakeError as exc:
            if mesh_path is not None:
                raise
            raise NeuralBakeError(f"{sdf_path}: no surface to bake from the model alone ({exc})") from None

    if cache is None or kind == "keep" or (kind == "decimate" and source is None):
        return make()
    t0 = time.perf_counter()
    # march and level: the model file, and the source mesh whose frame a model without one is marched in
    made_from = [mesh_digest(source) if source is not None else "no source"]
    if kind != "decimate":
        made_from.append(_file_digest(sdf_path))
    mesh, info, hit = cache.get_or_make(cache.key("coarse", coarse, *made_from), make)
    info = dict(info, cached=hit)
    if hit:
        info["seconds"] = time.perf_counter() - t0
    return mesh, info


def _file_digest(path) -> str:
    """Hex digest of a file's bytes."""
    import hashlib

    h = hashlib.blake2b(digest_size=20)
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def check_uv_area(path, uv, size: int) -> None:
    """MeshError if a mesh's own UV layout ((F, 3, 2) per-corner UVs) covers less than one texel of the map."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 3, 2)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area = 0.5 * float(np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum())
    if not area * size * size >= 1.0:
        raise MeshError(f"{path}: its UV layout covers {area:.3g} of the UV square, less than one texel of the "
                        f"{size}x{size} map; bake with --coarse decimate or march, which unwrap a new layout")


def bake_maps(inputs: BakeInputs, coarse_m: Mesh, *, maps: list[str], size: int, supersample: int = 1,
              normal_space: str = "tangent", directx: bool = False, padding: str = "pull-push",
              cache_texels: bool | None = None, report_samples: int, keep: bool, hybrid: bool = True,
              hybrid_tol: float, hybrid_angle: float, hybrid_color_tol: float, hybrid_color_psnr: float | None = None,
              hybrid_color_within: float | None = None, bits: int = 8, hybrid_decide: str = "lattice",
              hybrid_detail: int = HYBRID_DETAIL_SIDE, cage: float | None = None, keep_baseline: bool = False,
              adaptive=None, precision: str = "auto", layout_cache: LayoutCache | None = None) -> TexelBake:
    """Bake the texel maps (``maps`` "normal", "albedo") of ``inputs`` onto ``coarse_m`` (:class:`TexelBake`).

    The hybrid fallback runs when ``hybrid`` and a source mesh is there: normals always, colours where a
    texture is baked and the source has one (``hybrid_color_tol`` finite, ``hybrid_color_psnr`` or
    ``hybrid_color_within`` set; ``bits``: the albedo map's, which the last compares in; ``hybrid_detail``: the
    widest cell given up as too fine for the lattice, :class:`~.hybrid.HybridFallback`'s ``detail_side``).
    ``keep_baseline``: the hybrid keeps its classical bake of every sample for the report (when the report
    measures every texel: a map up to the report's lattice side). ``keep``: the coarse mesh is the source itself
    (the texture is read at the point). ``layout_cache``: a coarse mesh without UVs takes its layout from it (:meth:`LayoutCache.unwrap`)."""
    from .baker import Baker
    from .report import lattice_step

    t0 = time.perf_counter()
    pre = inputs.preloaded  # its unwrap of this coarse mesh for this size, made while torch was imported
    layout = pre.layout if pre is not None and pre.made(coarse_m) and pre.layout_size == size else None
    baker = Baker(coarse_m, size, supersample=supersample, normal_space=normal_space,
                  y_convention="directx" if directx else "opengl",
                  padding=None if padding == "none" else padding, cache_texels=cache_texels,
                  layout_cache=layout_cache, layout=layout)
    prepare = time.perf_counter() - t0
    tex, reference = inputs.texture, inputs.reference
    # colours follow the hybrid rule where a texture is baked and the source has one to take colours from
    colours = (tex is not None and "albedo" in maps and reference is not None and reference.uv is not None
               and reference.texture is not None)
    colour_tol = hybrid_color_tol if colours and np.isfinite(hybrid_color_tol) else None
    colour_psnr = hybrid_color_psnr if colours else None
    colour_within = hybrid_color_within if colours and hybrid_color_within is not None \
        and np.isfinite(hybrid_color_within) else None
    fallback = None
    if hybrid and ("normal" in maps or colour_tol is not None or colour_psnr is not None
                   or colour_within is not None) and reference is not None:
        from .hybrid import HybridFallback

        fallback = HybridFallback(reference, inputs.sdf, sdf_tol=hybrid_tol, angle_deg=hybrid_angle, cage=cage,
                                  keep_baseline=keep_baseline and baker.cache and lattice_step((size, size)) == 1,
                                  decide=hybrid_decide, detail_side=hybrid_detail,
                                  color_tol=colour_tol, color_psnr=colour_psnr, color_within=colour_within,
                                  color_bits=int(bits))
    res = baker.bake(inputs.sdf, tex if "albedo" in maps else None, delta=inputs.delta,
                     report_samples=int(report_samples), hybrid=fallback, adaptive=adaptive, precision=precision,
                     texture_at="point" if keep else "surface")
    if res.stats["texels_covered"] == 0:
        raise MeshError(f"{inputs.mesh_path}: the coarse mesh's UV layout covers no texel of the {size}x{size} map")
    return TexelBake(baker=baker, result=res, hybrid=fallback, colour_tol=colour_tol, seconds=prepare,
                     colour_psnr=colour_psnr, colour_within=colour_within)


def reserve_heap(size: int, supersample: int = 1) -> str:
    """Reserve the heap a texel bake of ``size``² (``supersample``) is about to use and fault it in on a
    background thread while the bake loads (:func:`neural_bake.nets.heap.reserve`):
    :data:`~neural_bake.constants.BAKE_HEAP_PER_SAMPLE` a sample position, at most half the free memory."""
    from ..constants import BAKE_HEAP_PER_SAMPLE
    from ..nets.heap import reserve

    want = BAKE_HEAP_PER_SAMPLE * int(size) ** 2 * int(supersample) ** 2
    try:
        free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # not a POSIX system that says
        free = want
    return reserve(min(want, free // 2))


def write_maps(stage: Path, baked: TexelBake, inputs: BakeInputs, *, maps: list[str], formats: list[str],
               bits: int = 8, exr: bool = False, normal_space: str = "tangent", directx: bool = False,
               keep: bool = False) -> tuple[list[str], dict | None]:
    """Write the loose maps (PNG, and EXR with ``exr``) and the asset files (``formats``) of ``baked`` into
    ``stage``; returns (the files written, what a bake onto the source itself kept of it, or None)."""
    from .export import export_glb
    from ..io.images import write_image

    res, baker, asset, fine = baked.result, baked.baker, inputs.asset, inputs.fine
    written: list[str] = []
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
            **({"albedo": stage / "albedo.png"} if res.albedo is not None and albedo_out is res.albedo else {})}
        export_glb(stage / "asset.glb", baker.mesh, normal_map=res.normal_map if gltf_normals else None,
                   albedo=albedo_out, tangents=baker.tangents, material_maps=kept_maps,
                   same_image=None if asset is None else asset.same_image,
                   material_factors=None if asset is None else asset.factors, png_files=png_files)
        written.append("asset.glb")
    for fmt in ("usd", "usdz"):  # the same mesh and maps; the stage references the loose PNGs
        if fmt in formats:
            from .usd_export import export_usd

            export_usd(stage / f"asset.{fmt}", baker.mesh,
                       base_colour=stage / "albedo.png" if res.albedo is not None else None,
                       normal_map=stage / "normal.png" if gltf_normals else None)
            written.append(f"asset.{fmt}")
    kept = None
    if keep:
        kept = {"vertex_normals": "the asset's" if asset.corner_normals is not None else "computed",
                "uv": "the asset's" if fine.uv is not None else "unwrapped",
                "maps": sorted((["base_colour"] if res.albedo is None and fine.texture is not None else [])
                               + [k for k in kept_maps if not (k == "normal" and gltf_normals)])}
    return written, kept


def report_maps(stage: Path, baked: TexelBake, inputs: BakeInputs, *, baseline: bool, cage: float | None,
                truth: str, bits: int, timings: dict, coarse: str,
                log: Callable[[str], None] = print) -> tuple[dict, list[str]]:
    """The quality report of ``baked`` (:func:`~neural_bake.bake.report.bake_report`), its error maps written
    into ``stage``: against the analytic truth of a bundled sample, the source mesh, or (no source) ∇f; with
    the classical baseline on the same texels when ``baseline`` (the hybrid's, when it kept one over every
    texel). Returns (report entries, files written)."""
    from .report import bake_report

    res, baker, hybrid, reference = baked.result, baked.baker, baked.hybrid, inputs.reference
    base = base_fn = None
    if baseline and reference is not None:
        from .baseline import baseline_bake, raycasting_scene

        base = hybrid.baseline() if hybrid is not None and res.normals is not None else None  # the hybrid's
        if base is not None:
            log(f"baseline (mesh-to-mesh rays): {base['seconds']['total']:.1f} s, "
                f"{base['fallback']} closest-point fallbacks")
        else:  # on the texels the report measures (all, its lattice, or its sample and band by band)
            scene = raycasting_scene(reference)

            def base_fn(texels):
                return baseline_bake(baker.mesh, reference, texels, cage=cage, scene=scene)

    normals_fn, colours_fn, sample_name = (None, None, None) if inputs.mesh_path is None else \
        sample_truth(inputs.mesh_path, baker.mesh, truth)
    rep = bake_report(res, baker, truth=normals_fn, fine=None if normals_fn else reference,
                      truth_colors=colours_fn, baseline=base, baseline_fn=base_fn, bits=int(bits),
                      timings=timings, out_dir=stage)
    if sample_name:
        rep["truth"] = f"analytic ({sample_name} sample)"
    if inputs.mesh_path is None:
        rep["truth"] = ("none: no source mesh; the map is measured against ∇f of the finest level "
                        "(vs_gradient_deg), and there is no classical baseline")
    if base_fn is not None and "baseline" in rep and res.normals is not None:
        b = rep["baseline"]
        log(f"baseline (mesh-to-mesh rays) on {b['samples']} texel samples: {b['seconds']['total']:.1f} s, "
            f"{b['fallback']} closest-point fallbacks")
    every = rep.get("baseline", {}).get("all_texels")
    if every:
        log(f"baseline (mesh-to-mesh rays) over all {every['samples']} samples: {every['seconds']:.1f} s, "
            f"{every['fallback']} closest-point fallbacks")
    if rep["sampling"]["sampled"]:
        log(f"report: {rep['sampling']['note']}")
    files = rep.pop("files", [])
    if hybrid is not None:
        rep.setdefault("hybrid", {}).update(hybrid.summary())
    rep["warnings"] = fidelity_warnings(rep, coarse)
    return rep, files


def bake_vertex_colours(stage: Path, inputs: BakeInputs, coarse_m: Mesh, *, keep: bool) -> tuple[list[str], dict]:
    """The per-vertex bake of ``coarse_m`` (normals, and colours with a texture) written as vertex.glb and
    vertex.ply into ``stage``; returns (files, report entry)."""
    from .baker import bake_vertices
    from .export import export_glb, export_vertex_ply

    t0 = time.perf_counter()
    vb = bake_vertices(coarse_m, inputs.sdf, inputs.texture, texture_at="point" if keep else "surface")
    colors = None if vb["colors"] is None else np.clip(vb["colors"][:, :3], 0, 1)
    export_glb(stage / "vertex.glb", coarse_m, normals=vb["normals"], vertex_colors=colors)
    export_vertex_ply(stage / "vertex.ply", coarse_m, normals=vb["normals"], vertex_colors=colors)
    return ["vertex.glb", "vertex.ply"], {"vertices": coarse_m.n_vertices, "invalid_gradients": vb["invalid"],
                                          "seconds": time.perf_counter() - t0}


def fidelity_warnings(report: dict, coarse: str) -> list[str]:
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


def sample_truth(path: str, mesh, choice: str):
    """(normals(points) callable, colours callable, name) of an analytic sample the mesh is, or Nones."""
    from ..samples.shapes import SAMPLES, get_sample, unit_frame_normals

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
            raise NeuralBakeError(f"truth {choice}: {path} is not the {name} sample (vertices off its surface)",
                                  parameter="truth")
        return None, None, None

    normals = unit_frame_normals(sample, mesh.frame)

    def colours(p):
        return sample.albedo(mesh.frame.to_source(p))

    return normals, colours, name
