"""`bench fit` in its smallest form: fields of the result, targets not checked in quick runs, saved models."""

from __future__ import annotations

import math

from neural_bake.bench.fit import run
from neural_bake.nets.model_io import load_model


def test_bench_fit_smallest_run_saves_models(tmp_path, monkeypatch, ticker):
    from neural_bake.fit import sdf

    # a simulated clock bounds the polish by its reads, not by its evaluations: keep the polish short
    monkeypatch.setitem(sdf.PRESETS, "64x1", {**sdf.PRESETS["64x1"], "polish_evals": 6, "polish_points": 2048})
    # 1.8 s of a simulated clock: enough steps for the micro-batch tuner, however loaded
    # the machine
    res = run(quick=True, presets=["64x1"], minutes=0.03, step_networks=[(16, 1)], save_dir=tmp_path / "models",
              clock=ticker(0.02))
    step = res["tables"]["training step"]
    assert [r["network"] for r in step] == ["16x1"]
    assert step[0]["ours_s"] > 0 and step[0]["autograd_2x_backward_s"] > 0
    assert step[0]["compiled_s"] is None and step[0]["compile_once_s"] is None  # --quick skips the compile
    assert math.isclose(step[0]["speedup_vs_autograd"], step[0]["autograd_2x_backward_s"] / step[0]["ours_s"])
    (row,) = res["tables"]["accuracy vs time"]
    assert row["mesh"] == "bumpy_sphere" and row["preset"] == "64x1" and row["steps"] >= 1
    assert row["micro_batches"].split()[0].split("x")[0] in ("1", "2")  # the tuner's choices: "2x3 1x1"
    assert 0 < row["chamfer_l1"] <= row["hausdorff"] < 2.0
    assert "target_met" not in row  # a quick run's shortened budgets are not the targets'
    # a bundled sample: ∇f against its analytic surface, beside the mesh's own faces against it
    assert 0 <= row["analytic_median_deg"] < 180 and 0 < row["mesh_faces_analytic_median_deg"] < 5
    model, meta = load_model(tmp_path / "models" / "bumpy_sphere-64x1.nbm")
    assert (model.width, model.depth) == (64, 1) and meta["kind"] == "sdf"


def test_bench_fit_puts_a_polishing_preset_beside_its_run_without_polish(monkeypatch):
    from neural_bake.fit import sdf

    monkeypatch.setitem(sdf.PRESETS, "64x1", {**sdf.PRESETS["64x1"], "polish_evals": 6, "polish_points": 2048})
    res = run(quick=True, presets=["64x1"], minutes=0.05, step_networks=[(16, 1)], compare_polish=True)
    polished, plain = res["tables"]["accuracy vs time"]
    assert (polished["preset"], plain["preset"]) == ("64x1", "64x1 (no polish)")
    assert polished["polish_evals"] >= 2 and polished["polish_s"] > 0
    assert plain["polish_evals"] == 0 and plain["polish_s"] == 0.0 and plain["steps"] > polished["steps"] // 2
    for key in ("chamfer_l1", "hausdorff", "normal_median_deg"):
        # the bench rounds the ratio to 3 decimals
        assert math.isclose(polished[f"{key}_vs_no_polish"], polished[key] / plain[key], abs_tol=5e-4 + 1e-9)
    assert any("no polish" in note for note in res["notes"])
    # quick runs leave the comparison out unless asked
    (row,) = run(quick=True, presets=["64x1"], minutes=0.02, step_networks=[(16, 1)])["tables"]["accuracy vs time"]
    assert row["preset"] == "64x1" and "hausdorff_vs_no_polish" not in row


def test_bench_fit_step_timing_times_every_count_the_tuner_tries():
    from neural_bake.bench.fit import step_timing

    # 9,216 points × width 64: the rule's 2 parts; the tuner tries 1 and 2
    row = step_timing(64, 1, repeat=1, compiled=False)
    assert row["micro_batches"] == 2 and set(row["eager_ms_by_parts"]) == {"1", "2"}
    assert row["ours_micro_batches"] in (1, 2)
    assert math.isclose(row["ours_s"] * 1e3, min(row["eager_ms_by_parts"].values()), abs_tol=0.051)
    assert row["compiled_ms_by_parts"] is None and row["compiled_s"] is None
