"""The bundled samples through `neural-bake batch --preset quick`, end to end (the smoke run of the samples)."""

import json

import pytest

from neural_bake.cli.main import main
from neural_bake.samples.generate import sample_path
from neural_bake.samples.shapes import SAMPLES


@pytest.mark.slow
def test_bundled_samples_at_the_quick_preset(tmp_path, capsys):
    manifest = tmp_path / "samples.txt"
    manifest.write_text("".join(f"{sample_path(n)}\n" for n in SAMPLES))
    # the quick preset's networks for fixed step counts (a fraction of what its budgets make: the samples are
    # simple, and the floors below are loose), so the figures do not depend on the machine's load
    code = main(["batch", str(manifest), "-o", str(tmp_path / "out"), "--preset", "quick", "--workers", "2",
                 "--set", "sdf.steps=100", "--set", "sdf.minutes=30", "--set", "sdf.polish_evals=0",
                 "--set", "sdf.compile=off", "--set", "texture.steps=50", "--set", "texture.minutes=30"])
    out = capsys.readouterr().out
    assert code == 0, out
    summary = json.loads((tmp_path / "out" / "batch.json").read_text())
    assert summary["ok"] == len(SAMPLES) and summary["failed"] == 0
    for name in SAMPLES:
        rec = summary["assets"][name]
        assert {s["status"] for s in rec["stages"].values()} == {"done"}
        bake = rec["metrics"]["bake"]
        # quality floors of a one-minute asset, normals against the analytic surfaces (not the mesh's facets)
        assert bake["normal_deg_vs_truth"]["median"] < 8.0, (name, bake)
        assert bake["normal_deg_vs_gradient"]["median"] < 1.0
        assert bake["color_psnr_db"] > 12.0, (name, bake)
        assert rec["metrics"]["nested"]["deltas"][0] > 0
        assert (tmp_path / "out" / name / "bake" / "asset.glb").is_file()
    assert f"batch: {len(SAMPLES)} ok, 0 failed" in out
