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
    presets = {"quick", "quick/coarse", "quick/fine", "default", "default/coarse", "default/fine", "high",
               "high/coarse", "high/fine", "64x1", "128x2", "256x2", "256x3", "texture:quick", "texture:default",
               "texture:high"}
    assert set(STEP_COST) == presets and all(c > 0 for c in STEP_COST.values())
    # the quick construction's levels: its 64-wide coarse level costs less a step than its 128-wide fine one,
    # which costs less than the plain 192-wide network
    assert STEP_COST["quick/coarse"] < STEP_COST["quick/fine"] < STEP_COST["quick"]
    # larger networks cost more a step; the compiled 5-minute preset less than the eager 2-minute one
    assert STEP_COST["64x1"] < STEP_COST["128x2"] < STEP_COST["256x3"] < STEP_COST["high"]
    # the feature grids (the C kernel's encoding, the fused Adam update of their tables) cost less a step than the
    # 10-minute texture's (256, 3) SIREN of 2,048 points; the 1-minute grid of 2,048 points a little less than the
    # 4-minute one of 4,096 (measured: bench budget)
    assert STEP_COST["texture:quick"] < STEP_COST["texture:default"] < STEP_COST["texture:high"]
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


def test_budget_record_names_the_slowdown_and_notes_the_sampling():
    """Below half, the warning says how much slower than quiet the steps' own work ran; the mesh's own
    sampling is counted in the expected steps, so a large share of it is a note, not a warning."""
    slow = budget_record(40, 100, preset="64x1", seconds=90, stopped_reason="time budget", step_seconds=0.5,
                         compute_seconds=1.25, asset_seconds=0.0, sampling_share=0.0)
    assert slow["warning"] == ("64x1: made 40 steps of the ~100 this machine makes in 90 s (40 %): its steps' own "
                               "work took 2.5× the 500.0 ms this machine takes for one when quiet: the machine was "
                               "busy or slowed; the fit is weaker than the preset's")
    assert slow["note"] is None and slow["budget"] == "time"
    heavy = budget_record(95, 100, preset="64x1", seconds=90, stopped_reason="time budget", step_seconds=0.2,
                          compute_seconds=0.2, asset_seconds=0.7, sampling_share=0.72, preset_steps=450)
    assert heavy["warning"] is None and heavy["asset_seconds_per_step"] == 0.7
    assert heavy["note"] == ("64x1: drawing training samples (this mesh's pools and mined points) took 72 % of its "
                             "time; the ~100 steps expected count it (~450 without it)")
    # a small sampling share needs no note
    assert budget_record(95, 100, preset="64x1", seconds=90, sampling_share=0.13, asset_seconds=0.01)["note"] is None


def test_expected_steps_count_the_assets_own_seconds():
    cost = STEP_COST["64x1"]
    assert expected_steps("64x1", 120.0, rate=cost) == 120  # a quiet step takes 1 s here
    assert expected_steps("64x1", 120.0, rate=cost, asset_seconds=3.0) == 30
    assert expected_steps("64x1", 120.0, rate=cost, asset_seconds=None) == 120


def test_reference_steps_are_each_presets_budget_at_one_reference_rate():
    """REFERENCE_STEPS holds, for every preset with a step cost, the Adam part of its time budget times one
    reference rate over its cost: the rate each entry implies is the same."""
    from neural_bake.fit.budget import reference_steps
    from neural_bake.fit.presets import REFERENCE_STEPS
    from neural_bake.fit.sdf_config import PRESETS as SDF
    from neural_bake.fit.sdf_config import SdfFitConfig
    from neural_bake.fit.texture import PRESETS as TEXTURE

    def adam_seconds(key):
        if key.startswith("texture:"):
            return 60.0 * TEXTURE[key.split(":", 1)[1]]["minutes"]
        preset, _, level = key.partition("/")  # a construction's level: its share of the preset's time
        coarse = SDF[preset].get("coarse_share", SdfFitConfig().coarse_share)
        share = {"": 1.0, "coarse": coarse, "fine": 1.0 - coarse}[level]
        return 60.0 * SDF[preset]["minutes"] * (1.0 - SDF[preset].get("polish_share", 0.0)) * share

    assert set(REFERENCE_STEPS) == set(STEP_COST)
    rates = [n * STEP_COST[k] / adam_seconds(k) for k, n in REFERENCE_STEPS.items()]
    assert max(rates) / min(rates) < 1.001
    assert reference_steps("quick") == REFERENCE_STEPS["quick"] and reference_steps(None) is None
    assert reference_steps("9x9") is None


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


# ------------------------------------------------------------------- the asset's own costs, budget="steps"
def _ball(sub=2):
    import trimesh

    from neural_bake.io.mesh_io import mesh_from_arrays

    m = trimesh.creation.icosphere(subdivisions=sub, radius=0.8)
    return mesh_from_arrays(np.asarray(m.vertices), np.asarray(m.faces), normalise=False)


