"""Quality report: errors vs truth, ∇f and baseline; PSNR; seams; error maps; errors."""

import json

import numpy as np
import pytest
import torch
import trimesh

from neural_bake.bake.baker import Baker
from neural_bake.bake.baseline import baseline_bake
from neural_bake.fields import ColorField, SdfField
from neural_bake.bake.report import angular_error, bake_report, error_stats, psnr, seam_discontinuity
from neural_bake.errors import NeuralBakeError
from neural_bake.io.images import read_image
from neural_bake.mesh.unwrap import unwrap
from neural_bake.types import Mesh

R = 0.7
C = np.array([0.05, 0.03, 0.0])  # the field's sphere is off-centre: the map is not flat


def unit(p):
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def truth(p):
    return unit(p - C)


def colour_field():
    """Colours constant along the field's normal lines (its direction from C): what the bake reads at a texel's
    closest point of the zero set is the colour at the texel itself, the truth below."""
    c = torch.as_tensor(C)
    return ColorField(lambda p: ((p - c) / (p - c).norm(dim=1, keepdim=True) + 1) / 2)


def truth_colors(p):
    return (unit(p - C) + 1) / 2


def fine_sphere():
    t = trimesh.creation.icosphere(subdivisions=4, radius=R)
    return Mesh(vertices=np.asarray(t.vertices) + C, faces=np.asarray(t.faces, dtype=np.int64))


@pytest.fixture(scope="module")
def baked():
    ico = trimesh.creation.icosphere(subdivisions=1, radius=R)
    m = unwrap(Mesh(vertices=np.asarray(ico.vertices), faces=np.asarray(ico.faces, dtype=np.int64)), resolution=64)
    m.vertex_normals = None  # the Baker recomputes them welded across seams
    baker = Baker(m, 64)
    colour = colour_field()
    c = torch.as_tensor(C)
    res = baker.bake(SdfField(lambda p: (p - c).norm(dim=1) - R), colour)
    return baker, res


def test_small_helpers():
    a = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    assert np.allclose(angular_error(a, np.array([[1.0, 0, 0], [1.0, 0, 0]])), [0.0, 90.0])
    assert error_stats([]) == {"median": None, "mean": None, "p95": None, "max": None, "count": 0}
    assert error_stats([1.0, 3.0])["median"] == 2.0
    assert psnr(np.zeros(4), np.zeros(4)) == float("inf")
    assert psnr(np.zeros(4), np.full(4, 0.1)) == pytest.approx(20.0)


def test_report_on_sphere(tmp_path, baked):
    baker, res = baked
    fine = fine_sphere()
    base = baseline_bake(baker.mesh, fine, baker.texels, cage=0.2)
    rep = bake_report(
        res, baker, truth=truth, truth_colors=truth_colors, baseline=base, out_dir=tmp_path,
        timings={"load": 0.5},
    )
    json.dumps(rep)  # JSON-ready
    # 8-bit quantisation of the map is the only error left: well under a degree
    assert rep["vs_truth_deg"]["max"] < 1.0 and rep["vs_gradient_deg"]["max"] < 1.0
    assert rep["gradient_vs_truth_deg"]["max"] < 1e-4
    assert rep["geometric_vs_truth_deg"]["median"] > 2.0
    assert rep["baseline"]["vs_truth_deg"]["median"] < 1.0 and rep["baseline"]["fallback"] == 0
    assert rep["color_psnr_db"] > 40.0  # 8-bit quantisation only
    assert rep["coverage"] == pytest.approx(res.coverage.mean()) and rep["miss_texels"] == 0
    assert rep["seconds"]["load"] == 0.5 and "sdf" in rep["seconds"]
    assert rep["seams"]["edges"] > 0 and rep["seams"]["normal_deg"]["median"] < 1.0
    assert rep["seams"]["color"]["median"] < 0.02
    assert rep["files"] == ["error_normal.png", "error_baseline.png", "miss.png"]
    err = read_image(tmp_path / "error_normal.png", colour="data")
    assert err.shape[:2] == (64, 64) and err.max() < 0.1  # < 1° of the 10° scale
    # float maps (no quantisation) are exact
    rep = bake_report(res, baker, truth=truth, bits=None)
    assert rep["vs_truth_deg"]["max"] < 1e-3 and "baseline" not in rep and "files" not in rep


