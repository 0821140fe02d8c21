"""Honest budgets: the reference-step probe, the expected steps, the one-line warning, and a fit on a slow clock."""

import math

import numpy as np
import pytest
import torch

from neural_bake.errors import NeuralBakeWarning
from neural_bake.fit.budget import STEP_COST, budget_record, expected_steps, probe_rate, ReferenceStep, stop_note
from neural_bake.fit.training import LoopConfig, train


def test_probe_times_the_best_reference_step_with_the_clock(ticker):
    # each step is timed by two consecutive calls: one tick
    assert math.isclose(probe_rate(repeat=3, clock=ticker(0.02)), 1 / 0.02)
    real = probe_rate(repeat=3)
    assert real > 0 and probe_rate(repeat=3) == real  # measured once per process


def test_reference_step_trains_the_reference_network():
    """A call is one whole backward of the SDF loss: every parameter gets a finite, non-zero gradient, and
    the same again on the next call (gradients are reset, not summed)."""
    step = ReferenceStep(torch.Generator().manual_seed(3))
    step()
    model = step.model
    first = [p.grad.clone() for p in model.parameters()]
    assert all(torch.isfinite(g).all() and g.abs().sum() > 0 for g in first)
    step()
    for g, p in zip(first, model.parameters()):
        torch.testing.assert_close(p.grad, g)


def test_expected_steps_scale_with_rate_and_time():
    assert expected_steps("64x1", 90.0, rate=20.0) == int(90 * 20 / STEP_COST["64x1"])
    assert expected_steps("64x1", 90.0, rate=10.0) == int(90 * 10 / STEP_COST["64x1"])
    assert expected_steps("9x9", 90.0, rate=20.0) is None and expected_steps("64x1", None, rate=1.0) is None
    presets = {"quick", "default", "high", "64x1", "128x2", "256x2", "256x3", "texture:quick", "texture:default",
               "texture:high"}
    assert set(STEP_COST) == presets and all(c > 0 for c in STEP_COST.values())
    # larger networks cost more a step; the compiled 5-minute preset less than the eager 2-minute one
    assert STEP_COST["64x1"] < STEP_COST["128x2"] < STEP_COST["256x3"] < STEP_COST["high"]
    # the 64x1 texture step is the cheapest; the 10-minute texture's (256, 3) of 2,048 points costs less than
    # the 4-minute one's (192, 3) of 4,096 (measured: bench budget)
    assert STEP_COST["texture:quick"] < STEP_COST["texture:high"] < STEP_COST["texture:default"]
    assert STEP_COST["default"] < STEP_COST["quick"]


def test_budget_record_warns_below_half():
    ok = budget_record(60, 100, preset="64x1", seconds=90, stopped_reason="time budget")
    assert ok["warning"] is None and ok["ratio"] == 0.6 and ok["expected_steps"] == 100
    low = budget_record(49, 100, preset="64x1", seconds=90, stopped_reason="time budget")
    assert low["warning"] == ("64x1: made 49 steps of the ~100 this machine makes in 90 s (49 %): the machine "
                              "was busy or slowed; the fit is weaker than the preset's")
    assert "\n" not in low["warning"]
    # a run that stopped at its step cap was not short of time
    assert budget_record(10, 100, preset="64x1", seconds=90, stopped_reason="steps")["warning"] is None
    assert budget_record(10, None)["ratio"] is None


def test_budget_warning_names_the_sampling_when_it_took_the_time():
    slow = budget_record(40, 100, preset="64x1", seconds=90, stopped_reason="time budget", sampling_share=0.72)
    assert slow["sampling_share"] == 0.72
    assert slow["warning"] == ("64x1: made 40 steps of the ~100 this machine makes in 90 s (40 %): drawing "
                               "training samples took 72 % of its time (an open mesh's winding numbers are "
                               "costly); the fit is weaker than the preset's")
    # a small sampling share leaves the machine as the cause
    busy = budget_record(40, 100, preset="64x1", seconds=90, stopped_reason="time budget", sampling_share=0.13)
    assert "the machine was busy or slowed" in busy["warning"]


def test_stop_notes():
    assert stop_note("time budget", 10, 60.0, 1.0, 500) == "time budget (60 s) used"
    assert stop_note("steps", 500, 12.04, 1.0, 500) == "step cap (500) reached after 12.0 s of the 60-s budget"
    assert stop_note("steps", 500, 12.0, None, 500) == "step count (500) done"


