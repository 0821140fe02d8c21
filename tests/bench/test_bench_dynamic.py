"""`bench dynamic` in its smallest form: every figure the issue asks for is in its JSON (per-frame render and
bake cost, Hausdorff at t = 0, t = 1 and at every frame of an animated sample, nesting at every sampled t,
storage KB against MB), the morph methods at equal steps with their ratios, and one-line errors."""

from __future__ import annotations

import json
import math

import pytest

from neural_bake.bench.dynamic import EIKONAL_TIMES
from neural_bake.cli.main import main
from neural_bake.samples import ANIMATED


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "dynamic.json"
    code = main(["bench", "dynamic", "--quick", "--steps", "60", "--frames", "2", "--size", "16", "--json", str(out)])
    assert code == 0
    return json.loads(out.read_text())


def test_morph_methods_at_equal_steps_with_ratios(result):
    rows = result["tables"]["morph sphere -> torus (equal steps)"]
    lse, itp, ratio = rows
    assert [lse["method"], itp["method"], ratio["method"]] == ["lse", "interpolate", "interpolate / lse"]
    for r in (lse, itp):
        assert r["steps"] == 60 and r["network"] == "32x1" and r["seconds"] > 0 and r["ms_per_step"] > 0
        assert 0 < r["hausdorff_t0"] < 1 and 0 < r["hausdorff_t1"] < 1
        assert 0 < r["chamfer_t0"] <= r["hausdorff_t0"] and 0 < r["chamfer_t1"] <= r["hausdorff_t1"]
    assert ratio["steps"] == 1.0
    for k in ("ms_per_step", "hausdorff_t0", "hausdorff_t1"):
        assert math.isclose(ratio[k], itp[k] / lse[k], rel_tol=5e-3, abs_tol=1e-3), k
    eik = result["tables"]["morph eikonal residual against t"]
    assert [r["t"] for r in eik] == list(EIKONAL_TIMES)
    for r in eik:
        assert 0 <= r["lse"] < 1 and 0 <= r["interpolate"] < 1
        assert math.isclose(r["interpolate / lse"], r["interpolate"] / r["lse"], rel_tol=5e-3, abs_tol=1e-3)


def test_sequence_is_measured_at_every_frame_of_the_animation(result):
    rows = result["tables"]["sequence splitting_sphere"]
    times = list(ANIMATED["splitting_sphere"].times)
    assert [r["t"] for r in rows if r["frame"]] == times
    assert len([r for r in rows if not r["frame"]]) == len(times) - 1  # half-way between frames
    assert all(r["hausdorff"] is None or (0 < r["chamfer_l1"] <= r["hausdorff"] < 2) for r in rows)
    assert all(r["hausdorff"] is not None for r in rows if r["frame"])
    # the baseline (eikonal term alone between frames) is measured at the same times
    assert all(r["hausdorff_eikonal"] is None or 0 < r["chamfer_l1_eikonal"] <= r["hausdorff_eikonal"] < 2
               for r in rows)


def test_nesting_holds_at_every_sampled_t(result):
    (nest,) = result["tables"]["nesting over space-time"]
    assert nest["level"] == "16x1" and nest["delta"] >= nest["sup_estimated"] > 0
    assert nest["sup_certified"] >= nest["sup_estimated"] and nest["certify_boxes"] > 0 and nest["certify_s"] > 0
    # the stored δ is the certified bound: the nesting is guaranteed, so every sampled t must hold
    assert nest["delta_source"] == "certified" and nest["guaranteed"] is True and nest["holds_at_all_t"] is True
    assert nest["delta"] >= nest["delta_estimated"] and nest["certified_over_estimated"] >= 1
    by_t = result["tables"]["nesting at each sampled t"]
    assert len(by_t) == nest["times_checked"] == 11 and [r["t"] for r in by_t][::10] == [0.0, 1.0]
    assert nest["holds_at_all_t"] == all(r["holds"] for r in by_t)
    assert all(r["holds"] == (r["sup"] <= r["allowed"]) for r in by_t)
    assert math.isclose(nest["worst_t_sup_over_allowed"], max(r["sup"] / r["allowed"] for r in by_t), rel_tol=1e-2)


def test_render_and_bake_cost_and_storage(result):
    (cost,) = result["tables"]["render and bake cost, storage"]
    assert cost["frames"] == 2 and cost["size"] == "16x16" and cost["rendered"] is True
    assert cost["render_total_s"] > 0 and math.isclose(cost["render_per_frame_s"], cost["render_total_s"] / 2,
                                                       rel_tol=0.05, abs_tol=1e-3)
    assert cost["target_render_s"] == 300 and cost["target_met"] in (True, False)
    assert cost["bake_frames"] == 3 and cost["bake_per_frame_s"] > 0 and cost["bake_vertices"] > 0
    assert 0 <= cost["bake_colours_s"] < cost["bake_per_frame_s"]
    assert cost["model_kb"] > 0 and cost["ply_frames_mb"] > 0
    assert math.isclose(cost["storage_ratio"], cost["ply_frames_mb"] * 1024 / cost["model_kb"], rel_tol=0.05)
    assert any("target: 60 frames at 256x256" in n for n in result["notes"])  # a shrunken run says so


def test_bad_settings_are_one_line(capsys):
    assert main(["bench", "dynamic", "--quick", "--frames", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["neural-bake: error: bench dynamic: frames must be a positive integer, got 0"]
