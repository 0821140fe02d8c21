"""The classical mesh-to-mesh baseline: sphere oracle, closest-point fallback, texture colours, errors."""

import numpy as np
import pytest
import trimesh

from neural_bake.bake.baseline import baseline_bake, closest_surface
from neural_bake.errors import MeshError, NeuralBakeError
from neural_bake.mesh.texels import rasterize_texels
from neural_bake.mesh.unwrap import unwrap
from neural_bake.types import Frame, Mesh


def ico(sub, radius, frame=Frame()):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=radius)
    return Mesh(vertices=np.asarray(m.vertices), faces=np.asarray(m.faces, dtype=np.int64), frame=frame)


def unit(p):
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def angles(a, b):
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1, 1)))


@pytest.fixture(scope="module")
def coarse_texels():
    coarse = unwrap(ico(1, 0.7), resolution=64)
    coarse.vertex_normals = None  # faceted: the geometric normals are off by several degrees
    return coarse, rasterize_texels(coarse, 48)


def test_sphere_baseline_close_to_analytic(coarse_texels):
    coarse, tx = coarse_texels
    fine = ico(5, 0.7)
    out = baseline_bake(coarse, fine, tx, cage=0.1)
    assert out["hit"].all() and out["fallback"] == 0 and out["colors"] is None
    # the normal of the fine sphere where the rays land is radial at the hit point; compare with the
    # radial direction through the texel point (the ray leaves along the coarse normal, close to radial)
    err = angles(out["normals"], unit(tx.points))
    assert np.median(err) < 1.0 and np.median(angles(tx.normal, unit(tx.points))) > 2.0
    assert out["distance"].max() <= 0.1 and set(out["seconds"]) >= {"rays", "closest", "total"}


def test_tiny_cage_uses_closest_point_fallback(coarse_texels):
    coarse, tx = coarse_texels
    fine = ico(4, 0.75)  # 0.05 outside the coarse mesh everywhere
    out = baseline_bake(coarse, fine, tx, cage=1e-3)
    assert not out["hit"].any() and out["fallback"] == len(tx.points)
    assert np.all(out["distance"] > 0.04) and np.isfinite(out["normals"]).all()
    assert np.median(angles(out["normals"], unit(tx.points))) < 2.0


def test_frames_are_reconciled(coarse_texels):
    coarse, tx = coarse_texels
    # the same fine sphere, loaded in another unit frame (scaled by 2 and shifted)
    f2 = Frame((1.0, 0.0, 0.0), 2.0)
    fine = ico(5, 0.7)
    moved = Mesh(vertices=f2.to_unit(fine.vertices), faces=fine.faces, frame=f2)
    a = baseline_bake(coarse, fine, tx, cage=0.1)
    b = baseline_bake(coarse, moved, tx, cage=0.2)
    assert np.allclose(a["normals"], b["normals"], atol=1e-3)


def test_colours_from_the_fine_texture(coarse_texels):
    coarse, tx = coarse_texels
    fine = ico(3, 0.7)
    # texture: left half red, right half blue; UV u = 0.25 on x < 0 faces, 0.75 on the others
    tex = np.zeros((4, 4, 3), dtype=np.float32)
    tex[:, :2] = (1, 0, 0)
    tex[:, 2:] = (0, 0, 1)
    cx = fine.triangles[:, :, 0].mean(axis=1)
    u = np.where(cx < 0, 0.25, 0.75)
    fine.uv = np.stack([np.repeat(u[:, None], 3, axis=1), np.full((fine.n_faces, 3), 0.5)], axis=2)
    fine.texture = tex
    out = baseline_bake(coarse, fine, tx, cage=0.1)
    x = tx.points[:, 0]
    sure = np.abs(x) > 0.1
    expect = np.where((x < 0)[:, None], [1.0, 0, 0], [0, 0, 1.0])
    assert np.allclose(out["colors"][sure], expect[sure], atol=1e-6)
    # a bake of normals alone reads no texture: the same normals and points, no colours
    bare = baseline_bake(coarse, fine, tx, cage=0.1, colors=False)
    assert bare["colors"] is None
    for k in ("normals", "points", "hit", "distance"):
        np.testing.assert_array_equal(bare[k], out[k])


