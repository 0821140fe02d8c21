"""Benchmark of the training-data sampling: samples per second, and the inside test against the baselines.

Two tables:

- ``throughput``: surface samples (points, normals, uv, colours), near samples (σ = 0.01 / 0.003 mixed)
  and uniform samples with their ground-truth signed distance, on the bundled bumpy sphere (closed), the
  same with a cap cut off (open: the accelerated winding number signs it), and Keenan Crane's spot
  from the data folder when present.
- ``sign``: on the same query points (half near the surface, half uniform in the cube), each inside test
  against the exact generalised winding number (the reference): agreement of the signs, time, and the
  speed ratio to the baseline a user would otherwise pick, measured in the same run:
  ``trimesh.proximity.signed_distance`` when its ``rtree`` dependency is installed, otherwise open3d's own
  ``compute_signed_distance`` (one ray, parity).
"""

from __future__ import annotations

import time

import numpy as np

from ..geometry import import_open3d, raycasting_scene
from ..io.mesh_io import load_mesh
from ..types import Mesh
from .common import data_file, machine_info

__all__ = ["run"]

SPOT = data_file("spot/spot_triangulated.obj")


def _meshes() -> tuple[dict[str, Mesh], list[str]]:
    from ..samples import sample_path

    notes = []
    bumpy = load_mesh(sample_path("bumpy_sphere"))
    keep = bumpy.triangles.mean(1)[:, 2] < 0.85 * bumpy.vertices[:, 2].max()  # a hole of ~1/13 of the area
    open_bumpy = Mesh(vertices=bumpy.vertices, faces=bumpy.faces[keep], uv=bumpy.uv[keep], texture=bumpy.texture,
                      frame=bumpy.frame, uv_policy=bumpy.uv_policy, watertight=False,
                      source="bumpy_sphere minus its top cap")
    meshes = {"bumpy_sphere": bumpy, "bumpy_open": open_bumpy}
    if SPOT.is_file():
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            meshes["spot"] = load_mesh(SPOT, SPOT.with_name("spot_texture.png"))
    else:
        notes.append(f"{SPOT} not found: spot skipped")
    return meshes, notes


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _trimesh_sdf(mesh: Mesh, p: np.ndarray) -> np.ndarray:
    import trimesh

    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    return -trimesh.proximity.signed_distance(tm, p)  # trimesh: positive inside


def _open3d_sdf(mesh: Mesh, p: np.ndarray) -> np.ndarray:
    o3d = import_open3d()

    scene = raycasting_scene(mesh.vertices, mesh.faces)
    return scene.compute_signed_distance(o3d.core.Tensor(p.astype(np.float32))).numpy().astype(np.float64)


def run(quick: bool = False, n: int | None = None, n_sign: int | None = None, seed: int = 0) -> dict:
    """Run the benchmark; ``n`` samples per throughput row, ``n_sign`` query points per sign row."""
    from ..fit.sampling import sample_near, sample_surface, sample_uniform, signed_distance
    from ..mesh.winding import winding_number

    n = n or (5_000 if quick else 100_000)
    n_sign = n_sign or (500 if quick else 4_000)
    meshes, notes = _meshes()
    try:
        import rtree  # noqa: F401  (trimesh.proximity needs it)

        has_rtree = True
        notes.append("baseline of the speed-up column: trimesh.proximity.signed_distance")
    except ImportError:
        has_rtree = False
        notes.append("trimesh.proximity.signed_distance needs the 'rtree' package (not installed): the baseline of "
                     "the speed-up column is open3d's compute_signed_distance")
    through = []
    for name, mesh in meshes.items():
        signed_distance(mesh, np.zeros((2, 3)))  # warm-up: imports, first BVH
        for op, fn in (
            ("surface", lambda: sample_surface(mesh, n, seed=seed)),
            ("near σ=.01/.003", lambda: sample_near(mesh, n, sigma=(0.01, 0.003), seed=seed)),
            ("uniform", lambda: sample_uniform(mesh, n, seed=seed)),
            ("uniform hybrid", lambda: sample_uniform(mesh, n, seed=seed, sign="hybrid")),
        ):
            _, dt = _timed(fn)
            through.append({"mesh": name, "faces": mesh.n_faces, "closed": mesh.watertight, "op": op, "n": n,
                            "seconds": dt, "samples/s": n / dt})

    sign_rows = []
    for name, mesh in meshes.items():
        rng = np.random.default_rng(seed)
        near = sample_near(mesh, n_sign // 2, sigma=0.01, seed=seed + 1).points.astype(np.float64)
        p = np.concatenate([near, rng.uniform(-1, 1, (n_sign - len(near), 3))])
        ref, t_ref = _timed(lambda: winding_number(mesh, p, exact=True))
        ref_in = ref > 0.5
        methods = {}
        if has_rtree:
            methods["trimesh.proximity.signed_distance"] = lambda: _trimesh_sdf(mesh, p)
        methods.update({
            "open3d compute_signed_distance (1 ray)": lambda: _open3d_sdf(mesh, p),
            "ours raycast (3 rays)": lambda: signed_distance(mesh, p, sign="raycast"),
            "ours winding (accelerated)": lambda: signed_distance(mesh, p, sign="winding"),
            "ours hybrid (5 rays + winding)": lambda: signed_distance(mesh, p, sign="hybrid"),
            "ours auto": lambda: signed_distance(mesh, p, sign="auto"),
        })
        rows = []
        for method, fn in methods.items():
            d, dt = _timed(fn)
            rows.append({"mesh": name, "closed": mesh.watertight, "method": method, "n": n_sign, "seconds": dt,
                         "points/s": n_sign / dt, "sign agreement": float(np.mean((d < 0) == ref_in))})
        rows.append({"mesh": name, "closed": mesh.watertight, "method": "exact winding number (reference)",
                     "n": n_sign, "seconds": t_ref, "points/s": n_sign / t_ref, "sign agreement": 1.0})
        base = rows[0]["seconds"]  # the baseline: trimesh if it can run, else open3d alone
        for r in rows:
            r["speed-up vs baseline"] = base / r["seconds"]
        sign_rows += rows

    notes += [
        "sign agreement: fraction of points whose inside/outside matches the exact generalised winding number "
        "(w > 1/2); points are half near the surface (σ = 0.01), half uniform in [-1, 1]^3",
        "'ours auto' = raycast for closed meshes, accelerated winding number for open ones; the throughput rows "
        "of near/uniform include the ground-truth signed distance with 'auto'",
        "timings are single runs on a shared, busy CPU: expect noise of a factor ~2 between runs",
    ]
    return {
        "name": "sampling",
        "title": "Training-data sampling: throughput and inside test",
        "machine": machine_info(),
        "quick": quick,
        "tables": {"throughput": through, "sign": sign_rows},
        "notes": notes,
    }
