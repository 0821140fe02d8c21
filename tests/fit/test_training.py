"""The shared training loop: reproducibility, resume, budgets, divergence recovery, keep-best."""

import math

import pytest
import torch

from neural_bake.errors import FitError, NeuralBakeWarning
from neural_bake.fit.training import LoopConfig, load_checkpoint, step_generator, train


def _problem(seed=0):
    """A tiny regression: a 2-layer MLP to sin(3x) on random points drawn per step."""
    torch.manual_seed(seed)
    model = torch.nn.Sequential(torch.nn.Linear(1, 16), torch.nn.Tanh(), torch.nn.Linear(16, 1))

    def step_fn(step, gen):
        x = torch.rand(64, 1, generator=gen) * 2 - 1
        mse = ((model(x) - torch.sin(3 * x)) ** 2).mean()
        return {"loss": mse, "mse": mse}

    return model, step_fn


def _weights(model):
    return torch.cat([p.detach().flatten() for p in model.parameters()])


def test_loss_decreases_and_history_is_logged():
    model, step_fn = _problem()
    res = train(model, step_fn, LoopConfig(steps=300, lr=3e-2, progress=False, log_every=50))
    assert res.steps == 300 and res.stopped_reason == "steps"
    assert [h["step"] for h in res.history] == [1, 50, 100, 150, 200, 250, 300]
    assert res.history[-1]["mse"] < 0.25 * res.history[0]["mse"]
    assert all(set(h) >= {"step", "seconds", "lr", "loss", "mse"} for h in res.history)


@pytest.mark.parametrize("factor", [0.05, 0.01, 1.0])
def test_cosine_schedule_decays_to_the_min_factor(factor):
    model, step_fn = _problem()
    n = 100
    res = train(model, step_fn, LoopConfig(steps=n, lr=1e-2, lr_min_factor=factor, progress=False, log_every=1))
    lrs = [h["lr"] for h in res.history]  # entry k ran step k - 1
    want = [1e-2 * (factor + (1 - factor) * 0.5 * (1 + math.cos(math.pi * k / n))) for k in range(n)]
    assert lrs == pytest.approx(want, rel=1e-9)
    assert lrs[0] == pytest.approx(1e-2) and lrs[-1] == pytest.approx(factor * 1e-2, rel=0.05)


def test_seed_reproduces_and_differs():
    a, fa = _problem()
    b, fb = _problem()
    c, fc = _problem()
    train(a, fa, LoopConfig(steps=40, lr=1e-2, seed=3, progress=False))
    train(b, fb, LoopConfig(steps=40, lr=1e-2, seed=3, progress=False))
    train(c, fc, LoopConfig(steps=40, lr=1e-2, seed=4, progress=False))
    assert torch.equal(_weights(a), _weights(b))
    assert not torch.equal(_weights(a), _weights(c))


def test_step_generator_depends_on_seed_and_step_only():
    x = torch.rand(5, generator=step_generator(1, 7))
    assert torch.equal(x, torch.rand(5, generator=step_generator(1, 7)))
    assert not torch.equal(x, torch.rand(5, generator=step_generator(1, 8)))


def test_resume_matches_uninterrupted_run(tmp_path):
    ck = tmp_path / "run.ckpt"
    full, ff = _problem()
    train(full, ff, LoopConfig(steps=60, lr=1e-2, progress=False, lr_schedule="cosine"))
    part, fp = _problem()
    r1 = train(part, fp, LoopConfig(steps=60, lr=1e-2, progress=False, checkpoint=str(ck), checkpoint_every=25),
               fingerprint="x")
    assert r1.steps == 60
    # interrupted after 25 steps: rebuild from the step-25 checkpoint written by a run that stops there
    ck2 = tmp_path / "half.ckpt"
    half, fh = _problem()
    cfg = LoopConfig(steps=60, lr=1e-2, progress=False, checkpoint=str(ck2), checkpoint_every=25)

    def interrupting(step, gen):
        if step == 30:
            raise KeyboardInterrupt
        return fh(step, gen)

    with pytest.raises(KeyboardInterrupt):
        train(half, interrupting, cfg, fingerprint="x")
    assert load_checkpoint(ck2)[2]["step"] == 25
    resumed, fr = _problem(seed=99)  # different init: everything must come from the checkpoint
    r2 = train(resumed, fr, LoopConfig(steps=60, lr=1e-2, progress=False, checkpoint=str(ck2),
                                       checkpoint_every=25, resume=True), fingerprint="x")
    assert r2.steps == 60
    assert torch.allclose(_weights(resumed), _weights(full), atol=1e-6)