def test_report_against_fine_mesh(baked):
    baker, res = baked
    rep = bake_report(res, baker, fine=fine_sphere())
    assert rep["truth"] == "fine mesh, closest point"
    assert rep["vs_truth_deg"]["median"] < 1.0 and "color_psnr_db" not in rep


def test_seam_discontinuity_detects_a_broken_map(baked):
    baker, res = baked
    ok = seam_discontinuity(baker.mesh, baker.tangents, res.normal_map)
    assert ok["edges"] > 0 and ok["normal_deg"]["max"] < 2.0
    flat = np.full_like(res.normal_map, 0.5)
    flat[..., 2] = 1.0  # the interpolated vertex normal everywhere: the same on both sides of a seam
    same = seam_discontinuity(baker.mesh, baker.tangents, flat)
    assert same["normal_deg"]["max"] < 1e-6
    noisy = np.random.default_rng(0).uniform(0, 1, size=res.normal_map.shape).astype(np.float32)
    bad = seam_discontinuity(baker.mesh, baker.tangents, noisy)
    assert bad["normal_deg"]["median"] > 10.0


def test_report_needs_samples(baked):
    baker, res = baked
    streamed = Baker(baker.mesh, 32, cache_texels=False)
    r2 = streamed.bake(SdfField(lambda p: p.norm(dim=1) - R), report_samples=0)
    assert r2.sample is None and r2.normals is None
    with pytest.raises(NeuralBakeError, match="bake_report: needs the per-sample values"):
        bake_report(r2, streamed)


def test_report_takes_one_baseline(baked):
    baker, res = baked
    base = baseline_bake(baker.mesh, fine_sphere(), baker.texels, cage=0.2)
    with pytest.raises(NeuralBakeError, match="baseline or baseline_fn, not both"):
        bake_report(res, baker, truth=truth, baseline=base, baseline_fn=lambda tx: base)


# -- streamed bakes: the report on a seeded uniform subsample, maps over every texel -------------------------

DELTA = 0.02  # the coarse icosphere strays further than this from the off-centre sphere: some misses


def _bake_pair(report_samples, band_samples=300):
    """The same bake cached and streamed in many bands (off-centre sphere field, colours, a miss band)."""
    ico = trimesh.creation.icosphere(subdivisions=1, radius=R)
    m = unwrap(Mesh(vertices=np.asarray(ico.vertices), faces=np.asarray(ico.faces, dtype=np.int64)), resolution=64)
    m.vertex_normals = None
    c = torch.as_tensor(C)
    f = SdfField(lambda p: (p - c).norm(dim=1) - R)
    colour = colour_field()
    cached_baker = Baker(m, 64)
    streamed_baker = Baker(m, 64, cache_texels=False, band_samples=band_samples)
    cached = cached_baker.bake(f, colour, delta=DELTA)
    streamed = streamed_baker.bake(f, colour, delta=DELTA, report_samples=report_samples, seed=1)
    return cached_baker, cached, streamed_baker, streamed


def _reports(tmp_path, report_samples):
    cb, cres, sb, sres = _bake_pair(report_samples)
    fine = fine_sphere()
    kw = dict(truth=truth, truth_colors=truth_colors)
    cached = bake_report(cres, cb, baseline_fn=lambda tx: baseline_bake(cb.mesh, fine, tx, cage=0.2),
                         out_dir=tmp_path / "c", **kw)
    streamed = bake_report(sres, sb, baseline_fn=lambda tx: baseline_bake(sb.mesh, fine, tx, cage=0.2),
                           out_dir=tmp_path / "s", **kw)
    return cb, cres, sres, cached, streamed


EXACT = ("coverage", "texels_covered", "miss_texels", "miss_fraction", "invalid_gradients", "seams")


@pytest.fixture
def dirs(tmp_path):
    (tmp_path / "c").mkdir()
    (tmp_path / "s").mkdir()
    return tmp_path


def _same_images(tmp_path, names):
    for name in names:
        a = read_image(tmp_path / "c" / name, colour="data")
        b = read_image(tmp_path / "s" / name, colour="data")
        assert np.array_equal(a, b), name


