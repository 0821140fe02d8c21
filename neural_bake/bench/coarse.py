"""`neural-bake bench coarse`: coarse meshes by decimation vs marching cubes (dense, range-pruned, cost-aware).

One table, ``coarse meshes``, measured in the same run on the bundled bumpy sphere (and Keenan Crane's Spot
from ``DATA_DIR/spot`` in the full run, when present):

- ``decimate``: quadric edge collapse of the fine mesh to several face counts (what a user would otherwise pick;
  it needs the fine mesh); on the data folder's large scans (decimation rows only; the ogre in the quick run)
  the default, a fast first pass then pymeshlab, beside ``decimate pymeshlab alone`` of the same mesh, with
  the time as a ratio to it (``÷ pymeshlab alone``);
- ``march dense`` / ``march pruned`` / ``march auto``: marching cubes of an SDF network at several grid
  resolutions, every grid point evaluated, range-pruned octree (``pruned=True``), and the cost-aware octree
  (``pruned="auto"``, what ``--coarse march:N`` uses), each followed by the clean-up of ``coarse_mesh``.
  The three give the same triangles; the columns show the network evaluations (and ``fewer evals ×`` =
  grid points ÷ evaluations), the seconds spent bounding boxes and evaluating points, and the time as a
  ratio to the dense run.

Every row gives faces, seconds and the geometric error of the coarse mesh against the fine mesh in the unit
frame (Chamfer-L1 and Hausdorff of :func:`neural_bake.fit.metrics.mesh_distances`). Marching needs an SDF
model: ``sdf_model=PATH`` (of the bumpy sphere), else a small SIREN is trained with :func:`fit_sdf` first
((64, 1) for 30 s in the quick run, (128, 2) for 2 minutes in the full one) and the notes say so; the
marching error then includes the network's own fitting error.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import NeuralBakeError
from .common import load_note, machine_info

__all__ = ["run"]

#: Table columns, in order.
COLUMNS = ["mesh", "method", "setting", "faces", "seconds", "÷ pymeshlab alone", "time ÷ dense", "evaluations",
           "fewer evals ×", "bound s", "eval s", "levels bounded", "chamfer-L1", "hausdorff", "watertight", "note"]


def _meshes(quick: bool, notes: list) -> list:
    from ..io.mesh_io import load_mesh
    from ..samples.generate import sample_path
    from .fit import DATA_DIR

    out = [("bumpy_sphere", load_mesh(sample_path("bumpy_sphere")))]
    if not quick:
        spot = DATA_DIR / "spot" / "spot_triangulated.obj"
        if spot.is_file():
            out.append(("spot", load_mesh(spot)))
        else:
            notes.append(f"spot: {spot} not found; skipped")
    return out


#: Large meshes of the data folder decimated (no marching: no SDF is fitted for them), in the full run; the quick
#: run takes the first.
SCANS = ("scans/ogre.obj", "scans/nefertiti.obj", "bunny/bunny_closed.obj")


def _scans(scans, quick: bool, notes: list) -> list:
    from ..io.mesh_io import load_mesh
    from .fit import DATA_DIR

    out = []
    for rel in (SCANS[:1] if quick else SCANS) if scans is None else scans:
        path = DATA_DIR / rel  # an absolute path stays itself
        if path.is_file():
            out.append((path.stem, load_mesh(path)))
        else:
            notes.append(f"{rel}: {path} not found; skipped")
    return out


def _decimation_rows(name, fine, faces, samples, seed) -> list:
    """Rows of ``fine`` decimated to every count of ``faces``; where the first pass runs, pymeshlab alone before
    it, and the time as a ratio to that."""
    from ..mesh.decimate import decimate, first_pass_faces

    def row(nf: int, first: bool) -> dict:
        t0 = time.perf_counter()
        cm = decimate(fine, faces=nf, first_pass=first)
        dt = time.perf_counter() - t0
        return {"mesh": name, "method": "decimate" if first else "decimate pymeshlab alone", "setting": f"{nf} faces",
                "faces": cm.n_faces, "seconds": dt, **_errors(cm, fine, samples, seed),
                "watertight": bool(cm.watertight)}

    rows = []
    for nf in faces:
        first_faces = first_pass_faces(fine.n_faces, nf)
        alone = row(nf, False) if first_faces is not None else None
        ours = row(nf, True)
        if alone is not None:
            ours.update({"÷ pymeshlab alone": ours["seconds"] / alone["seconds"],
                         "note": f"a first pass to {first_faces} faces"})
            rows.append(alone)
        rows.append(ours)
    return rows


def _network(spec: str) -> tuple[int, int]:
    try:
        w, d = (int(x) for x in str(spec).lower().split("x"))
    except ValueError:
        raise NeuralBakeError(f"bench coarse: network must be WxD (e.g. 64x1), got {spec!r}") from None
    if w < 1 or d < 0:
        raise NeuralBakeError(f"bench coarse: network must be WxD with W >= 1, D >= 0, got {spec!r}")
    return w, d


def _sdf_for(name, mesh, sdf_model, network, minutes, steps, fit_overrides, seed, notes):
    """The SDF network to march for ``mesh``: the given model file (bumpy sphere only) or a quick fit."""
    from ..fit.sdf import fit_sdf, load_sdf

    if sdf_model and name == "bumpy_sphere":
        fit = load_sdf(sdf_model)
        same = np.allclose([*fit.frame.center, fit.frame.scale], [*mesh.frame.center, mesh.frame.scale], rtol=1e-6)
        if not same:
            notes.append(f"{sdf_model}: its frame differs from the bumpy sphere sample's; errors may be off")
        c = fit.config
        notes.append(f"{name}: SDF from {sdf_model} ({c.width}x{c.depth})")
        return fit.model
    w, d = _network(network)
    t0 = time.perf_counter()
    fit = fit_sdf(mesh, width=w, depth=d, minutes=minutes, steps=steps, progress=False, seed=seed,
                  **(fit_overrides or {}))
    notes.append(f"{name}: no SDF model given, trained a ({w}, {d}) SIREN with fit_sdf: {fit.steps} steps in "
                 f"{time.perf_counter() - t0:.0f} s (budget {minutes} min); a short fit, so the marching "
                 f"error includes its fitting error")
    return fit.model


def _errors(coarse, fine, n, seed) -> dict:
    from ..fit.metrics import mesh_distances

    d = mesh_distances(coarse.vertices, coarse.faces, fine.vertices, fine.faces, n=n, seed=seed)
    return {"chamfer-L1": d["chamfer_l1"], "hausdorff": d["hausdorff"]}


def run(
    quick: bool = False,
    *,
    sdf_model: str | None = None,
    faces=None,
    resolutions=None,
    network: str | None = None,
    minutes: float | None = None,
    steps: int = 100_000,
    fit_overrides: dict | None = None,
    samples: int | None = None,
    modes=("dense", "pruned", "auto"),
    scans=None,
    seed: int = 0,
) -> dict:
    """Run the benchmark (module docstring); returns the result dict of :mod:`neural_bake.bench.common`.

    Args:
        quick: the bumpy sphere (and the ogre scan, decimated to 2,000 faces); 500 and 2,000 faces; grids 32
            and 64; a (64, 1) fit of 30 s; 20,000 distance samples (about a minute and a half on an idle 2-core
            CPU).
        sdf_model: an SDF model file of the bumpy sphere sample to march (else one is trained).
        faces: decimation face counts (default 500, 2000, 8000).
        resolutions: marching-cubes grid resolutions (default 32, 64, 128).
        network: ``"WxD"`` of the SIREN trained when no model is given (default 64x1 quick, 128x2 full).
        minutes: its training budget (default 0.5 quick, 2 full).
        steps: its step cap.
        fit_overrides: more :class:`~neural_bake.fit.sdf.SdfFitConfig` fields for that fit (e.g. pool sizes).
        samples: surface samples per mesh for the distances (default 20,000 quick, 100,000 full).
        modes: marching modes among "dense", "pruned", "auto" ("dense" is always run: the ratios need it).
        scans: mesh paths decimated only (relative to the data folder, or absolute; default :data:`SCANS`).
        seed: seeds the fit and the distance samples.
    """
    from ..mesh.cleanup import clean_mesh
    from ..mesh.marching import march

    faces = list(faces or ([500, 2000] if quick else [500, 2000, 8000]))
    resolutions = list(resolutions or ([32, 64] if quick else [32, 64, 128]))
    network = network or ("64x1" if quick else "128x2")
    minutes = minutes if minutes is not None else (0.5 if quick else 2.0)
    samples = int(samples or (20_000 if quick else 100_000))
    bad = [m for m in modes if m not in ("dense", "pruned", "auto")]
    if bad:
        raise NeuralBakeError(f"bench coarse: unknown marching mode(s) {', '.join(map(repr, bad))} "
                              "(choose dense, pruned, auto)")
    _network(network)
    notes = ["timings: one run per row, no repetition"]
    rows = []
    for name, fine in _meshes(quick, notes):
        rows += _decimation_rows(name, fine, faces, samples, seed)
        model = _sdf_for(name, fine, sdf_model, network, minutes, steps, fit_overrides, seed, notes)
        for res in resolutions:
            dense_s = None
            for mode in ["dense", *[m for m in modes if m != "dense"]]:
                pruned = {"dense": False, "pruned": True, "auto": "auto"}[mode]
                row = {"mesh": name, "method": f"march {mode}", "setting": f"{res}³"}
                try:
                    t0 = time.perf_counter()
                    raw, st = march(model, res, pruned=pruned, frame=fine.frame)
                    cm, rep = clean_mesh(raw)
                    dt = time.perf_counter() - t0
                except NeuralBakeError as exc:
                    rows.append({**row, "note": str(exc)})
                    continue
                dense_s = dt if mode == "dense" else dense_s
                row.update(faces=cm.n_faces, seconds=dt, evaluations=st["evaluations"],
                           **{"fewer evals ×": st["evaluation_ratio"], "bound s": st["seconds_bound"],
                              "eval s": st["seconds_eval"], "levels bounded": st["levels_bounded"]})
                if dense_s:
                    row["time ÷ dense"] = dt / dense_s
                if cm.n_faces:
                    row.update(_errors(cm, fine, samples, seed))
                row["watertight"] = bool(cm.watertight)
                note = [st["reason"]] if st["reason"] else []
                if rep["faces_in"] != rep["faces_out"]:
                    note.append(f"clean-up removed {rep['faces_in'] - rep['faces_out']} faces")
                if rep["non_manifold_edges"]:
                    note.append(f"{rep['non_manifold_edges']} non-manifold edges")
                row["note"] = "; ".join(note)
                row["_levels"] = st["levels"]
                rows.append(row)
    for name, fine in _scans(scans, quick, notes):
        rows += _decimation_rows(name, fine, [2000] if quick else faces, samples, seed)
    notes.append("errors: Chamfer-L1 and Hausdorff of the coarse mesh against the fine mesh, unit frame "
                 f"({samples} samples per surface); seconds include the clean-up of coarse_mesh")
    notes.append("march pruned / auto give the same triangles as dense; 'time ÷ dense' and 'fewer evals ×' are "
                 "against the dense run of the same grid in this run; 'auto' is what --coarse march:N uses")
    notes.append(load_note())
    return {
        "name": "coarse",
        "title": "coarse: decimation vs marching cubes (dense, range-pruned, cost-aware), error against time",
        "machine": machine_info(),
        "quick": quick,
        "tables": {"coarse meshes": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]},
        "levels": [{"mesh": r["mesh"], "method": r["method"], "setting": r["setting"], "levels": r["_levels"]}
                   for r in rows if r.get("_levels")],
        "notes": notes,
    }
