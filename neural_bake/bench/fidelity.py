"""`neural-bake bench fidelity`: what a neural bake gives on real assets, beside the classical bake.

For each real mesh of the data folder (``$NEURAL_BAKE_DATA``, else ``shared/data`` beside the repository;
skipped, saying so, when absent) and each preset at its time budget: fit the SDF, measure its Hausdorff
distance (an open mesh's also without the caps the SDF puts over its holes, and those caps on their own),
decimate (or keep, for game assets), bake a normal map and report the angle between the baked normal and the
source mesh's (median, p95) for the hybrid map, ∇f alone (the same bake without the hybrid: the network at
every texel), the classical mesh-to-mesh bake and the coarse mesh's own normals, all on the same texels; the
share of hybrid texels; times of each stage; the texture PSNR of textured assets (a texture fit at the same
preset name); and storage (the networks' KB against the source file's MB).

Textured assets also get a texture row (:mod:`neural_bake.bench.fidelity_texture`): the albedo of the network
alone, of the hybrid colour rule and of the classical transfer, each against the source texture at the
closest points (PSNR, SSIM), the network's two against the classical one, and the time of each bake.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from ..constants import HYBRID_COLOR_DELTA_E
from ..errors import NeuralBakeError
from .common import data_folder, load_note, machine_info

__all__ = ["run", "MESHES", "SAMPLINGS", "open_caps"]

#: The real meshes, relative to the data folder, with their bake settings: game assets bake onto themselves.
MESHES: dict[str, dict] = {
    "nefertiti": {"path": "scans/nefertiti.obj"},
    "ogre": {"path": "scans/ogre.obj"},
    "fandisk": {"path": "cad/fandisk.obj"},
    "rocker-arm": {"path": "cad/rocker-arm.obj"},
    "cabinet": {"path": "polyhaven/painted_wooden_cabinet/painted_wooden_cabinet_1k.gltf", "coarse": "keep"},
    "tea_set": {"path": "polyhaven/tea_set_01/tea_set_01_1k.gltf", "coarse": "keep"},
    "spot": {"path": "spot/spot_triangulated.obj", "texture": "spot/spot_texture.png"},
    "bunny": {"path": "bunny/bunny_closed.obj"},
}

#: The meshes of :data:`MESHES` with a texture (their own, or a named image): the texture rows' default.
TEXTURED = ("cabinet", "tea_set", "spot")

#: Generated samples the benchmark takes by name (no data folder needed), with their bake settings. ``dots``:
#: flat colour with sharp discs down to 8 texels across (at 1024²), baked onto itself; its texture rows also
#: score each 8-texel disc's window (:func:`~neural_bake.bench.fidelity_texture.dot_windows`).
SAMPLE_MESHES: dict[str, dict] = {"dots": {"sample": "dots", "coarse": "keep", "features": "dots"}}

#: Colour-network constructions the texture rows compare (``texture_networks``): "siren", the preset's SIREN
#: (its own network, or :data:`~neural_bake.fit.texture.PRESET_SIRENS` where that is a grid); "siren-wide",
#: that SIREN twice as wide and one hidden matrix deeper; "grid", a multiresolution feature grid in front of a
#: 64x1 ReLU MLP (the grid settings' defaults, lr 1e-2, half the samples at the texture's edges), reading the
#: point alone; "grid-uniform", that grid with no edge samples; "grid-normals", that grid's MLP also reading the
#: surface normal (``normal_inputs`` "on"); "grid-auto", reading it on open meshes only ("auto").
TEXTURE_NETWORKS = ("siren", "siren-wide", "grid", "grid-uniform", "grid-normals", "grid-auto")

#: The fit settings of the "grid" construction at a preset whose own network is a SIREN (a grid preset's
#: constructions keep its own).
GRID_TEXTURE = {"network": "grid", "width": 64, "depth": 1, "lr": 1e-2, "edge_share": 0.5, "normal_inputs": "off"}

#: The grid constructions that differ by their ``normal_inputs`` alone.
_GRID_NORMALS = {"grid": "off", "grid-normals": "on", "grid-auto": "auto"}


def _sdf_settings(given: dict | None) -> dict:
    """``{field: value}`` of SDF fit settings checked against :class:`~neural_bake.fit.sdf_config.SdfFitConfig`'s
    fields and types (text read as the field's type); NeuralBakeError naming the first bad one."""
    from ..configs import convert, field_types
    from ..fit.sdf_config import SdfFitConfig

    types = field_types(SdfFitConfig)
    out = {}
    for key, value in (given or {}).items():
        if key in ("minutes", "steps", "budget"):
            raise NeuralBakeError(f"fidelity: sdf_settings cannot set {key!r}; the budget is the benchmark's own "
                                  "(minutes, steps)", parameter="sdf_settings")
        if key not in types:
            raise NeuralBakeError(f"fidelity: sdf_settings: unknown SDF fit setting {key!r}", parameter="sdf_settings")
        out[key] = convert(value, types[key], f"fidelity: sdf_settings: {key}")
    return out


def texture_network_settings(name: str, preset: str) -> dict:
    """The texture-fit overrides of construction ``name`` (:data:`TEXTURE_NETWORKS`) at texture ``preset``:
    empty when the construction is the preset's own network."""
    from ..fit.presets import TEXTURE_ALIASES, resolve_preset
    from ..fit.texture import PRESET_SIRENS, PRESETS, TextureFitConfig

    key = resolve_preset(preset, TEXTURE_ALIASES, PRESETS)
    own = {**vars(TextureFitConfig()), **(PRESETS[key] if key is not None else {})}
    siren = {**own, **PRESET_SIRENS.get(key, {})} if own["network"] != "siren" else own
    # a grid preset's grid constructions keep its MLP and settings; a SIREN preset's take GRID_TEXTURE's
    grid = {**GRID_TEXTURE, **({k: own[k] for k in ("width", "depth", "lr", "edge_share")}
                               if own["network"] == "grid" else {})}
    if name == "siren":
        over = {"network": "siren"}
    elif name == "siren-wide":
        over = {"network": "siren", "width": 2 * int(siren["width"]), "depth": int(siren["depth"]) + 1}
    elif name in _GRID_NORMALS:
        over = {**grid, "normal_inputs": _GRID_NORMALS[name]}
    elif name == "grid-uniform":
        over = {**grid, "edge_share": 0.0}
    else:
        raise NeuralBakeError(f"fidelity: texture_networks must be among {', '.join(TEXTURE_NETWORKS)}, got {name!r}")
    return {} if all(own.get(k) == v for k, v in over.items()) else over


def own_texture_network(preset: str) -> str:
    """The construction (:data:`TEXTURE_NETWORKS`) a texture ``preset`` fits by itself: "grid", "grid-normals",
    "grid-auto" or "siren"."""
    from ..fit.presets import TEXTURE_ALIASES, resolve_preset
    from ..fit.texture import PRESETS

    key = resolve_preset(preset, TEXTURE_ALIASES, PRESETS)
    own = {} if key is None else PRESETS[key]
    network = str(own.get("network", "siren"))
    if network != "grid":
        return network
    return {v: k for k, v in _GRID_NORMALS.items()}[str(own.get("normal_inputs", "off"))]


def network_label(model) -> str:
    """A colour network in a row: "WxD" for a SIREN, "grid L×F 2^T R0–Rmax, WxD relu" for a grid network."""
    arch = getattr(model, "architecture", {})
    if arch.get("network") == "grid":
        return (f"grid {arch['levels']}x{arch['features']} 2^{arch['log2_table']} {arch['base_resolution']}–"
                f"{arch['max_resolution']}, {arch['width']}x{arch['depth']} {arch['activation']}"
                + (", normals" if arch.get("in_dim") == 6 else ""))
    return f"{arch.get('width')}x{arch.get('depth')}"

#: Surface-sampling variants the benchmark can compare in one run (``sampling=``): their SDF fit settings.
#: "uniform" is the baseline every ratio is taken against; "preset" keeps the preset's own settings; "sign" and
#: "no-sign" set the sign-error mining of the uniform batch (``SdfFitConfig.sign_fraction``) on and off; "audit"
#: adds the residual construction's band audit to it (``SdfFitConfig.audit_candidates``), "no-audit" removes it;
#: "texel" and "no-texel" draw half the surface and near pools by UV area or none (``SdfFitConfig.texel_sampling``);
#: "edge" and "no-edge" a quarter of them along the hard edges or none (``SdfFitConfig.edge_sampling``).
SAMPLINGS: dict[str, dict] = {
    "preset": {},
    "uniform": {"curvature_sampling": 0.0, "error_sampling": 0.0, "texel_sampling": 0.0},
    "curvature": {"curvature_sampling": 0.5, "error_sampling": 0.0},
    "error": {"curvature_sampling": 0.0, "error_sampling": 0.25},
    "curvature+error": {"curvature_sampling": 0.5, "error_sampling": 0.25},
    "sign": {"sign_fraction": 0.5},
    "no-sign": {"sign_fraction": 0.0},
    "audit": {"sign_fraction": 0.5, "audit_candidates": 100_000},
    "no-audit": {"audit_candidates": 0},
    "texel": {"texel_sampling": 0.5},
    "no-texel": {"texel_sampling": 0.0},
    "edge": {"edge_sampling": 0.25},
    "no-edge": {"edge_sampling": 0.0},
}

#: The targets on nefertiti (decimated to 3,000 faces, 1024² map): median baked normal error, by the
#: fit's time budget in minutes (at equal time: the 2-minute and the 10-minute presets).
TARGETS = {("nefertiti", 2.0): 1.4, ("nefertiti", 10.0): 1.0}

#: The median baked normal errors the "halve at every preset" target starts from, by the fit's budget in
#: minutes: the detailed scans with the 2-, 5- and 10-minute presets of that time (64x1, 128x2 and 256x3;
#: BENCHMARKS.md, "Previous presets" and the 5-minute rows).
HALVE_FROM = {("nefertiti", 2.0): 2.64, ("ogre", 2.0): 4.88, ("nefertiti", 5.0): 1.25, ("ogre", 5.0): 2.95,
              ("nefertiti", 10.0): 1.19, ("ogre", 10.0): 2.57}


def target_text(name: str, minutes: float | None, median: float | None) -> str | None:
    """The targets a row of ``name`` at a ``minutes`` budget is held to, each marked met or NOT met
    by its map ``median`` (degrees); None when no target applies."""
    parts = []
    limit, start = TARGETS.get((name, minutes)), HALVE_FROM.get((name, minutes))
    ok = median is not None and math.isfinite(median)
    if limit is not None:
        parts.append(f"map ≤ {limit}°: " + ("met" if ok and median <= limit else "NOT met"))
    if start is not None:
        ratio = f", {median / start:.2f}×" if ok else ""
        parts.append(f"halving {start}°: " + ("met" if ok and median <= start / 2 else "NOT met") + ratio)
    return "; ".join(parts) or None


def open_caps(model, mesh, *, n: int = 50_000, resolution: int = 128, seed: int = 0,
              mesh_to_net_max: float | None = None) -> dict | None:
    """Distances of an open mesh's SDF surface split at the caps the SDF closes its holes with.

    A point of f = 0 (marching cubes, ``n`` samples) belongs to a cap when its closest point on ``mesh`` lies on
    a boundary edge (or boundary vertex): the hole is where it is nearest. Returns ``{"cap_share": share of
    f = 0 samples on caps, "hausdorff_without_caps": max(f = 0 → mesh without caps, mesh → f = 0),
    "cap_max": f = 0 → mesh over the caps}`` (unit frame), or None for a closed mesh. ``mesh_to_net_max``:
    the mesh → f = 0 distance if already measured (:func:`~neural_bake.fit.metrics.sdf_metrics`).
    """
    from ..bake.baseline import closest_surface
    from ..fit.metrics import _sample_triangles, sdf_metrics, zero_level_mesh

    f = mesh.faces
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    boundary = uniq[count == 1]
    if len(boundary) == 0:
        return None
    mv, mf = zero_level_mesh(model, int(resolution))
    pts, _ = _sample_triangles(mv, mf, int(n), np.random.default_rng([seed, 11]))
    close = closest_surface(mesh, pts)
    bary, face = close["bary"], close["face"]
    zero = bary < 1e-6
    on_vertex = zero.sum(axis=1) >= 2
    on_edge = zero.sum(axis=1) == 1
    bverts = np.zeros(mesh.n_vertices, dtype=bool)
    bverts[boundary.ravel()] = True
    corners = f[face]
    cap = np.zeros(len(pts), dtype=bool)
    v_idx = np.argmax(bary, axis=1)
    cap[on_vertex] = bverts[corners[on_vertex, v_idx[on_vertex]]]
    if on_edge.any():
        rows = np.flatnonzero(on_edge)
        keep = ~zero[rows]
        ends = np.sort(corners[rows][keep].reshape(-1, 2), axis=1)
        key = ends[:, 0].astype(np.int64) * (mesh.n_vertices + 1) + ends[:, 1]
        bkey = boundary[:, 0].astype(np.int64) * (mesh.n_vertices + 1) + boundary[:, 1]
        cap[rows] = np.isin(key, bkey)
    d = close["distance"]
    if mesh_to_net_max is None:
        mesh_to_net_max = sdf_metrics(model, mesh, n=int(n), resolution=int(resolution), seed=seed)["mesh_to_net_max"]
    return {"cap_share": float(cap.mean()),
            "hausdorff_without_caps": max(float(d[~cap].max()) if (~cap).any() else 0.0, mesh_to_net_max),
            "cap_max": float(d[cap].max()) if cap.any() else 0.0}


def _source_bytes(path: Path) -> int:
    """Bytes of a mesh file, with a .gltf's external buffers (its .bin); textures not counted."""
    size = path.stat().st_size
    if path.suffix.lower() == ".gltf":
        import json
        from urllib.parse import unquote

        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return size
        for buf in doc.get("buffers", []):
            uri = buf.get("uri") if isinstance(buf, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:") and (path.parent / unquote(uri)).is_file():
                size += (path.parent / unquote(uri)).stat().st_size
    return size


def _stats(rep: dict, key: str, what=("median", "p95")) -> tuple:
    head, _, tail = key.partition(".")
    d = rep.get(head) or {}
    d = d.get(tail) or {} if tail else d
    return tuple(d.get(w) for w in what)


def _adam_seconds_per_step(fit) -> float | None:
    """Seconds per Adam step of a fit (its polish excluded; a residual construction's fine level's)."""
    if not fit.steps:
        return None
    seconds = fit.seconds if getattr(fit, "fine_seconds", None) is None else fit.fine_seconds
    return (seconds - float((fit.polish or {}).get("seconds") or 0.0)) / fit.steps


def _networks(fit) -> tuple[str, int]:
    """A fit's networks as a row names them ("192x3", "64x3+192x3") and their parameters (a residual
    construction's two networks', not the zero blocks of their sum as one network)."""
    from ..fit.residual import ResidualSdfFit

    if isinstance(fit, ResidualSdfFit) and fit.fine is not None and fit.coarse is not None:
        params = sum(p.numel() for m in (fit.coarse.model, fit.fine) for p in m.parameters())
        return fit.label, params
    label = fit.label if isinstance(fit, ResidualSdfFit) else f"{fit.config.width}x{fit.config.depth}"
    return label, sum(p.numel() for p in fit.model.parameters())


def _baselines(rows: list[dict], column: str, value: str) -> dict:
    """The row each row is compared with: the one of the same case whose ``column`` is ``value`` (the other
    case columns equal), keyed by :func:`id` of the row (absent: no such row in the run)."""
    case = ("mesh", "preset", "step_cap", "sampling", "construction")

    def key(r):
        return tuple(r.get(k) for k in case if k != column)

    base = {key(r): r for r in rows if r.get(column) == value}
    return {id(r): base[key(r)] for r in rows if key(r) in base}


def _ratio_columns(r: dict, b: dict | None, pairs) -> None:
    for key, out in pairs:
        ok = b is not None and r.get(key) is not None and b.get(key)
        r[out] = r[key] / b[key] if ok else None


def _with_ratios(rows: list[dict]) -> None:
    """Adds to each row its ratios against the "uniform" row of the same mesh, preset, step count and
    construction (measured in the same run): map median and p95, Hausdorff, seconds per Adam step, and the
    sampling's cost ratio: (the baseline's step + this row's extra sampling seconds per step) / the baseline's
    step, which a loaded machine disturbs less than the ratio of whole steps (the step's own work is the
    same); and against the "plain" construction of the same mesh, preset, step count and sampling: map
    median and p95, Hausdorff (``plain_*_ratio``)."""
    base = _baselines(rows, "sampling", "uniform")
    plain = _baselines(rows, "construction", "plain")
    for r in rows:
        b = base.get(id(r))
        _ratio_columns(r, b, (("map_median_deg", "median_ratio"), ("map_p95_deg", "p95_ratio"),
                              ("hausdorff", "hausdorff_ratio"), ("s_per_step", "step_cost_ratio")))
        _ratio_columns(r, plain.get(id(r)), (("map_median_deg", "plain_median_ratio"),
                                             ("map_p95_deg", "plain_p95_ratio"),
                                             ("hausdorff", "plain_hausdorff_ratio")))
        ok = b is not None and all(x.get(k) is not None for x in (r, b) for k in ("s_per_step", "sampling_share"))
        r["sampling_cost_ratio"] = (1.0 + (r["s_per_step"] * r["sampling_share"] - b["s_per_step"] * b[
            "sampling_share"]) / b["s_per_step"]) if ok and b["s_per_step"] else None


def _row(name, preset, fit, fit_s, metrics, caps, rep, bake_s, source_mb, tex, alone) -> dict:
    """One normal row: ``rep`` the hybrid bake's report, ``alone`` the report of the same bake without the
    hybrid (``neural_*``: ∇f at every texel, as computed, before the map's 8-bit encoding, like the classical
    bake's column; ``neural_evaluated_*``: ∇f where the hybrid bake evaluated or interpolated it; ``faces_*``:
    the source's own face normals at the same closest points, what its exact SDF's gradient gives there: the
    floor of any field that keeps to the surface, above 0 where the file shades away from its geometry)."""
    med, p95 = _stats(rep, "vs_truth_deg")
    n_med, n_p95 = _stats(alone, "gradient_vs_truth_deg")
    e_med, e_p95 = _stats(rep, "neural_vs_truth_deg")
    b_med, b_p95 = _stats(rep, "baseline.vs_truth_deg")
    g_med, g_p95 = _stats(rep, "geometric_vs_truth_deg")
    f_med, f_p95 = _stats(rep, "faces_vs_truth_deg")
    net, params = _networks(fit)
    coarse = getattr(fit, "coarse", None)
    row = {
        "mesh": name, "preset": preset, "net": net, "construction": getattr(fit, "construction", "plain"),
        "sampling": None, "step_cap": None, "steps": fit.steps, "s_per_step": _adam_seconds_per_step(fit),
        "coarse_steps": None if coarse is None else coarse.steps, "band": getattr(fit, "band", None),
        "audit_kept": (getattr(fit, "audit", None) or {}).get("kept"),
        "audit_s": (getattr(fit, "audit", None) or {}).get("seconds"),
        "sampling_share": (None if not fit.sampling_seconds or not fit.seconds
                           else fit.sampling_seconds / (_adam_seconds_per_step(fit) * fit.steps)),
        "expected_steps": _fine_account(fit).get("expected_steps"), "fit_s": fit_s,
        "hausdorff": metrics["hausdorff"], "chamfer_l1": metrics["chamfer_l1"],
        "hausdorff_without_caps": None if caps is None else caps["hausdorff_without_caps"],
        "cap_max": None if caps is None else caps["cap_max"],
        "map_median_deg": med, "map_p95_deg": p95, "neural_median_deg": n_med, "neural_p95_deg": n_p95,
        "neural_evaluated_median_deg": e_med, "neural_evaluated_p95_deg": e_p95,
        "classical_median_deg": b_med, "classical_p95_deg": b_p95, "coarse_median_deg": g_med,
        "coarse_p95_deg": g_p95, "faces_median_deg": f_med, "faces_p95_deg": f_p95, "map_max_deg": _stats(rep, "vs_truth_deg", ("max",))[0],
        "classical_max_deg": _stats(rep, "baseline.vs_truth_deg", ("max",))[0],
        "coarse_max_deg": _stats(rep, "geometric_vs_truth_deg", ("max",))[0], "hybrid_pct": 100.0 * (rep.get("hybrid") or {}).get("hybrid_fraction", 0.0),
        "bake_s": bake_s, "classical_s": (rep.get("baseline") or {}).get("seconds", {}).get("total"),
        "texture_psnr_db": None if tex is None else tex.get("psnr"),
        "classical_texture_psnr_db": None if tex is None else tex.get("classical_psnr"),
        "networks_kb": (params + (0 if tex is None else tex["params"])) * 4 / 1024.0, "source_mb": source_mb,
        "target": target_text(name, fit.config.minutes, med),
        "hidden_pct": _hidden_pct(rep),
    }
    return row


def _fine_account(fit) -> dict:
    """The budget account of the level ``steps`` counts: a construction's fine level (its coarse level's steps
    are ``coarse_steps``), or the plain fit's whole account; {} without one."""
    budget = fit.budget or {}
    return (budget.get("levels") or {}).get("fine") or budget


def _hidden_pct(rep: dict) -> float:
    """The share (%) of the measured texels left out of the figures as hidden: their nearest source surface is
    buried in another of its shells (:func:`~neural_bake.bake.report.bake_report`)."""
    hidden = int(rep.get("hidden_texels", 0))
    seen = int((rep.get("vs_truth_deg") or {}).get("count") or 0)
    return 100.0 * hidden / (hidden + seen) if hidden + seen else 0.0


def run(quick: bool = False, *, meshes: list[str] | None = None, presets: list[str] | None = None,
        faces: int | None = None, size: int | None = None, minutes: float | None = None, texture: bool | None = None,
        data: str | os.PathLike | None = None, sampling: list[str] | None = None, steps: list[int] | None = None,
        save_dir: str | os.PathLike | None = None, texture_steps: int | None = None, only_textures: bool = False,
        texture_networks: list[str] | None = None, texture_minutes: float | None = None,
        constructions: list[str] | None = None, sdf_settings: dict | None = None, log=None) -> dict:
    """Run the fidelity benchmark; returns ``{"name", "machine", "quick", "rows", "notes"}``.

    - ``meshes``: names of :data:`MESHES` or :data:`SAMPLE_MESHES`, or mesh file paths (default: every mesh the
      data folder holds; quick: fandisk).
    - ``presets``: SDF presets (default quick: "quick"; full: "quick" and "high").
    - ``faces``, ``size``: decimation target and map side (default 3,000 and 1024; quick 1,000 and 256).
    - ``minutes``: override every preset's time budget (default: the preset's; quick 0.3).
    - ``texture``: also fit a texture (same preset name) for textured assets (default: not with quick).
    - ``data``: the data folder (default :func:`data_folder`).
    - ``sampling``: names of :data:`SAMPLINGS` to fit and bake side by side (default: the preset's own);
      rows get ratios against "uniform" of the same mesh, preset and step count (add it to have them).
    - ``steps``: step counts to fit each case for, without a time budget (equal steps compare sampling
      methods fairly on a loaded machine; the per-step cost ratio says what a step costs more).
    - ``save_dir``: also save every fitted SDF as ``save_dir/MESH-PRESET[-STEPS][-VARIANT].sdf`` (to re-bake
      or time them, e.g. ``bench bake --anchor-model``).
    - ``texture_steps``: Adam steps of every texture fit (default: the preset's steps on the quiet reference
      machine, ``budget="steps"``, so the figures do not follow the machine's load; quick 200).
    - ``only_textures``: the texture rows alone (textured assets only; no SDF metrics, no normal bake), the SDF
      fitted with ``budget="steps"`` unless ``minutes`` or ``steps`` is given (default meshes: those of
      :data:`MESHES` with a texture; quick: spot).
    - ``texture_networks``: colour-network constructions (:data:`TEXTURE_NETWORKS`) fitted and scored side by
      side, one texture row each (default: the preset's own network: "grid" for quick, else "siren"); the
      normal rows' texture PSNR is the first's. With neither ``texture_steps`` nor ``texture_minutes``, the
      preset's own network alone runs the preset's steps on the reference machine, and any other
      construction makes every texture fit run the preset's time budget (equal time).
    - ``texture_minutes``: the time budget of every texture fit (equal time; the steps made follow the machine).
    - ``constructions``: SDF constructions (:data:`~neural_bake.fit.residual.CONSTRUCTIONS`: "plain", one
      network; "residual", a fine level fitted on a coarse one inside its band; "residual-warm"; default: the
      preset's own, :attr:`~neural_bake.fit.sdf_config.SdfFitConfig.construction`) fitted
      at the same budget and baked side by side, one row each; rows get ratios against "plain" of the same
      mesh, preset, step count and sampling (``plain_median_ratio``, ``plain_p95_ratio``,
      ``plain_hausdorff_ratio``; add "plain" to have them).
    - ``sdf_settings``: ``{field: value}`` of :class:`~neural_bake.fit.sdf_config.SdfFitConfig` set on every SDF
      fit over the preset's (e.g. ``{"coarse_share": 0.1}``: a preset's setting measured before it is changed);
      text values are read as the field's type. Rows carry them as ``sdf_settings``, labels and saved models'
      names as ``field=value``. NeuralBakeError for an unknown field, a bad value, or a budget field (``minutes``,
      ``steps``: the benchmark's own options).

    The result has ``"texture_rows"`` (one per textured case with a texture fit) and, when there are any,
    ``"tables"`` (the normal rows and the texture rows, as the bench report prints them).
    """
    from ..fit.metrics import sdf_metrics
    from ..fit.residual import CONSTRUCTIONS, fit_sdf_construction
    from ..io.mesh_io import load_mesh
    from ..pipelines.bake_asset import BakeAssetConfig, bake_asset

    say = log or (lambda s: None)
    presets = list(presets or (["quick"] if quick else ["quick", "high"]))
    faces = int(faces or (1000 if quick else 3000))
    size = int(size or (256 if quick else 1024))
    minutes = minutes if minutes is not None else (0.3 if quick else None)
    texture = (not quick or only_textures) if texture is None else bool(texture)
    if only_textures and not texture:
        raise NeuralBakeError("fidelity: only_textures needs the texture fits (texture=False given)")
    networks = list(texture_networks or [])
    bad_nets = [n for n in networks if n not in TEXTURE_NETWORKS]
    if bad_nets or len(set(networks)) != len(networks):
        raise NeuralBakeError(f"fidelity: texture_networks must be distinct names among {', '.join(TEXTURE_NETWORKS)}, "
                              f"got {', '.join(networks)}", parameter="texture_networks")
    if texture_minutes is not None and not (isinstance(texture_minutes, (int, float)) and math.isfinite(texture_minutes)
                                            and texture_minutes > 0):
        raise NeuralBakeError(f"fidelity: texture_minutes must be a positive number, got {texture_minutes!r}",
                              parameter="texture_minutes")
    if texture_minutes is not None and texture_steps is not None:
        raise NeuralBakeError("fidelity: give texture_steps or texture_minutes, not both", parameter="texture_minutes")
    default_steps = 200 if quick and texture_minutes is None else None
    texture_steps = texture_steps if texture_steps is not None else default_steps
    if texture_steps is not None and (isinstance(texture_steps, bool) or int(texture_steps) < 1):
        raise NeuralBakeError(f"fidelity: texture_steps must be a positive integer, got {texture_steps!r}")
    if texture_steps is not None:
        texture_budget: dict = {"steps": int(texture_steps), "minutes": None}
    elif texture_minutes is not None:
        texture_budget = {"minutes": float(texture_minutes), "budget": "time"}
    else:  # resolved per preset: its steps on the reference machine when every construction is its own network
        texture_budget = {}
    notes: list[str] = []
    folder = data_folder(data)
    jobs: list[tuple[str, Path, dict]] = []
    textured = [m for m in MESHES if m in TEXTURED]
    wanted = meshes or ((["spot"] if quick else textured) if only_textures else (["fandisk"] if quick else list(MESHES)))
    for m in wanted:
        if m in SAMPLE_MESHES:
            from ..samples import sample_path

            jobs.append((m, sample_path(SAMPLE_MESHES[m]["sample"]), dict(SAMPLE_MESHES[m])))
        elif m in MESHES:
            if folder is None:
                notes.append(f"{m}: skipped, no data folder (set NEURAL_BAKE_DATA)")
                continue
            spec = MESHES[m]
            p = folder / spec["path"]
            if not p.is_file():
                notes.append(f"{m}: skipped, {p} not found")
                continue
            jobs.append((m, p, {**spec, "texture": None if "texture" not in spec else str(folder / spec["texture"])}))
        else:
            jobs.append((Path(m).stem, Path(m), {}))
    sampling = list(sampling or ["preset"])
    unknown = [v for v in sampling if v not in SAMPLINGS]
    if unknown:
        raise NeuralBakeError(f"fidelity: sampling must be among {', '.join(SAMPLINGS)}, got {', '.join(unknown)}")
    kinds: list[str | None] = [*constructions] if constructions else [None]  # None: the preset's own
    bad = [c for c in kinds if c is not None and c not in CONSTRUCTIONS]
    if bad or len(set(kinds)) != len(kinds):
        raise NeuralBakeError(f"fidelity: constructions must be distinct names among {', '.join(CONSTRUCTIONS)}, "
                              f"got {', '.join(map(str, kinds))}", parameter="constructions")
    if only_textures and kinds not in ([None], ["plain"]):
        raise NeuralBakeError("fidelity: only_textures fits the plain SDF (its reference steps); constructions "
                              f"{', '.join(map(str, kinds))} are for the normal rows", parameter="constructions")
    settings = _sdf_settings(sdf_settings)
    caps_of_steps = [None] if not steps else [int(n) for n in steps]
    if any(n is not None and n < 1 for n in caps_of_steps):
        raise NeuralBakeError(f"fidelity: steps must be positive integers, got {steps!r}")
    if save_dir is not None:  # before any fit: a bad folder fails in a second, not after an hour
        try:
            Path(save_dir).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise NeuralBakeError(f"{save_dir}: cannot create the models folder ({exc.strerror or exc})") from None
    rows: list[dict] = []
    texture_rows: list[dict] = []
    for name, path, spec in jobs:
        mesh = load_mesh(path, spec.get("texture"))
        if only_textures and (mesh.texture is None or mesh.uv is None):
            notes.append(f"{name}: skipped, no texture (texture rows only)")
            continue
        source_mb = _source_bytes(path) / 2**20
        coarse = spec.get("coarse", f"decimate:{faces}")
        cases = [(p, n, v, c) for p in presets for n in caps_of_steps for v in sampling for c in kinds]
        for preset, step_cap, variant, construction in cases:
            label = f"{name} {preset}" + ("" if step_cap is None else f" {step_cap} steps") + (
                "" if variant == "preset" else f" {variant}") + ("" if construction is None else f" {construction}") + (
                "".join(f" {k}={v}" for k, v in settings.items()))
            say(f"{label}: fitting the SDF")
            t0 = time.perf_counter()
            over = {} if minutes is None else {"minutes": minutes}
            if step_cap is not None:
                over = {"minutes": None, "steps": step_cap}
            sdf_over = {"budget": "steps"} if only_textures and not over else over
            fit = fit_sdf_construction(mesh, construction, preset=preset, progress=False,
                                       **{**sdf_over, **SAMPLINGS[variant], **settings})
            fit_s = time.perf_counter() - t0
            if save_dir is not None:
                stem = "-".join([Path(name).stem, preset, *([] if step_cap is None else [str(step_cap)]),
                                 *([] if variant == "preset" else [variant]),
                                 *([] if construction is None else [construction]),
                                 *(f"{k}={v}" for k, v in settings.items())])
                fit.save(Path(save_dir) / f"{stem}.sdf")
            n, res = (20_000, 96) if quick else (50_000, 128)
            metrics = caps = None
            if not only_textures:
                metrics = sdf_metrics(fit.model, mesh, n=n, resolution=res)
                caps = None if mesh.watertight else open_caps(fit.model, mesh, n=n, resolution=res,
                                                               mesh_to_net_max=metrics["mesh_to_net_max"])
            with tempfile.TemporaryDirectory(prefix="bench-fidelity-") as tmp:
                sdf_path = Path(tmp) / "f.sdf"
                fit.save(sdf_path)
                tex = tex_path = None
                maps = "normal"
                if texture and mesh.texture is not None and mesh.uv is not None:
                    from ..fit.texture import fit_texture

                    names = networks or [own_texture_network(preset)]
                    net_settings = [texture_network_settings(net, preset) for net in names]
                    # the preset's own network alone: its steps on the reference machine (not the load's); any
                    # other construction: every fit at the preset's time budget (equal time)
                    budget = texture_budget or ({"budget": "steps"} if not any(net_settings) else {"budget": "time"})
                    for k, (net, over) in enumerate(zip(names, net_settings)):
                        say(f"{label}: fitting the texture ({net})")
                        tfit = fit_texture(mesh, str(sdf_path), preset=preset, **budget, **over)
                        path_k = Path(tmp) / f"g{k}.tex"
                        tfit.save(path_k)
                        if tex_path is None:
                            tex_path = path_k
                            tex = {"params": sum(p.numel() for p in tfit.model.parameters()),
                                   "seconds": tfit.seconds}
                        texture_rows.append(_texture_row(name, preset, path, sdf_path, path_k, spec, coarse, size,
                                                         fit, tfit, f"{label} {net}", say, network=net))
                    maps = "normal,albedo"
                if only_textures:
                    continue
                say(f"{label}: baking {size}² onto {coarse}")
                t0 = time.perf_counter()
                rep = bake_asset(path, str(sdf_path), Path(tmp) / "out",
                                 BakeAssetConfig(coarse=coarse, size=size, maps=maps, texture=spec.get("texture"),
                                                 truth="mesh", cache_texels=True, force=True),
                                 texture_model=None if tex_path is None else str(tex_path), log=lambda s: None)
                bake_s = time.perf_counter() - t0
                # ∇f alone at every texel: the same bake without the hybrid (the hybrid bake's report scores
                # ∇f only where it evaluated or interpolated it, not in cells given up to the classical bake)
                alone = bake_asset(path, str(sdf_path), Path(tmp) / "alone",
                                   BakeAssetConfig(coarse=coarse, size=size, maps="normal", truth="mesh",
                                                   cache_texels=True, force=True, hybrid=False, baseline=False),
                                   log=lambda s: None)
            if tex is not None:
                tex["psnr"] = rep.get("color_psnr_db")
                tex["classical_psnr"] = (rep.get("baseline") or {}).get("color_psnr_db")
            row = _row(name, preset, fit, fit_s, metrics, caps, rep, bake_s, source_mb, tex, alone)
            row.update(sampling=variant, step_cap=step_cap, sdf_settings=dict(settings) or None)
            rows.append(row)
            for w in rep.get("warnings", []):
                notes.append(f"{label}: {w}")
            if fit.budget and fit.budget.get("warning"):
                notes.append(f"{label}: {fit.budget['warning']}")
    _with_ratios(rows)
    if texture_rows:
        notes.append("texture rows: albedo PSNR (dB) and SSIM on the 8-bit sRGB maps over the covered texels, "
                     "against the source texture at each texel's closest source point and (vs_classical) against "
                     "the classical transfer of the same texels; hybrid: the default colour tolerance (ΔE "
                     f"{HYBRID_COLOR_DELTA_E:g}); *_time_ratio: a bake's seconds over the network alone's")
    if not only_textures:
        notes.append("bakes are forced past the SDF/mesh agreement check: a weak fit is measured, not refused "
                     "(the hybrid share says how much of its map is classical)")
        notes.append("errors: angle between the baked normal (as a renderer decodes the 8-bit map) and the source "
                     "mesh's interpolated normal at the closest point, on the same texels for every column; a "
                     "glTF's own vertex normals are the reference; texels whose closest point lies on a face buried "
                     "in another shell of the source (inside the solid, never seen) are left out of every column "
                     "(hidden_pct)")
    notes.append(load_note())
    out = {"name": "fidelity", "title": "fidelity on real assets (normal error in degrees vs the source mesh)",
           "machine": machine_info(), "quick": quick, "faces": faces, "size": size, "rows": rows,
           "texture_rows": texture_rows, "notes": notes}
    if texture_rows:
        out["tables"] = {"textures": texture_rows} if only_textures else {"normals": rows, "textures": texture_rows}
    return out


def _texture_row(name, preset, path, sdf_path, tex_path, spec, coarse, size, fit, tfit, label, say,
                 network: str = "siren") -> dict:
    """The texture row of one case (:func:`~neural_bake.bench.fidelity_texture.texture_row`) with its fits:
    the construction's name, its network, steps, seconds, milliseconds per step, threads and kilobytes."""
    from ..bake.job import load_inputs, make_coarse
    from .fidelity_texture import dot_windows, texture_row

    inputs = load_inputs(str(path), str(sdf_path), str(tex_path), coarse=coarse, texture_image=spec.get("texture"),
                         force=True, log=lambda s: None)
    coarse_m, _ = make_coarse(inputs, coarse)
    say(f"{label}: texture rows ({size}² onto {coarse})")
    params = sum(p.numel() for p in tfit.model.parameters())
    row = {"mesh": name, "preset": preset, "texture_network": network, "texture_net": network_label(tfit.model),
           "texture_steps": tfit.steps, "texture_fit_s": tfit.seconds,
           "texture_step_ms": 1000.0 * tfit.seconds / tfit.steps if tfit.steps else None,
           "texture_threads": (tfit.threads or {}).get("threads"),
           "texture_kb": params * 4 / 1024.0, "sdf_steps": fit.steps}
    features = dot_windows(size) if spec.get("features") == "dots" else None
    row.update(texture_row(inputs, coarse_m, size=size, keep=coarse == "keep", log=None, features=features))
    db = {k: "—" if row[f"{k}_psnr_db"] is None else f"{row[f'{k}_psnr_db']:.1f}" for k in ("network", "hybrid",
                                                                                         "classical")}
    dots = ""
    if row.get("network_feature_ssim_min") is not None:
        dots = (f"; 8-texel dots, worst SSIM: network {row['network_feature_ssim_min']:.3f}, hybrid "
                f"{row['hybrid_feature_ssim_min']:.3f}")
    say(f"{label}: albedo vs the source, network alone {db['network']} dB, hybrid {db['hybrid']} dB "
        f"({row['hybrid_color_pct']:.1f} % of texels replaced), classical {db['classical']} dB; "
        f"{row['texture_steps']} steps, {row['texture_fit_s']:.0f} s{dots}")
    return row