def test_streamed_report_keeping_every_sample_equals_the_cached_report(dirs):
    _, cres, sres, cached, streamed = _reports(dirs, report_samples=1 << 20)
    m = len(cres.normals)
    assert sres.sample.n_samples == sres.sample.total == m  # the limit exceeds M: every sample, in order
    assert cached["sampling"] == {"samples": m, "of": m, "seed": None, "lattice_step": None, "sampled": [],
                                  "note": f"all {m} texel samples"}
    assert streamed["sampling"]["samples"] == streamed["sampling"]["of"] == m and streamed["sampling"]["sampled"] == []
    assert cached["miss_texels"] > 0
    for key in (*EXACT, "vs_gradient_deg", "vs_truth_deg", "gradient_vs_truth_deg", "geometric_vs_truth_deg",
                "color_psnr_db"):
        assert streamed[key] == cached[key], key
    assert streamed["baseline"]["vs_truth_deg"] == cached["baseline"]["vs_truth_deg"]
    assert streamed["baseline"]["all_texels"]["samples"] == m and "all_texels" not in cached["baseline"]
    assert streamed["files"] == cached["files"] == ["error_normal.png", "error_baseline.png", "miss.png"]
    _same_images(dirs, cached["files"])


def test_streamed_report_on_a_subsample(dirs):
    cb, cres, sres, cached, streamed = _reports(dirs, report_samples=600)
    m = len(cres.normals)
    smp = sres.sample
    assert smp.n_samples == 600 and smp.total == m and m > 1500
    # the subsample is the cached bake's samples at those positions, values included
    assert np.array_equal(np.sort(smp.index), smp.index)
    for name in ("pixel", "points", "normal", "tangent", "weight", "face"):
        assert np.array_equal(getattr(smp.texels, name), getattr(cb.texels, name)[smp.index]), name
    assert np.allclose(smp.normals, cres.normals[smp.index]) and np.array_equal(smp.valid, cres.valid[smp.index])
    assert np.allclose(smp.colors, cres.colors[smp.index])
    s = streamed["sampling"]
    assert (s["samples"], s["of"], s["seed"]) == (600, m, 1)
    assert {"vs_truth_deg", "vs_gradient_deg", "geometric_vs_truth_deg", "color_psnr_db",
            "baseline.vs_truth_deg"} <= set(s["sampled"])
    assert s["note"].startswith(f"sampled 600 of {m} texel samples")
    # exact over every texel: coverage, misses, seams (from the final maps) and the error-map PNGs
    for key in EXACT:
        assert streamed[key] == cached[key], key
    assert cached["miss_texels"] > 0
    _same_images(dirs, cached["files"])
    assert streamed["files"] == cached["files"]
    assert streamed["baseline"]["all_texels"]["samples"] == m and streamed["baseline"]["samples"] == 600
    # sampled: the exact median lies in the sample's 95 % interval; means and PSNR agree within sampling error
    for key in ("vs_truth_deg", "geometric_vs_truth_deg", "gradient_vs_truth_deg"):
        lo, hi = streamed[key]["median_ci95"]
        assert lo <= cached[key]["median"] <= hi, key
        assert streamed[key]["count"] == 600 and "median_ci95" not in cached[key]
    lo, hi = streamed["baseline"]["vs_truth_deg"]["median_ci95"]
    assert lo <= cached["baseline"]["vs_truth_deg"]["median"] <= hi
    geo_c, geo_s = cached["geometric_vs_truth_deg"], streamed["geometric_vs_truth_deg"]
    assert abs(geo_s["mean"] - geo_c["mean"]) < 0.1 * geo_c["mean"]
    assert abs(streamed["color_psnr_db"] - cached["color_psnr_db"]) < 1.0


