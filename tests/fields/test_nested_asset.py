"""Item 2: the nested sequence is an asset end to end (fit nested → fit texture → bake, level:I:RES), and
fit sdf records its sampled distance error as the file's δ."""

import json

import pytest
import torch

from neural_bake.cli.main import main
from neural_bake.constants import TEXTURE_SURFACE_SAMPLES
from neural_bake.fields import NestedSequence, SdfField, TextureField, load_field
from neural_bake.fit.sampling import sample_surface
from neural_bake.fit.sdf import DISTANCE_ERROR_SOURCE, SdfFit, fit_sdf, load_sdf, sampled_distance_error
from neural_bake.io.mesh_io import load_mesh
from neural_bake.samples.generate import sample_path


@pytest.fixture(scope="module")
def sphere():
    return load_mesh(sample_path("sphere"))


@pytest.fixture(scope="module")
def files(tmp_path_factory, fit_sphere_siren, sphere):
    d = tmp_path_factory.mktemp("nested_asset")
    fine = fit_sphere_siren(r=0.9, steps=400)
    SdfFit(model=fine, frame=sphere.frame, distance_error=sampled_distance_error(fine, sphere)).save(d / "f.sdf")
    assert main(["fit", "nested", str(d / "f.sdf"), "-o", str(d / "f.nested"), "--levels", "16x0", "--steps", "150",
                 "--max-boxes", "400", "--no-progress"]) == 0
    return d


def test_fit_sdf_records_its_sampled_distance_error(sphere, tmp_path):
    fit = fit_sdf(sphere, width=16, depth=0, steps=20, batch=256, batch_near=256, batch_uniform=64, pool_surface=2000,
                  pool_near=2000, pool_uniform=500, progress=False, compile="off", gemm_dtype="float32")
    pts = torch.as_tensor(sample_surface(sphere, 20_000, seed=0).points, dtype=torch.float32)
    with torch.no_grad():
        assert fit.distance_error == pytest.approx(float(fit.model(pts)[:, 0].abs().max()), rel=1e-6)
    fit.save(tmp_path / "s.sdf")
    field = load_field(tmp_path / "s.sdf")
    assert field.delta == pytest.approx(fit.distance_error) and field.metadata["delta_source"] == DISTANCE_ERROR_SOURCE
    assert load_sdf(tmp_path / "s.sdf").distance_error == pytest.approx(fit.distance_error)


def test_fit_texture_takes_a_nested_file(files, sphere, capsys):
    seq = load_field(files / "f.nested")
    assert isinstance(seq, NestedSequence) and len(seq.levels) == 2
    out = files / "t.tex"
    assert main(["fit", "texture", str(sample_path("sphere")), "--sdf", str(files / "f.nested"), "-o", str(out),
                 "--steps", "20", "--width", "16", "--depth", "0", "--no-progress", "--no-metrics"]) == 0
    tex = load_field(out)
    assert isinstance(tex, TextureField)
    # the band is the sequence's widest one (level 0's δ), normals from its fine level
    assert tex.delta == pytest.approx(seq.deltas[0]) and f"δ = {seq.deltas[0]:g}" in capsys.readouterr().out
    against = dict(tex.fitted_against)
    assert len(against.pop("surface")) == TEXTURE_SURFACE_SAMPLES  # the sphere's points the texture was fitted on
    assert against == {"name": "f.nested (f, band of level 0)", "kind": "nested", "delta": pytest.approx(seq.deltas[0])}
    # a fit sdf file gives its sampled distance error as the band
    assert main(["fit", "texture", str(sample_path("sphere")), "--sdf", str(files / "f.sdf"), "-o",
                 str(files / "t2.tex"), "--steps", "2", "--width", "16", "--depth", "0", "--no-progress",
                 "--no-metrics"]) == 0
    assert load_field(files / "t2.tex").delta == pytest.approx(load_field(files / "f.sdf").delta)


@pytest.mark.parametrize("coarse", ["level:0:32", "level:1:24", "decimate:300"])
def test_bake_takes_a_nested_file(files, coarse, capsys):
    seq = load_field(files / "f.nested")
    out = files / f"bake-{coarse.replace(':', '-')}"
    code = main(["bake", str(sample_path("sphere")), "--sdf", str(files / "f.nested"), "--coarse", coarse,
                 "--size", "48", "--no-baseline", "--maps", "normal,vertex", "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    assert report["sdf_check"]["passed"]
    level = int(coarse.split(":")[1]) if coarse.startswith("level") else 0
    if coarse.startswith("level"):
        assert report["coarse"]["level"] == {"index": level, "delta": pytest.approx(seq.deltas[level])}
        assert report["coarse"]["faces"] > 100
    # normals from f: the vertex normals of a sphere are its unit positions
    assert report["vs_truth_deg"]["median"] < 5.0


def test_level_spec_errors(files, capsys):
    base = ["bake", str(sample_path("sphere")), "--size", "16", "--no-baseline", "-o", str(files / "bad")]
    assert main(base + ["--sdf", str(files / "f.nested"), "--coarse", "level:5:32"]) == 2
    assert "f.nested: no level 5 (the sequence has levels 0..1)" in capsys.readouterr().err
    assert main(base + ["--sdf", str(files / "f.sdf"), "--coarse", "level:0:32"]) == 2
    assert "level needs a nested-sequence SDF file" in capsys.readouterr().err
    assert main(base + ["--sdf", str(files / "f.nested"), "--coarse", "level:x"]) == 2
    assert "level needs LEVEL:RESOLUTION" in capsys.readouterr().err
    assert not (files / "bad").exists()


def test_python_path(files, sphere):
    """The README's Python lines: load the sequence, bake onto its level-0 zero set."""
    import neural_bake as nb

    seq = nb.load_field(files / "f.nested")
    coarse, info = nb.coarse_mesh(sphere, "level:0:24", seq)
    res = nb.bake_vertices(coarse, nb.to_sdf_field(seq))
    assert info["level"]["index"] == 0 and res["invalid"] == 0
    pts = torch.as_tensor(coarse.vertices)
    cos = (torch.as_tensor(res["normals"]) * torch.nn.functional.normalize(pts, dim=1)).sum(1)
    assert float(cos.median()) > 0.99
    assert isinstance(seq.finest, SdfField)
