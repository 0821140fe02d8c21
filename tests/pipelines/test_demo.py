"""The demo pipeline end to end in a shrunken form (tiny budgets, small maps), read from its JSON."""

import json

import pytest

from neural_bake.cli.main import main
from neural_bake.errors import NeuralBakeError
from neural_bake.pipelines.demo import DemoConfig, run_demo


@pytest.mark.slow
def test_demo_shrunken_end_to_end(tmp_path):
    out = tmp_path / "demo"
    lines = []
    cfg = DemoConfig(sample="sphere", sdf_preset="64x1", sdf_minutes=0.1, texture_minutes=0.05, size=64,
                     coarse="decimate:300", nested_levels="16x0", nested_minutes=0.05, nested_boxes=200,
                     progress=False, report_views=1)
    summary = run_demo(out, cfg, log=lines.append)
    names = set(summary["outputs"])
    assert {"sdf.safetensors", "nested.safetensors", "texture.safetensors", "asset.glb", "normal.png", "albedo.png",
            "report.json", "demo.json"} <= names
    assert {"asset.usd", "asset.usdz"} <= names  # usd-core is in the test extras: the USD beside the GLB
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
    assert any(line.startswith("[5/5] baking the nested sequence") for line in lines)
    # the nested path: the texture's band and the bake's miss band are the sequence's widest δ
    seq = on_disk["nested"]
    assert seq["levels"] == ["16x0", "64x1"] and len(seq["deltas"]) == 2 and seq["deltas"][0] >= seq["deltas"][1]
    assert on_disk["texture"]["delta"] == pytest.approx(seq["deltas"][0])
    assert report["sdf"].endswith("nested.safetensors") and report["sdf_check"]["median_abs_f"] >= 0
    assert on_disk["sdf"]["distance_error"] > 0
    # the demo ends with the paths of its HTML report and of the page comparing it with the classical bake
    assert lines[-2].endswith(str(out / "report" / "index.html")) and (out / "report" / "index.html").is_file()
    assert lines[-1].endswith(str(out / "compare" / "index.html")) and (out / "compare" / "index.html").is_file()
    classical = json.loads((out / "classical" / "report.json").read_text())
    assert classical["method"] == "classical" and classical["truth"] == "analytic (sphere sample)"
    assert classical["bake"]["size"] == report["bake"]["size"]
    cmp = json.loads((out / "compare" / "comparison.json").read_text())
    assert [b["name"] for b in cmp["bakes"]] == ["neural", "classical"]
    assert cmp["bakes"][0]["normal_median_deg"] == report["vs_truth_deg"]["median"]
    # the same coarse mesh, layout and texels: the two maps are compared texel by texel
    assert cmp["pairs"] and cmp["pairs"][0]["normal_map_angle_deg"]["count"] > 1000
    assert {f["fit"] for f in cmp["bakes"][0]["fits"]} >= {"SDF (fine level)", "nested level 0 (16x0)", "texture"}
    assert cmp["bakes"][1]["fits"] == []
    page = (out / "report" / "index.html").read_text()  # built in the staging folder, titled after the output
    assert "<title>neural-bake report: demo</title>" in page and ".stage-" not in page
    view = json.loads((out / "report" / "view.json").read_text())
    assert view["neural"] and {"baked_vs_source", "neural_vs_source", "baked_vs_neural"} <= set(view["metrics"])


def test_demo_unknown_sample_is_one_line_error(tmp_path, capsys):
    with pytest.raises(NeuralBakeError, match="nope"):
        run_demo(tmp_path / "d", DemoConfig(sample="nope"), log=lambda m: None)
    code = main(["demo", "--out", str(tmp_path / "d2"), "--sample", "nope"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("neural-bake: error:") and err.count("\n") == 1