def test_resume_other_run_is_refused(tmp_path):
    ck = tmp_path / "run.ckpt"
    m, f = _problem()
    train(m, f, LoopConfig(steps=5, progress=False, checkpoint=str(ck)), fingerprint="a")
    with pytest.raises(FitError, match="belongs to another run"):
        train(m, f, LoopConfig(steps=10, progress=False, checkpoint=str(ck), resume=True), fingerprint="b")


def test_corrupt_checkpoint_is_a_fit_error(tmp_path):
    ck = tmp_path / "bad.ckpt"
    ck.write_bytes(b"not a checkpoint at all")
    with pytest.raises(FitError, match="not a readable checkpoint"):
        load_checkpoint(ck)
    with pytest.raises(FitError, match="checkpoint not found"):
        load_checkpoint(tmp_path / "missing.ckpt")


def test_time_budget_stops():
    m, f = _problem()

    def slow(step, gen):
        import time
        time.sleep(0.02)
        return f(step, gen)

    res = train(m, slow, LoopConfig(steps=100000, minutes=0.5 / 60, progress=False))
    assert res.stopped_reason == "time budget"
    assert 0 < res.steps < 100 and res.seconds >= 0.5


def test_transient_divergence_restores_and_halves_lr():
    m, f = _problem()
    state = {"fired": False}

    def flaky(step, gen):
        out = f(step, gen)
        if step == 15 and not state["fired"]:
            state["fired"] = True
            return {"loss": out["loss"] * float("nan"), "mse": out["mse"]}
        return out

    with pytest.warns(NeuralBakeWarning, match=r"diverged at step 15 \(non-finite loss\); restored step 10 and "
                                               r"halved the learning rate to 0.005"):
        res = train(m, flaky, LoopConfig(steps=30, lr=1e-2, progress=False, snapshot_every=10,
                                         lr_schedule="constant"))
    assert res.restarts == 1 and res.lr == pytest.approx(5e-3) and res.steps == 30
    assert torch.isfinite(_weights(m)).all()


def test_persistent_divergence_raises_and_leaves_finite_weights():
    m, f = _problem()

    def exploding(step, gen):
        out = f(step, gen)
        return {"loss": out["loss"] * (1.0 if step < 3 else 1e9)}

    with pytest.warns(NeuralBakeWarning), pytest.raises(FitError, match=r"diverged at step 3 .*after 2 "
                                                                         r"learning-rate halvings"):
        train(m, exploding, LoopConfig(steps=20, lr=1e-2, progress=False, max_restarts=2))
    assert torch.isfinite(_weights(m)).all()


def _linear_problem():
    """A ReLU network fitting a linear map with noise 0.03: its loss settles near 1e-3, a thousandth of the
    first one."""
    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Linear(3, 16), torch.nn.ReLU(), torch.nn.Linear(16, 1))
    w = torch.tensor([[1.0, -2.0, 0.5]])

    def step_fn(step, gen):
        x = torch.randn(256, 3, generator=gen)
        y = x @ w.t() + 0.03 * torch.randn(256, 1, generator=gen)
        mse = ((model(x) - y) ** 2).mean()
        return {"loss": mse, "mse": mse}

    return model, step_fn


def test_collapse_back_to_the_first_loss_restores_and_halves_lr():
    """A network that collapses at step 150 (every ReLU dead: a constant, for good) falls back to about its
    first loss, which the first-loss test misses; its median loss becomes thousands of times its best: the
    loop restores the last snapshot, halves the learning rate, says so, and ends near the loss it had."""
    m, f = _linear_problem()
    state = {"fired": False}

    def collapsing(step, gen):
        if step == 150 and not state["fired"]:
            state["fired"] = True
            with torch.no_grad():
                m[0].bias.fill_(-1e3)
        return f(step, gen)

    with pytest.warns(NeuralBakeWarning, match=r"diverged at step 1[78]\d \(loss collapsed: its median over 50 "
                                               r"steps \S+ is \d+× its best \S+\); restored step 100 and halved the "
                                               r"learning rate to 0.01"):
        res = train(m, collapsing, LoopConfig(steps=300, lr=0.02, progress=False, lr_schedule="constant",
                                              log_every=10))
    assert res.restarts == 1 and res.steps == 300 and res.history[-1]["mse"] < 3e-3
    # without the test the same run ends as a constant
    m, f = _linear_problem()
    state["fired"] = False
    res = train(m, collapsing, LoopConfig(steps=300, lr=0.02, progress=False, lr_schedule="constant",
                                          collapse=0, log_every=10))
    assert res.restarts == 0 and res.history[-1]["mse"] > 1.0