def test_subsample_is_uniform_and_seeded():
    _, cres, sb, sres = _bake_pair(report_samples=500)
    m = sres.sample.total
    # the sampled positions spread over the whole texel order: each quarter holds about a quarter
    counts = np.bincount(sres.sample.index * 4 // m, minlength=4)
    assert np.all(np.abs(counts - 125) < 4 * np.sqrt(125 * 0.75))
    other = sb.bake(SdfField(lambda p: p.norm(dim=1) - R), report_samples=500, seed=2).sample
    assert not np.array_equal(other.index, sres.sample.index)
    again = sb.bake(SdfField(lambda p: p.norm(dim=1) - R), report_samples=500, seed=1).sample
    assert np.array_equal(again.index, sres.sample.index)


def test_large_map_is_compared_on_a_lattice_of_its_texels(tmp_path, baked, monkeypatch):
    """A map wider than the report's lattice side is compared on every k-th texel of each row and column:
    the lattice error maps are the full ones at those texels, the figures those of the lattice's samples
    (with a confidence interval), and the baseline runs on the lattice only."""
    from neural_bake.bake import report as report_mod

    baker, res = baked
    fine = fine_sphere()
    calls = []

    def base_fn(texels):
        calls.append(texels.n_samples)
        return baseline_bake(baker.mesh, fine, texels, cage=0.2)

    (tmp_path / "all").mkdir()
    (tmp_path / "lat").mkdir()
    every = bake_report(res, baker, truth=truth, baseline_fn=base_fn, out_dir=tmp_path / "all")
    monkeypatch.setattr(report_mod, "REPORT_LATTICE_SIDE", 32)
    assert report_mod.lattice_step((64, 64)) == 2 and report_mod.lattice_step((32, 32)) == 1
    lat = bake_report(res, baker, truth=truth, baseline_fn=base_fn, out_dir=tmp_path / "lat")
    pix = np.asarray(baker.texels.pixel)
    on = ((pix % 2) == report_mod.lattice_offsets(pix, 2)).all(axis=1)
    assert 0 < on.sum() < len(pix) and len(np.unique(pix[on] // 2, axis=0)) == on.sum()  # one texel a block
    # not the even rows and columns alone (where an adaptive bake's nodes lie): every offset of a block is taken
    assert len(np.unique(pix[on] % 2, axis=0)) == 4
    assert calls == [baker.texels.n_samples, int(on.sum())]  # the baseline ray-casts the lattice only
    s = lat["sampling"]
    assert s["lattice_step"] == 2 and s["samples"] == on.sum() and s["of"] == baker.texels.n_samples
    assert "vs_truth_deg" in s["sampled"] and "median_ci95" in lat["vs_truth_deg"]
    assert every["sampling"]["lattice_step"] is None and not every["sampling"]["sampled"]
    for name in ("error_normal.png", "error_baseline.png"):
        full = read_image(tmp_path / "all" / name, colour="data")
        small = read_image(tmp_path / "lat" / name, colour="data")
        assert small.shape[:2] == (32, 32)
        blocks, at = pix[on] // 2, pix[on]  # each block's pixel is its lattice texel's
        np.testing.assert_array_equal(small[blocks[:, 0], blocks[:, 1]], full[at[:, 0], at[:, 1]])
    # the lattice's figures are those of the full comparison at its samples
    dec = report_mod.decode_map(res.normal_map, baker.texels, baker.normal_space, baker.y_convention, 8)
    err = angular_error(dec, truth(baker.texels.points))
    assert lat["vs_truth_deg"]["max"] == pytest.approx(err[on].max()) and lat["vs_truth_deg"]["count"] == on.sum()
    # masks and counts still cover every texel
    assert read_image(tmp_path / "lat" / "miss.png", colour="data").shape[:2] == (64, 64)
    assert lat["texels_covered"] == every["texels_covered"]


def test_texels_on_faces_buried_in_another_shell_are_left_out(tmp_path):
    # two overlapping boxes baked onto themselves: the faces of each inside the other are never seen
    def box(lo, hi, k):
        t = trimesh.creation.box(extents=np.subtract(hi, lo))
        t.apply_translation(np.add(lo, hi) / 2)
        for _ in range(k):
            t = t.subdivide()
        return np.asarray(t.vertices), np.asarray(t.faces, dtype=np.int64)

    (va, fa), (vb, fb) = box((-0.75, -0.5, -0.5), (0.25, 0.5, 0.5), 4), box((-0.25, -0.25, -0.25), (0.75, 0.25, 0.25), 4)
    fine = Mesh(np.concatenate([va, vb]), np.concatenate([fa, fb + len(va)]))
    from neural_bake.mesh.shells import buried_faces

    m = unwrap(fine, resolution=128)
    baker = Baker(m, 128)
    lo_a, hi_a = torch.tensor([-0.75, -0.5, -0.5]), torch.tensor([0.25, 0.5, 0.5])
    lo_b, hi_b = torch.tensor([-0.25, -0.25, -0.25]), torch.tensor([0.75, 0.25, 0.25])

    def box_sdf(p, lo, hi):
        q = (p - (lo + hi) / 2).abs() - (hi - lo) / 2
        return q.clamp(min=0).norm(dim=1) + q.max(dim=1).values.clamp(max=0)

    res = baker.bake(SdfField(lambda p: torch.minimum(box_sdf(p, lo_a.to(p), hi_a.to(p)),
                                                      box_sdf(p, lo_b.to(p), hi_b.to(p)))))
    on_buried = buried_faces(m)[baker.texels.face]
    assert 0 < on_buried.sum() < len(on_buried)
    rep = bake_report(res, baker, fine=fine, out_dir=tmp_path)
    assert rep["hidden_texels"] == pytest.approx(int(on_buried.sum()), rel=0.02)
    assert rep["vs_truth_deg"]["count"] == len(on_buried) - rep["hidden_texels"]
    # what is seen is the union's surface, whose face normals the field gives (the truth's interpolated vertex
    # normals bend only on the faces along the boxes' edges, fewer than half)
    assert rep["gradient_vs_truth_deg"]["median"] < 1e-3 and rep["vs_truth_deg"]["median"] < 1.0
    # a single box: nothing is hidden
    one = Mesh(va, fa)  # A alone
    baker1 = Baker(unwrap(one, resolution=64), 64)
    res1 = baker1.bake(SdfField(lambda p: box_sdf(p, lo_a.to(p), hi_a.to(p))))
    assert "hidden_texels" not in bake_report(res1, baker1, fine=one)


def test_faces_figure_is_the_source_geometry_against_its_own_shading():
    # a box baked onto itself with its exact SDF (∇f: each face's normal): flat-shaded (split corners, as a
    # file's hard edges) its faces read 0 against its normals; welded, its averaged normals bend on the faces
    # along the edges, up to the worst corner's angle to its face
    from neural_bake.geometry import vertex_normals

    t = trimesh.creation.box(extents=(1.0, 0.8, 0.6)).subdivide().subdivide().subdivide()
    half = torch.tensor([0.5, 0.4, 0.3])

    def box_sdf(p):
        q = p.abs() - half.to(p)
        return q.clamp(min=0).norm(dim=1) + q.max(dim=1).values.clamp(max=0)

    welded = Mesh(np.asarray(t.vertices), np.asarray(t.faces, dtype=np.int64))
    corners = np.asarray(t.vertices)[np.asarray(t.faces)].reshape(-1, 3)
    split = Mesh(corners, np.arange(len(corners), dtype=np.int64).reshape(-1, 3))
    split.vertex_normals = np.repeat(np.asarray(t.face_normals), 3, axis=0)
    reps = {}
    for name, fine in (("welded", welded), ("split", split)):
        baker = Baker(unwrap(fine, resolution=96), 96)
        reps[name] = bake_report(baker.bake(SdfField(box_sdf)), baker, fine=fine)
    assert reps["split"]["faces_vs_truth_deg"]["max"] < 1e-3
    faces = reps["welded"]["faces_vs_truth_deg"]
    worst = angular_error(vertex_normals(welded)[welded.faces].reshape(-1, 3),
                          np.repeat(np.asarray(t.face_normals), 3, axis=0)).max()
    assert faces["count"] == reps["welded"]["gradient_vs_truth_deg"]["count"] > 0
    assert faces["median"] < 1e-3 and faces["p95"] > 30.0 and 0.9 * worst < faces["max"] <= worst + 1e-6
    assert reps["welded"]["gradient_vs_truth_deg"]["median"] < 1e-3  # the exact SDF's ∇f reads the faces
    ico = trimesh.creation.icosphere(subdivisions=1, radius=R)
    baker = Baker(unwrap(Mesh(np.asarray(ico.vertices), np.asarray(ico.faces, dtype=np.int64)), resolution=32), 32)
    c = torch.as_tensor(C)
    sphere = baker.bake(SdfField(lambda p: (p - c).norm(dim=1) - R))
    assert "faces_vs_truth_deg" not in bake_report(sphere, baker, truth=truth)  # analytic truth: no faces