#: Pools small enough for a quick test (not part of a preset's step cost: its network and batches are).
SMALL_POOLS = dict(pool_surface=20000, pool_near=20000, pool_uniform=5000, progress=False)


def _costed_clock(monkeypatch, *, sample: float, compute: float):
    """A clock that moves only when an SDF fit samples (``sample`` seconds a step: pools, mining, the draw)
    and when its step computes (``compute`` seconds), with this machine's quiet 64x1 step at 1 s."""
    from neural_bake.fit import budget, sdf

    now = [0.0]
    draw, backward = sdf._draw, sdf.sdf_step_backward

    def slow_draw(*args, **kwargs):
        now[0] += sample
        return draw(*args, **kwargs)

    def slow_backward(*args, **kwargs):
        now[0] += compute
        return backward(*args, **kwargs)

    monkeypatch.setattr(sdf, "_draw", slow_draw)
    monkeypatch.setattr(sdf, "sdf_step_backward", slow_backward)
    monkeypatch.setattr(budget, "_full_rate", lambda: STEP_COST["64x1"])
    return lambda: now[0]


def test_a_mesh_whose_sampling_takes_the_time_is_expected_to_make_fewer_steps_and_not_warned(monkeypatch):
    """Each step samples for 3 s and computes for 1 s (the quiet step's time): 30 steps in 120 s, as
    expected for this mesh; no warning of a busy machine, a note of the sampling's share instead."""
    import warnings

    from neural_bake.fit.sdf import fit_sdf

    clock = _costed_clock(monkeypatch, sample=3.0, compute=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", NeuralBakeWarning)
        fit = fit_sdf(_ball(), preset="64x1", clock=clock, polish_evals=0, **SMALL_POOLS)
    b = fit.budget
    assert fit.steps == b["steps"] == 30 and b["expected_steps"] == 30 and b["warning"] is None
    assert b["preset_steps"] == 120 and b["ratio"] == 1.0
    assert b["asset_seconds_per_step"] == pytest.approx(3.0) and b["compute_seconds_per_step"] == pytest.approx(1.0)
    assert b["step_seconds"] == pytest.approx(1.0) and b["sampling_share"] == pytest.approx(0.75)
    assert b["note"] == ("64x1: drawing training samples (this mesh's pools and mined points) took 75 % of its "
                         "time; the ~30 steps expected count it (~120 without it)")


def test_a_fit_whose_steps_compute_slowly_is_warned_of_a_busy_machine(monkeypatch):
    """Each step computes for 3 s where this machine takes 1 s when quiet, and samples in no time: 40 of
    the 120 expected steps, and a warning that names the slowdown."""
    from neural_bake.fit.sdf import fit_sdf

    clock = _costed_clock(monkeypatch, sample=0.0, compute=3.0)
    with pytest.warns(NeuralBakeWarning) as caught:
        fit = fit_sdf(_ball(), preset="64x1", clock=clock, polish_evals=0, **SMALL_POOLS)
    b = fit.budget
    assert fit.steps == 40 and b["expected_steps"] == 120 and b["asset_seconds_per_step"] == 0.0
    assert b["warning"] == ("64x1: made 40 steps of the ~120 this machine makes in 120 s (33 %): its steps' own work "
                            "took 3.0× the 1000.0 ms this machine takes for one when quiet: the machine was busy or "
                            "slowed; the fit is weaker than the preset's")
    assert [str(w.message) for w in caught if "made 40 steps" in str(w.message)] == [b["warning"]]
    assert b["note"] is None


def test_a_steps_budget_runs_the_presets_reference_steps_whatever_the_clock(monkeypatch, tmp_path, ticker):
    """budget="steps": the preset's steps on the reference machine (here shrunk to 4), no time stop, on a slow
    clock as on a fast one; the file records the budget kind and the estimated seconds."""
    import warnings

    from neural_bake.fit import presets
    from neural_bake.fit.sdf import fit_sdf, load_sdf

    monkeypatch.setitem(presets.REFERENCE_STEPS, "64x1", 4)
    fits = []
    for clock in (ticker(10.0), ticker(1e-4)):
        with warnings.catch_warnings():
            warnings.simplefilter("error", NeuralBakeWarning)
            fits.append(fit_sdf(_ball(), preset="64x1", budget="steps", clock=clock, polish_evals=0,
                                **SMALL_POOLS))
    for fit in fits:
        b = fit.budget
        assert fit.steps == 4 and fit.stopped_reason == "steps" and fit.config.minutes is None
        assert fit.config.steps == 4 and fit.config.budget == "steps"
        assert b["budget"] == "steps" and b["reference_steps"] == b["expected_steps"] == 4 and b["warning"] is None
        assert b["estimated_seconds"] == pytest.approx(4 * (b["step_seconds"] + b["asset_seconds_per_step"]))
        assert b["stopped"] == "step count (4) done"
    torch.testing.assert_close(torch.cat([p.flatten() for p in fits[0].model.parameters()]),
                               torch.cat([p.flatten() for p in fits[1].model.parameters()]), atol=1e-5, rtol=0)
    fits[0].save(tmp_path / "s.sdf")
    back = load_sdf(tmp_path / "s.sdf")
    assert back.config.budget == "steps" and back.budget["budget"] == "steps" and back.steps == 4
    assert back.budget["estimated_seconds"] == fits[0].budget["estimated_seconds"]


def test_a_steps_budget_needs_a_preset_with_its_network():
    from neural_bake.errors import FitError
    from neural_bake.fit.sdf import fit_sdf

    with pytest.raises(FitError, match=r"^fit_sdf: budget='steps' needs preset .*got preset None$"):
        fit_sdf(_ball(1), budget="steps", width=16, depth=1, steps=2, progress=False)
    with pytest.raises(FitError, match=r"^fit_sdf: budget='steps' needs preset .*got preset '64x1'$"):
        fit_sdf(_ball(1), preset="64x1", budget="steps", width=32, progress=False)
    with pytest.raises(FitError, match=r"^fit_sdf: budget must be 'time' or 'steps', got 'wall'$"):
        fit_sdf(_ball(1), budget="wall")


def test_cli_fit_sdf_with_a_steps_budget(monkeypatch, tmp_path, capsys):
    """`fit sdf --preset quick --budget steps` runs the preset's reference steps (shrunk to 3) and records
    the budget kind, the steps and the estimate in the model file."""
    import trimesh

    from neural_bake.cli.main import main
    from neural_bake.fit import presets
    from neural_bake.fit.sdf import load_sdf

    monkeypatch.setitem(presets.REFERENCE_STEPS, "quick/coarse", 2)  # quick's construction: both its levels
    monkeypatch.setitem(presets.REFERENCE_STEPS, "quick/fine", 3)
    src, out = tmp_path / "ball.obj", tmp_path / "ball.sdf"
    trimesh.creation.icosphere(subdivisions=2, radius=1.0).export(src)
    code = main(["fit", "sdf", str(src), "-o", str(out), "--preset", "quick", "--budget", "steps", "--no-progress",
                 "--no-metrics", "--pool-surface", "4000", "--pool-near", "4000", "--pool-uniform", "1000"])
    assert code == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    assert "3 steps in" in printed and "the preset's steps on the quiet reference machine, ~" in printed
    fit = load_sdf(out)
    assert fit.steps == 3 and fit.config.budget == "steps" and fit.config.minutes is None
    assert fit.budget["budget"] == "steps" and fit.budget["reference_steps"] == 5 and fit.budget["steps"] == 5
    assert fit.budget["levels"]["coarse"]["reference_steps"] == 2 and fit.budget["estimated_seconds"] > 0


def test_texture_steps_budget_runs_the_presets_reference_steps(monkeypatch, tmp_path, ticker):
    """A texture fit with budget="steps" makes the preset's reference steps (shrunk to 5) on a clock that
    says each step took 20 s, without a warning; without a preset it is refused."""
    import warnings

    from neural_bake.errors import FitError
    from neural_bake.fit import presets
    from neural_bake.fit.texture import fit_texture
    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.samples.generate import write_sample
    from neural_bake.samples.shapes import get_sample

    mesh = load_mesh(write_sample(get_sample("sphere").mesh(resolution=400, texture_size=64), tmp_path, "sphere"))

    def sphere_sdf(x):
        n = x.norm(dim=1, keepdim=True)
        return n[:, 0] - 0.9, x / n.clamp_min(1e-12)

    monkeypatch.setitem(presets.REFERENCE_STEPS, "texture:quick", 5)
    with warnings.catch_warnings():
        warnings.simplefilter("error", NeuralBakeWarning)
        fit = fit_texture(mesh, sphere_sdf, preset="quick", budget="steps", pool=2000, clock=ticker(10.0))
    assert fit.steps == 5 and fit.stopped_reason == "steps" and fit.config.minutes is None
    assert fit.budget["budget"] == "steps" and fit.budget["reference_steps"] == 5
    assert fit.budget["estimated_seconds"] == pytest.approx(5 * fit.budget["step_seconds"])
    with pytest.raises(FitError, match=r"^budget: 'steps' needs preset .*got preset None$"):
        fit_texture(mesh, sphere_sdf, budget="steps", pool=2000)


def test_batch_stages_take_a_steps_budget():
    from neural_bake.pipelines.stages import resolve_stages

    stages = resolve_stages({"sdf": {"preset": "quick", "budget": "steps"}, "texture": {"budget": "steps"}})
    assert stages["sdf"].budget == "steps" and stages["texture"].budget == "steps"