def test_train_budget_follows_the_injected_clock(ticker):
    model = torch.nn.Linear(3, 1)
    x = torch.randn(32, 3)

    def step_fn(step, gen):
        loss = (model(x) ** 2).mean()
        return {"loss": loss}

    clock = ticker(10.0)  # every step looks like it took 20 s (two clock reads a step)
    res = train(model, step_fn, LoopConfig(steps=1000, minutes=1.0, progress=False, log_every=1), clock=clock)
    assert res.stopped_reason == "time budget" and res.steps == 3  # 60 s of budget, 20 s a step
    assert [h["seconds"] for h in res.history] == [20.0, 40.0, 60.0]
    assert res.seconds == pytest.approx(80.0)  # the budget check at 70 s stops it; the end is read at 80 s


def test_slow_texture_fit_warns_and_records(tmp_path, ticker):
    """A texture fit whose clock says each step took 20 s makes 3 of the thousands of steps its preset makes
    here: it warns in one line and the model file records both figures."""
    from neural_bake.fit.texture import fit_texture
    from neural_bake.nets.model_io import load_model

    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.samples.generate import write_sample
    from neural_bake.samples.shapes import get_sample

    mesh = load_mesh(write_sample(get_sample("sphere").mesh(resolution=400, texture_size=64), tmp_path, "sphere"))

    def sphere_sdf(x):  # the sample sphere fills the unit frame: radius 0.9
        n = x.norm(dim=1, keepdim=True)
        return n[:, 0] - 0.9, x / n.clamp_min(1e-12)

    with pytest.warns(NeuralBakeWarning, match=r"texture:quick: made 3 steps of the ~\d+ this machine makes in 60 s"):
        fit = fit_texture(mesh, sphere_sdf, preset="quick", pool=2000, clock=ticker(10.0))
    b = fit.budget
    assert b["steps"] == fit.steps == 3 and b["expected_steps"] > 6 and b["ratio"] < 0.5
    assert b["stopped"] == "time budget (60 s) used" and b["reference_rate"] > 0
    fit.save(tmp_path / "t.tex")
    _, meta = load_model(tmp_path / "t.tex")
    assert meta["budget"]["steps"] == 3 and meta["budget"]["expected_steps"] == b["expected_steps"]
    # a fit that stops at its step cap says so, and does not warn
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", NeuralBakeWarning)
        capped = fit_texture(mesh, sphere_sdf, preset="quick", pool=2000, steps=2)
    assert capped.budget["stopped"].startswith("step cap (2) reached after") and capped.budget["warning"] is None
    np.testing.assert_equal(capped.steps, 2)


def test_best_rate_is_recorded_and_kept(tmp_path, monkeypatch):
    """A busy moment's low probe does not lower the machine's recorded speed; a higher one raises it; a
    corrupt cache file is replaced."""
    import json

    from neural_bake.fit import budget

    monkeypatch.setenv("NEURAL_BAKE_CACHE_DIR", str(tmp_path))
    path = tmp_path / "step_rate.json"
    assert budget.cache_file() == path
    assert budget._best_seen("cpu|2|ref", 150.0) == 150.0
    assert budget._best_seen("cpu|2|ref", 20.0) == 150.0  # busy: the record stands
    assert budget._best_seen("cpu|2|ref", 180.0) == 180.0
    assert json.loads(path.read_text()) == {"cpu|2|ref": 180.0}
    path.write_text("{not json")
    assert budget._best_seen("cpu|2|ref", 30.0) == 30.0
    assert json.loads(path.read_text()) == {"cpu|2|ref": 30.0}


def test_step_cost_is_the_step_over_the_reference_step_on_one_clock():
    """A fit without a step-cost entry measures its own: with a clock on which each of its steps takes 0.5 s
    more than a reference step, and every reading 0.1 s, the cost is 0.6 / 0.1 reference steps."""
    from neural_bake.fit.budget import step_cost

    now = [0.0]

    def clock():
        now[0] += 0.1
        return now[0]

    def step():
        now[0] += 0.5

    assert math.isclose(step_cost(step, 3, clock=clock), 6.0)