def test_closest_surface_on_sphere(rng):
    fine = ico(4, 0.5)
    p = unit(rng.normal(size=(50, 3))) * 0.8
    out = closest_surface(fine, p)
    assert np.allclose(out["distance"], 0.3, atol=2e-3)
    assert np.median(angles(out["normals"], unit(p))) < 1.0
    recon = np.einsum("mk,mkd->md", out["bary"], fine.triangles[out["face"]])
    assert np.allclose(recon, out["points"], atol=1e-5)


def test_errors(coarse_texels):
    coarse, tx = coarse_texels
    with pytest.raises(NeuralBakeError, match="cage must be a positive distance"):
        baseline_bake(coarse, ico(2, 0.7), tx, cage=0.0)
    empty = Mesh(vertices=np.zeros((3, 3)), faces=np.zeros((0, 3), dtype=np.int64), source="empty.obj")
    with pytest.raises(MeshError, match="empty.obj: baseline: the fine mesh has no faces"):
        baseline_bake(coarse, empty, tx)


def back_to_back_boards() -> Mesh:
    """Two coincident squares at z = 0 facing opposite ways (a board of no thickness), the upper one mapped onto
    the red half of a texture and the lower one onto the blue half."""
    sq = np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]])
    v = np.concatenate([sq, sq])
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]], dtype=np.int64)
    uv_up = 0.05 + 0.4 * (sq[:, :2] + 0.5)
    uv_down = uv_up + [0.5, 0.0]
    uv = np.concatenate([uv_up[f[:2]], (uv_down[f[2:] - 4])])
    tex = np.zeros((16, 16, 3), dtype=np.float32)
    tex[:, :8], tex[:, 8:] = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)
    return Mesh(vertices=v, faces=f, uv=uv, texture=tex, watertight=False)