def test_no_snapshot_while_collapsing_and_a_short_spike_passes():
    """Snapshots are taken only near the best median loss: a collapse that starts five steps before a
    snapshot step restores the snapshot before it. A five-step spike of the reported loss, 1,000×, does not
    count."""
    m, f = _linear_problem()
    seen = {"max": -1, "restored": False}

    def scaled(factor_at):
        def step_fn(step, gen):
            seen["restored"] |= step <= seen["max"]
            seen["max"] = max(seen["max"], step)
            out = f(step, gen)
            k = factor_at(step, seen["restored"])
            # the loss reads k times higher; its gradient is the step's own
            return {"loss": out["loss"] + (k - 1.0) * out["loss"].detach(), "mse": out["mse"]}
        return step_fn

    with pytest.warns(NeuralBakeWarning, match=r"loss collapsed.*restored step 100 and halved"):
        res = train(m, scaled(lambda step, restored: 300.0 if step >= 195 and not restored else 1.0),
                    LoopConfig(steps=260, lr=0.02, progress=False, lr_schedule="constant"))
    assert res.restarts == 1
    m, f = _linear_problem()
    seen.update(max=-1, restored=False)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", NeuralBakeWarning)
        res = train(m, scaled(lambda step, restored: 1000.0 if 195 <= step < 200 else 1.0),
                    LoopConfig(steps=260, lr=0.02, progress=False, lr_schedule="constant"))
    assert res.restarts == 0


def test_keep_best_restores_best_weights():
    m, f = _problem()
    values = iter([3.0, 1.0, 2.0, 5.0])
    snap = {}

    def evaluate():
        v = next(values)
        snap[v] = _weights(m).clone()
        return v

    res = train(m, f, LoopConfig(steps=40, lr=1e-2, progress=False, eval_every=10), evaluate=evaluate)
    assert res.best_step == 20 and res.best_value == 1.0
    assert torch.equal(_weights(m), snap[1.0])
    assert [e["step"] for e in res.evaluations] == [10, 20, 30, 40]


@pytest.mark.parametrize("kw, msg", [
    ({"steps": -1}, "steps must be"), ({"steps": 0}, "steps must be a positive integer"), ({"lr": 0.0}, "learning rate must be positive"),
    ({"minutes": -2.0}, "minutes must be positive"), ({"lr_schedule": "step"}, "lr_schedule"),
    ({"resume": True}, "resume needs a checkpoint"), ({"log_every": 0}, "log_every must be"),
    ({"lr_min_factor": 0.0}, r"lr_min_factor must be in \(0, 1\]"), ({"lr_min_factor": 1.5}, "lr_min_factor"),
    ({"lr_min_factor": math.nan}, "lr_min_factor"), ({"collapse": 0.5}, "collapse must be 0 .off. or above 1"),
    ({"collapse": math.inf}, "collapse must be"), ({"collapse_window": 0}, "collapse_window must be"),
])
def test_bad_config(kw, msg):
    m, f = _problem()
    with pytest.raises(FitError, match=msg):
        train(m, f, LoopConfig(progress=False, **kw))


def test_progress_bar_runs(capsys):
    m, f = _problem()
    res = train(m, f, LoopConfig(steps=5, progress=True, log_every=1))
    assert res.steps == 5 and math.isfinite(res.history[-1]["loss"])


def test_step_that_back_propagates_itself():
    # a step_fn may run its own backward (the SDF fitter's micro-batches) and return the loss detached
    a, fa = _problem()
    b, _ = _problem()

    def own(step, gen):
        x = torch.rand(64, 1, generator=gen) * 2 - 1
        mse = ((b(x) - torch.sin(3 * x)) ** 2).mean()
        mse.backward()
        return {"loss": mse.detach()}

    cfg = LoopConfig(steps=20, lr=1e-2, progress=False, seed=3)
    train(a, fa, cfg)
    train(b, own, cfg)
    assert torch.allclose(_weights(a), _weights(b))


