"""The demo pipeline end to end in a shrunken form (tiny budgets, small maps), read from its JSON."""

import json

import pytest

from neural_bake.cli.main import main
from neural_bake.errors import NeuralBakeError
from neural_bake.pipelines.demo import DemoConfig, run_demo


def test_demo_shrunken_end_to_end(tmp_path):
    out = tmp_path / "demo"
    lines = []
    cfg = DemoConfig(sample="sphere", sdf_preset="64x1", sdf_minutes=0.1, texture_minutes=0.05, size=64,
                     coarse="decimate:300", progress=False, report_views=1)
    summary = run_demo(out, cfg, log=lines.append)
    names = set(summary["outputs"])
    assert {"sdf.safetensors", "texture.safetensors", "asset.glb", "normal.png", "albedo.png", "report.json",
            "demo.json"} <= names
    on_disk = json.loads((out / "demo.json").read_text())
    assert on_disk["config"]["sample"] == "sphere"
    # whatever the (short) training reached, the baked map holds the network's own gradient
    assert on_disk["bake"]["vs_gradient_deg"]["median"] < 1.0
    assert on_disk["sdf"]["steps"] > 0 and on_disk["texture"]["steps"] > 0
    # the sample's analytic normals: the sphere mesh's own faces are off them by its faceting, a few degrees
    assert 0 < on_disk["sdf"]["mesh_normal_truth_median_deg"] < 5
    assert 0 <= on_disk["sdf"]["normal_truth_median_deg"] < 180
    assert any("against the analytic surface" in line for line in lines)
    report = json.loads((out / "report.json").read_text())
    assert report["truth"] == "analytic (sphere sample)"
    assert report["bake"]["delta"] > 0  # the texture model's band
    assert any(line.startswith("[4/4]") for line in lines)
    # the demo ends with the path of its HTML report
    assert lines[-1].endswith(str(out / "report" / "index.html")) and (out / "report" / "index.html").is_file()


def test_demo_unknown_sample_is_one_line_error(tmp_path, capsys):
    with pytest.raises(NeuralBakeError, match="nope"):
        run_demo(tmp_path / "d", DemoConfig(sample="nope"), log=lambda m: None)
    code = main(["demo", "--out", str(tmp_path / "d2"), "--sample", "nope"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("neural-bake: error:") and err.count("\n") == 1
