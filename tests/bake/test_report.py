"""Quality report: errors vs truth, ∇f and baseline; PSNR; seams; error maps; errors."""

import json

import numpy as np
import pytest
import torch
import trimesh

from neural_bake.bake.baker import Baker
from neural_bake.bake.baseline import baseline_bake
from neural_bake.bake.fields import ColorField, SdfField
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


def fine_sphere():
    t = trimesh.creation.icosphere(subdivisions=4, radius=R)
    return Mesh(vertices=np.asarray(t.vertices) + C, faces=np.asarray(t.faces, dtype=np.int64))


@pytest.fixture(scope="module")
def baked():
    ico = trimesh.creation.icosphere(subdivisions=1, radius=R)
    m = unwrap(Mesh(vertices=np.asarray(ico.vertices), faces=np.asarray(ico.faces, dtype=np.int64)), resolution=64)
    m.vertex_normals = None  # the Baker recomputes them welded across seams
    baker = Baker(m, 64)
    colour = ColorField(lambda p: (p / R + 1) / 2)
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
        res, baker, truth=truth, truth_colors=lambda p: (p / R + 1) / 2, baseline=base, out_dir=tmp_path,
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
    r2 = streamed.bake(SdfField(lambda p: p.norm(dim=1) - R))
    with pytest.raises(NeuralBakeError, match="bake_report: needs the per-sample values"):
        bake_report(r2, streamed)