def test_detached_loss_without_backward_is_refused():
    model, _ = _problem()

    def forgot(step, gen):
        return {"loss": torch.tensor(1.0)}

    with pytest.raises(FitError, match="without a graph and back-propagated nothing"):
        train(model, forgot, LoopConfig(steps=3, progress=False))


def test_time_budgeted_progress_bar_shows_seconds_against_the_budget(capsys):
    """Not steps out of the (unreachable) step cap: seconds out of the budget, the step count beside them."""
    torch.manual_seed(0)
    model = torch.nn.Linear(3, 1)

    def step_fn(step, gen):
        x = torch.rand(64, 3, generator=gen)
        return {"loss": (model(x) ** 2).mean()}

    res = train(model, step_fn, LoopConfig(steps=100_000, minutes=0.02, progress=True, log_every=1, desc="budget"))
    err = capsys.readouterr().err
    assert res.stopped_reason == "time budget"
    assert "/1 s of the budget" in err and "step=" in err
    assert "100000" not in err


def test_adam_is_fused_for_many_parameters_only():
    """A feature grid's table (many parameters) takes torch's fused Adam update, a small network the default, a
    parameter in a dtype the fused update lacks the default; the fused step follows the default one."""
    from neural_bake.fit.training import FUSED_ADAM_PARAMETERS, adam_options

    big = [torch.nn.Parameter(torch.zeros(FUSED_ADAM_PARAMETERS))]
    assert adam_options(big) == {"fused": True}
    assert adam_options([torch.nn.Parameter(torch.zeros(100))]) == {}
    assert adam_options([torch.nn.Parameter(torch.zeros(FUSED_ADAM_PARAMETERS, dtype=torch.bfloat16))]) == {}
    a = torch.nn.Parameter(torch.linspace(-1, 1, FUSED_ADAM_PARAMETERS))
    b = torch.nn.Parameter(a.detach().clone())
    opts = [torch.optim.Adam([a], lr=1e-2, **adam_options([a])), torch.optim.Adam([b], lr=1e-2)]
    for _ in range(3):
        for p, opt in zip((a, b), opts):
            opt.zero_grad()
            (p ** 2).sum().backward()
            opt.step()
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_all_finite_finds_one_bad_element_anywhere(dtype, bad):
    """The loop's check (one sum a tensor) against the elementwise one, with the bad value at the first, a
    middle and the last place of one of several tensors; None is skipped; finite values summing far from zero
    stay finite."""
    from neural_bake.fit.training import _all_finite

    tensors = [torch.linspace(-1e30, 1e30, 1001, dtype=dtype), None, torch.full((300, 7), 3e4, dtype=dtype)]
    assert _all_finite(tensors) and _all_finite([]) and _all_finite([None])
    for which in (0, 2):
        for at in (0, tensors[which].numel() // 2, tensors[which].numel() - 1):
            t = [x.clone() if x is not None else None for x in tensors]
            t[which].view(-1)[at] = bad
            assert not _all_finite(t)
            assert not all(bool(torch.isfinite(x).all()) for x in t if x is not None)


class _PoisonGradient(torch.autograd.Function):
    """The identity, whose gradient has a NaN in its last entry."""

    @staticmethod
    def forward(ctx, x):
        return x.view_as(x)

    @staticmethod
    def backward(ctx, g):
        g = g.clone()
        g.view(-1)[-1] = float("nan")
        return g


def test_a_non_finite_gradient_under_a_finite_loss_restores_and_halves_lr():
    """A step whose loss is finite but one gradient entry NaN is caught before the update (the weights stay
    finite) and restarted from the last snapshot."""
    m, f = _problem()
    state = {"fired": False}
    w = next(m.parameters())

    def poisoned(step, gen):
        out = f(step, gen)
        if step == 12 and not state["fired"]:
            state["fired"] = True
            return {"loss": out["loss"] + (_PoisonGradient.apply(w) * 0.0).sum(), "mse": out["mse"]}
        return out

    with pytest.warns(NeuralBakeWarning, match=r"diverged at step 12 \(non-finite gradient\); restored step 10"):
        res = train(m, poisoned, LoopConfig(steps=20, lr=1e-2, progress=False, snapshot_every=10,
                                            lr_schedule="constant"))
    assert res.restarts == 1 and res.steps == 20
    assert torch.isfinite(_weights(m)).all()
