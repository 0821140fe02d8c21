"""The step-cost benchmark in its smallest configuration: two presets, a few seconds each, small pools."""

import pytest

from neural_bake.bench.budget import COLUMNS, QUICK_PRESETS, _presets, run, warm_seconds_per_step
from neural_bake.errors import NeuralBakeError
from neural_bake.fit.budget import STEP_COST

SMALL_SDF = dict(pool_surface=4000, pool_near=4000, pool_uniform=1000)


def test_warm_step_time_skips_the_first_window():
    # a first window of 10 s (a compile) then 0.5 s a step: the slope after it
    history = [{"step": 0, "seconds": 0.0}, {"step": 10, "seconds": 10.0}, {"step": 20, "seconds": 15.0},
               {"step": 30, "seconds": 20.0}]
    assert warm_seconds_per_step(history) == pytest.approx(0.5)
    assert warm_seconds_per_step(history, skip=0) == pytest.approx(20.0 / 30)
    assert warm_seconds_per_step(history[:2]) is None  # one entry left: no slope
    assert warm_seconds_per_step([{"step": 0, "seconds": 0.0}, {"step": 5, "seconds": 1.0},
                                  {"step": 5, "seconds": 2.0}]) is None  # no step between them
    assert warm_seconds_per_step([{"step": 3}, {"lr": 1.0}]) is None  # entries without a time


def test_shrunken_run_measures_costs_against_the_table():
    res = run(quick=True, presets=["texture:quick", "64x1"], seconds=3.0, log_every=5, sdf_overrides=SMALL_SDF,
              texture_overrides={"pool": 20_000})
    assert res["name"] == "budget" and res["quick"] is True and "cores" in res["machine"]
    rows = res["rows"]
    assert [r["preset"] for r in rows] == ["64x1", "texture:quick"]  # the texture needs the SDF first
    rate = res["reference_rate"]
    assert rate > 0
    for r in rows:
        assert set(r) <= set(COLUMNS)
        assert r["steps"] > 0 and r["compiled"] is False and r["table cost"] == STEP_COST[r["preset"]]
        assert r["ms / step"] > 0
        assert r["cost (reference steps)"] == pytest.approx(r["ms / step"] / 1000.0 * rate)
        assert r["measured ÷ table"] == pytest.approx(r["cost (reference steps)"] / r["table cost"])
        # both predictions of the preset's whole budget, one from the measured step and one from the table
        assert r["steps in budget (measured)"] == int(r["budget s"] / (r["ms / step"] / 1000.0))
        assert r["steps in budget (table)"] == int(r["budget s"] * rate / r["table cost"])
    assert rows[0]["net"] == "64x1" and rows[0]["budget s"] == 120.0
    assert rows[1]["budget s"] == 60.0
    assert any("reference rate" in n for n in res["notes"])


def test_texture_alone_fits_its_sdf_first():
    said = []
    res = run(quick=True, presets=["texture:quick"], seconds=2.0, log_every=5, sdf_overrides=SMALL_SDF,
              texture_overrides={"pool": 20_000}, log=said.append)
    assert [r["preset"] for r in res["rows"]] == ["texture:quick"] and res["rows"][0]["steps"] > 0
    assert said[0].startswith("texture:quick") and any("64x1: the SDF" in s for s in said)


def test_preset_choice_puts_textures_after_the_sdf_they_need():
    assert _presets(None, quick=True) == list(QUICK_PRESETS)  # nothing compiled: under two minutes
    full = _presets(None, quick=False)
    assert sorted(full) == sorted([*STEP_COST, "tile"])
    assert [p.startswith("texture:") for p in full] == sorted(p.startswith("texture:") for p in full)


def test_the_tile_row_measures_a_tile_levels_step_per_tile():
    from neural_bake.fit.budget import TILE_STEP_COST

    res = run(quick=True, presets=["tile"], seconds=8.0, log_every=2, sdf_overrides={**SMALL_SDF, "tile_grid": 3})
    (row,) = res["rows"]
    k = int(row["net"].split("x(")[0])
    # the 3³ cells over the mesh's cube and any of the ring around them where the rough coarse level errs
    assert row["preset"] == "tile" and row["net"] == f"{k}x(64x2)" and 0 < k <= 5 ** 3
    assert row["table cost"] == TILE_STEP_COST and row["budget s"] is None
    assert row["cost (reference steps)"] == pytest.approx(row["ms / step"] / 1000.0 * res["reference_rate"])


def test_errors():
    with pytest.raises(NeuralBakeError, match="no step cost for preset.*fastest"):
        run(quick=True, presets=["fastest"])
    with pytest.raises(NeuralBakeError, match="seconds must be positive"):
        run(quick=True, presets=["64x1"], seconds=0.0)


def test_cli_verb_is_registered(capsys):
    from neural_bake.cli.main import main

    assert main(["bench", "budget", "--help"]) == 0
    out = capsys.readouterr().out
    assert "--quick" in out and "--json" in out and "--preset" in out and "--seconds" in out
    assert main(["bench", "budget", "--seconds", "0"]) != 0  # below the range: a usage error
