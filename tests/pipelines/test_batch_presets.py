"""A batch under several presets: each preset's batch in its own folder, one comparison page per asset, linked
from the top index."""

import json

import pytest

from neural_bake.cli.main import main
from neural_bake.errors import NeuralBakeError
from neural_bake.pipelines.batch import BatchConfig, parse_presets, run_preset_batches


@pytest.fixture(scope="module")
def sphere(tmp_path_factory):
    from neural_bake.samples.generate import write_sample
    from neural_bake.samples.shapes import get_sample

    d = tmp_path_factory.mktemp("preset_samples")
    return write_sample(get_sample("sphere").mesh(resolution=400, texture_size=64), d, "sphere")


def test_two_presets_run_apart_and_each_asset_gets_a_comparison(tmp_path, sphere, tiny):
    (tmp_path / "m.txt").write_text(f"{sphere}\n")
    out = tmp_path / "out"
    lines = []
    cfg = BatchConfig(stages=tiny(bake={"size": 32, "baseline": False, "force": True}), workers=1, threads=1,
                      quiet=True)
    result = run_preset_batches(tmp_path / "m.txt", out, cfg, ["quick", "default"], log=lines.append,
                                compare_views=1)
    assert result["failed"] == 0 and set(result["presets"]) == {"quick", "default"}
    for preset in ("quick", "default"):
        summary = json.loads((out / preset / "batch.json").read_text())
        assert summary["config"]["preset"] == preset and summary["assets"]["sphere"]["status"] == "ok"
        assert (out / preset / "sphere" / "bake" / "report.json").is_file()
    page = out / "compare" / "sphere" / "index.html"
    assert result["comparisons"] == {"sphere": str(page)} and page.is_file()
    cmp = json.loads((page.parent / "comparison.json").read_text())
    assert [b["name"] for b in cmp["bakes"]] == ["quick", "default"]
    index = (out / "index.html").read_text()
    assert "href='compare/sphere/index.html'" in index
    assert "sphere · quick" in index and "sphere · default" in index
    rows = json.loads((out / "index.json").read_text())
    assert [r["preset"] for r in rows] == ["quick", "default"] and rows[0]["comparison"] == str(page)


def test_preset_lists_are_checked(tmp_path, sphere, capsys):
    assert parse_presets("quick, high,quick") == ["quick", "high"]
    with pytest.raises(NeuralBakeError, match="'huge': unknown"):
        parse_presets("quick,huge")
    (tmp_path / "m.txt").write_text(f"{sphere}\n")
    assert main(["batch", str(tmp_path / "m.txt"), "-o", str(tmp_path / "o"), "--preset", "quick,huge"]) == 2
    err = capsys.readouterr().err
    assert "'huge'" in err and err.count("\n") == 1 and not (tmp_path / "o").exists()
    assert main(["batch", "--preset", "quick,high", "--print-config"]) == 2
    assert "one --preset" in capsys.readouterr().err
