"""`bench fit` in its smallest form: fields of the result, targets not checked in quick runs, saved models."""

from __future__ import annotations

import math

from neural_bake.bench.fit import run
from neural_bake.nets.model_io import load_model


def test_bench_fit_smallest_run_saves_models(tmp_path):
    res = run(quick=True, presets=["64x1"], minutes=0.03, step_networks=[(16, 1)], save_dir=tmp_path / "models")
    step = res["tables"]["training step"]
    assert [r["network"] for r in step] == ["16x1"]
    assert step[0]["ours_s"] > 0 and step[0]["autograd_2x_backward_s"] > 0
    assert step[0]["compiled_s"] is None and step[0]["compile_once_s"] is None  # --quick skips the compile
    assert math.isclose(step[0]["speedup_vs_autograd"], step[0]["autograd_2x_backward_s"] / step[0]["ours_s"])
    (row,) = res["tables"]["accuracy vs time"]
    assert row["mesh"] == "bumpy_sphere" and row["preset"] == "64x1" and row["steps"] >= 1
    assert 0 < row["chamfer_l1"] <= row["hausdorff"] < 2.0
    assert "target_met" not in row  # a quick run's shortened budgets are not the targets'
    # a bundled sample: ∇f against its analytic surface, beside the mesh's own faces against it
    assert 0 <= row["analytic_median_deg"] < 180 and 0 < row["mesh_faces_analytic_median_deg"] < 5
    model, meta = load_model(tmp_path / "models" / "bumpy_sphere-64x1.nbm")
    assert (model.width, model.depth) == (64, 1) and meta["kind"] == "sdf"
