"""lbfgs_polish: it lowers the loss, keeps only what the held-out batch confirms, and restores exactly."""

import math
import time

import pytest
import torch

from neural_bake.errors import FitError, NeuralBakeWarning
from neural_bake.fit.polish import CHUNK_ITERATIONS, lbfgs_polish


def regression(dtype, n=400, seed=0, sign=1.0):
    """Points x and targets y = sin(3 x·a) (sign flips the target: another function)."""
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(n, 2, generator=g, dtype=dtype) * 2 - 1
    return x, sign * torch.sin(3.0 * (x @ torch.tensor([1.0, -0.5], dtype=dtype)))


def small_net(dtype):
    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Linear(2, 16), torch.nn.Tanh(), torch.nn.Linear(16, 1)).to(dtype)


def mse(model):
    def loss_fn(batch):
        x, y = batch
        loss = ((model(x)[:, 0] - y) ** 2).mean()
        loss.backward()
        return loss.detach()
    return loss_fn


def params(model):
    return torch.cat([p.detach().flatten() for p in model.parameters()])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_polish_lowers_both_losses_and_clears_the_gradients(dtype):
    model = small_net(dtype)
    res = lbfgs_polish(model, mse(model), regression(dtype), regression(dtype, seed=1), evals=60)
    assert res.kept and res.reason == "kept"
    assert res.loss_after < 0.1 * res.loss_before and res.check_after < 0.2 * res.check_before
    assert 1 < res.evals <= 60 + 25  # a line search may overshoot the count by at most its 25 evaluations
    assert all(p.grad is None for p in model.parameters())
    # the record is the truth: the model now has the polished loss
    with torch.no_grad():
        x, y = regression(dtype)
        assert math.isclose(float(((model(x)[:, 0] - y) ** 2).mean()), res.loss_after, rel_tol=1e-5)
    assert res.to_dict()["kept"] is True


def test_a_held_out_loss_that_rises_restores_the_weights_exactly():
    model = small_net(torch.float64)
    before = params(model).clone()
    # the check batch wants the opposite function: fitting one makes the other worse
    with pytest.warns(NeuralBakeWarning, match="held-out loss rose"):
        res = lbfgs_polish(model, mse(model), regression(torch.float64),
                           regression(torch.float64, seed=1, sign=-1.0), evals=40)
    assert not res.kept and res.reason == "held-out loss rose" and res.check_after > res.check_before
    assert torch.equal(params(model), before)


def test_a_loss_that_turns_non_finite_restores_the_weights():
    model = small_net(torch.float32)
    before = params(model).clone()
    inner = mse(model)
    calls = [0]

    def loss_fn(batch):
        calls[0] += 1
        loss = inner(batch)
        return loss * math.nan if calls[0] > 5 else loss

    with pytest.warns(NeuralBakeWarning, match="non-finite"):
        res = lbfgs_polish(model, loss_fn, regression(torch.float32), regression(torch.float32, seed=1), evals=50)
    assert not res.kept and res.reason == "non-finite weights or loss"
    assert torch.equal(params(model), before)
    assert all(torch.isfinite(p).all() for p in model.parameters())


def test_a_passed_deadline_does_nothing():
    model = small_net(torch.float32)
    before = params(model).clone()
    res = lbfgs_polish(model, mse(model), regression(torch.float32), regression(torch.float32, seed=1), evals=50,
                       deadline=time.perf_counter() - 1.0)
    assert res.evals == 0 and not res.kept and res.reason == "no time left"
    assert torch.equal(params(model), before) and res.loss_before == res.loss_after


def test_the_evaluation_count_is_honoured_across_calls():
    model = small_net(torch.float64)
    res = lbfgs_polish(model, mse(model), regression(torch.float64), regression(torch.float64, seed=1),
                       evals=3 * CHUNK_ITERATIONS)
    assert 2 * CHUNK_ITERATIONS < res.evals <= 3 * CHUNK_ITERATIONS + 25


@pytest.mark.parametrize("evals", [0, -3, 2.5])
def test_bad_evaluation_counts_are_refused(evals):
    model = small_net(torch.float32)
    with pytest.raises(FitError, match="evals must be a positive integer"):
        lbfgs_polish(model, mse(model), regression(torch.float32), regression(torch.float32), evals=evals)


def test_a_model_without_trainable_parameters_is_refused():
    model = small_net(torch.float32).requires_grad_(False)
    with pytest.raises(FitError, match="no trainable parameters"):
        lbfgs_polish(model, mse(model), regression(torch.float32), regression(torch.float32), evals=5)


def test_a_deadline_stops_the_polish_near_it_not_a_chunk_later():
    model = small_net(torch.float64)
    inner = mse(model)

    def slow(batch):  # 20 ms an evaluation: a whole chunk (~31 evaluations) would take ~0.6 s
        time.sleep(0.02)
        return inner(batch)

    # first-use costs (imports, the first float64 graphs of this worker: 2.6 s once under xdist) paid before
    # the clock starts, on a throwaway model
    spare = small_net(torch.float64)
    lbfgs_polish(spare, mse(spare), regression(torch.float64), regression(torch.float64, seed=1), evals=2)
    t0 = time.perf_counter()
    res = lbfgs_polish(model, slow, regression(torch.float64), regression(torch.float64, seed=1), evals=1000,
                       deadline=t0 + 0.25)
    assert 3 <= res.evals < 20 and time.perf_counter() - t0 < 0.25 + 0.3