def test_a_bake_onto_the_source_itself_reads_each_samples_own_face():
    mesh = back_to_back_boards()
    tx = rasterize_texels(mesh, 32)
    want = np.where((tx.face < 2)[:, None], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    split = Mesh(vertices=mesh.triangles.reshape(-1, 3), faces=np.arange(3 * len(mesh.faces)).reshape(-1, 3),
                 uv=mesh.uv, watertight=False)  # its vertices split at every face, as a layout splits them at seams
    for coarse in (mesh, Mesh(vertices=mesh.vertices.copy(), faces=mesh.faces.copy(), uv=mesh.uv, watertight=False),
                   split):
        out = baseline_bake(coarse, mesh, tx)
        assert np.abs(out["colors"] - want).max() < 1e-6  # every texel its own board's colour
        assert out["hit"].all() and out["distance"].max() == 0.0 and out["seconds"]["rays"] == 0.0
        assert np.allclose(out["points"], tx.points)
    # a coarse mesh that is not the source is baked by rays, whose hits on coincident faces are either board's
    moved = Mesh(vertices=mesh.vertices + [0.0, 0.0, 1e-4], faces=mesh.faces, uv=mesh.uv, watertight=False)
    assert baseline_bake(moved, mesh, tx)["seconds"]["rays"] > 0.0


def test_native_kernel_matches_the_numpy_path(coarse_texels, monkeypatch):
    """The C ray set-up, hit choice and shading (baseline.c) give the numpy path's bits: on a bake where some rays
    miss within a small cage, and on hand-made hits with ties, misses and hits beyond the cage."""
    from neural_bake.bake import baseline

    lib = baseline.KERNEL.lib()
    if lib is None:
        pytest.skip(baseline.kernel_status())
    coarse, tx = coarse_texels
    fine = ico(4, 0.72)
    for cage in (0.1, 0.015):
        native = baseline_bake(coarse, fine, tx, cage=cage)
        with monkeypatch.context() as mp:
            mp.setattr(baseline.KERNEL, "lib", lambda: None)
            ref = baseline_bake(coarse, fine, tx, cage=cage)
        assert native["fallback"] == ref["fallback"]
        for k in ("normals", "points", "hit", "distance"):
            np.testing.assert_array_equal(native[k], ref[k])
    assert ref["fallback"] > 0  # the small cage left some samples to the closest point
    # some samples by index: what the same samples gathered give, with the kernel (rows read in C) and numpy
    from types import SimpleNamespace

    idx = np.random.default_rng(2).choice(tx.n_samples, 400, replace=False)
    sub = SimpleNamespace(points=np.asarray(tx.points)[idx], normal=np.asarray(tx.normal)[idx])
    for use_kernel in (True, False):
        with monkeypatch.context() as mp:
            if not use_kernel:
                mp.setattr(baseline.KERNEL, "lib", lambda: None)
            at = baseline_bake(coarse, fine, tx, cage=0.015, index=idx)
            gathered = baseline_bake(coarse, fine, sub, cage=0.015)
        assert at["fallback"] == gathered["fallback"] > 0
        for k in ("normals", "points", "hit", "distance"):
            np.testing.assert_array_equal(at[k], gathered[k])

    rng = np.random.default_rng(3)
    m = 1000
    pts, nrm = rng.normal(size=(m, 3)), unit(rng.normal(size=(m, 3)))
    np.testing.assert_array_equal(baseline._rays(lib, pts, nrm), baseline._rays(None, pts, nrm))
    t = rng.uniform(0, 0.2, 2 * m).astype(np.float32)
    t[rng.random(2 * m) < 0.2] = np.inf  # misses
    t[m: m + 50] = t[:50]  # ties: the + ray's hit
    ids = rng.integers(0, fine.n_faces, 2 * m).astype(np.uint32)
    uv = rng.uniform(0, 0.5, (2 * m, 2)).astype(np.float32)
    for a, b in zip(baseline._pick_hits(lib, t, ids, uv, m, 0.1), baseline._pick_hits(None, t, ids, uv, m, 0.1)):
        np.testing.assert_array_equal(a, b)
    best_t, prim, bary = baseline._pick_hits(lib, t, ids, uv, m, 0.1)
    assert np.isinf(best_t).any() and (best_t[np.isfinite(best_t)] <= 0.1).all()
    np.testing.assert_array_equal(prim[:50][np.isfinite(best_t[:50])], ids[:50][np.isfinite(best_t[:50])])
    for a, b in zip(baseline._shade_points(lib, fine, prim, bary, None), baseline._shade_points(None, fine, prim, bary, None)):
        np.testing.assert_array_equal(a, b)


def test_rays_and_closest_points_run_on_the_bakes_threads(coarse_texels):
    """open3d's queries take the thread count the bake runs with (torch's: measured or fixed), not open3d's default
    of every core, so a thread choice made for a busy machine holds for the classical bake too; the result is the
    same whatever the count."""
    import torch

    from neural_bake.bake.baseline import raycasting_scene

    coarse, tx = coarse_texels
    fine = ico(3, 0.7)

    class Recording:  # the real scene, its calls' thread counts written down
        def __init__(self):
            self.scene, self.asked = raycasting_scene(fine), []

        def cast_rays(self, rays, nthreads=0):
            self.asked.append(nthreads)
            return self.scene.cast_rays(rays, nthreads=nthreads)

        def compute_closest_points(self, q, nthreads=0):
            self.asked.append(nthreads)
            return self.scene.compute_closest_points(q, nthreads=nthreads)

    before = torch.get_num_threads()
    try:
        outs = []
        for n in (1, 2):
            torch.set_num_threads(n)
            rec = Recording()
            outs.append(baseline_bake(coarse, fine, tx, cage=1e-3, scene=rec))  # a cage short enough to miss
            closest_surface(fine, np.asarray(tx.points)[:10], scene=rec)
            assert rec.asked and set(rec.asked) == {n}
    finally:
        torch.set_num_threads(before)
    assert outs[0]["fallback"] > 0  # the closest-point fallback ran too
    for k in ("normals", "points", "hit"):
        np.testing.assert_array_equal(outs[0][k], outs[1][k])
