"""Thread counts chosen by measurement: a simulated clock whose step cost depends on the threads in force and on
a neighbour's load, so every decision is tested without a wall-clock assertion."""

import pytest
import torch

from neural_bake.constants import THREAD_DECISIVE
from neural_bake.errors import NeuralBakeError
from neural_bake.nets.threads import (ENV_MAX_THREADS, ThreadTuner, choose_threads, fixed_threads,
                                      thread_candidates)

QUIET = {1: 2.0, 2: 1.05}  # seconds per step: two threads nearly twice as fast on an idle machine
BUSY = {1: 2.1, 2: 8.0}  # one core taken by another program: the second thread waits on it


class Machine:
    """A clock that advances by the cost of the work done with the threads torch has now."""

    def __init__(self):
        self.now = 0.0
        self.costs = QUIET
        self.calls = 0

    def clock(self) -> float:
        return self.now

    def work(self) -> None:
        self.calls += 1
        self.now += self.costs[torch.get_num_threads()]


@pytest.fixture(autouse=True)
def keep_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


@pytest.mark.parametrize("costs, expected", [(QUIET, 2), (BUSY, 1), ({1: 1.0, 2: 1.08}, 2), ({1: 1.0, 2: 1.12}, 1)])
def test_choose_threads_keeps_the_fastest(costs, expected):
    """The fastest count wins; a larger count within 10 % of the fastest is kept (a short probe's noise must
    not take threads from a quiet machine)."""
    m = Machine()
    m.costs = costs
    choice = choose_threads(m.work, candidates=(2, 1), clock=m.clock, env="auto")
    assert choice.threads == expected == torch.get_num_threads()
    assert choice.how == "measured" and set(choice.seconds) == {1, 2}
    assert choice.seconds[1] == pytest.approx(costs[1]) and choice.seconds[2] == pytest.approx(costs[2])
    decisive = max(costs.values()) >= THREAD_DECISIVE * min(costs.values())
    assert m.calls == (2 * 2 if decisive else 2 * 3)  # a warm-up and one timed call per count; a second round
    # only when the first did not decide
    assert f"{expected} thread" in choice.reason and choice.as_dict()["threads"] == expected


def test_an_undecided_first_round_is_timed_again_and_the_best_of_each_count_kept():
    """Noise in the first timed round (two threads slowed once, 1.25× the one thread's time) does not decide:
    a second round runs, and each count keeps its best time, so two threads win."""
    m = Machine()
    slow_once = {"left": 1}

    def work():
        m.work()
        if torch.get_num_threads() == 2 and m.calls == 4 and slow_once["left"]:  # count 2's first timed call
            slow_once["left"] = 0
            m.now += 1.5
    m.costs = {1: 2.0, 2: 1.0}
    choice = choose_threads(work, candidates=(1, 2), clock=m.clock, env="auto")
    assert m.calls == 6 and choice.threads == 2
    assert choice.seconds == {1: pytest.approx(2.0), 2: pytest.approx(1.0)}


def test_a_fixed_count_times_nothing():
    m = Machine()
    choice = choose_threads(m.work, candidates=(2, 1), clock=m.clock, env="1")
    assert (choice.threads, choice.how, m.calls, torch.get_num_threads()) == (1, "fixed", 0, 1)


def test_work_off_the_cpu_leaves_the_threads_alone():
    torch.set_num_threads(2)
    m = Machine()
    choice = choose_threads(m.work, device="meta", clock=m.clock, env="auto")
    assert (choice.how, m.calls, torch.get_num_threads()) == ("device", 0, 2)


@pytest.mark.parametrize("value", ["0", "-1", "two", "1.5", "5000"])
def test_bad_fixed_counts_are_one_line_naming_the_variable(value):
    with pytest.raises(NeuralBakeError, match="NEURAL_BAKE_THREADS"):
        fixed_threads(value)


def test_fixed_count_values():
    assert fixed_threads("") is None and fixed_threads("auto") is None and fixed_threads(" 3 ") == 3


def test_candidates_and_their_cap(monkeypatch):
    assert thread_candidates(1) == (1,)
    assert thread_candidates(4) == (4, 3, 2, 1)
    big = thread_candidates(64)
    assert big[0] == 64 and 1 in big and len(big) <= 8
    monkeypatch.setenv(ENV_MAX_THREADS, "1")
    assert thread_candidates() == (1,)


def run(tuner: ThreadTuner, m: Machine, steps: int) -> None:
    for _ in range(steps):
        tuner.before_step()
        t0 = m.clock()
        m.work()
        tuner.after_step(m.clock() - t0)


def test_tuner_follows_a_neighbour_that_starts_and_stops():
    """Quiet: two threads. A program starts beside the loop: the step time drifts, a probe picks one thread.
    It stops: one thread does not slow down, so the periodic probe finds two threads faster again, after a
    wait that keeps the probes' cost a small share of the time."""
    m = Machine()
    tuner = ThreadTuner(candidates=(2, 1), clock=m.clock, env="auto", trial_steps=3, window=10, drift=1.5,
                        interval=5.0, reprobe=60.0, warmup=0)
    run(tuner, m, 8)  # the first probe: 4 steps per count (one warm-up)
    assert tuner.threads == 2 and len(tuner.history) == 1
    assert tuner.history[0]["seconds_per_step"] == pytest.approx({"2": QUIET[2], "1": QUIET[1]})
    run(tuner, m, 30)
    assert tuner.threads == 2 and len(tuner.history) == 1  # steady: no probe
    m.costs = BUSY
    run(tuner, m, 30)
    assert tuner.threads == 1 and len(tuner.history) == 2 and "step time" in tuner.history[1]["reason"]
    m.costs = QUIET
    run(tuner, m, 10)
    assert tuner.threads == 1  # one thread's step time does not show the neighbour left
    # the probe that chose one thread cost ~24 s more than its steps at one thread: the periodic probe waits
    # until that is under 5 % of the time (~480 s), not the 60 s it would wait after a cheap probe
    run(tuner, m, 150)
    assert tuner.threads == 1 and len(tuner.history) == 2
    run(tuner, m, 100)
    assert tuner.threads == 2 and len(tuner.history) == 3 and "threads" in tuner.history[2]["reason"]
    s = tuner.summary()
    assert s["threads_used"] == [1, 2] and s["how"] == "measured" and len(s["decisions"]) == 3


def test_tuner_probes_no_more_often_than_its_interval():
    """A step time that keeps drifting starts a probe at most once per ``interval`` seconds."""
    m = Machine()
    tuner = ThreadTuner(candidates=(2, 1), clock=m.clock, env="auto", trial_steps=1, window=2, drift=1.2,
                        interval=1000.0, reprobe=1e9, warmup=0)
    run(tuner, m, 4)
    for k in range(50):
        m.costs = BUSY if k % 2 else QUIET
        run(tuner, m, 3)
    assert m.now < 1000.0 * 2 and len(tuner.history) <= 1 + int(m.now // 1000.0)


def test_first_steps_run_on_every_thread_untimed():
    """A loop's first steps (pools, compiles: one-time costs) run on all threads and are not taken as trials;
    the first probe follows them."""
    m = Machine()
    torch.set_num_threads(1)
    tuner = ThreadTuner(candidates=(2, 1), clock=m.clock, env="auto", trial_steps=2, warmup=5)
    assert tuner.threads == 2 == torch.get_num_threads()
    m.costs = {1: 2.0, 2: 50.0}  # the one-time costs: the first steps look slow with any count
    run(tuner, m, 5)
    assert tuner.history == []  # nothing decided from them
    m.costs = QUIET
    run(tuner, m, 6)  # the probe: 3 steps per count
    assert tuner.threads == 2 and tuner.history[0]["step"] == 11 and tuner.history[0]["reason"] == "start"


def test_fixed_tuner_never_probes():
    m = Machine()
    tuner = ThreadTuner(candidates=(2, 1), clock=m.clock, env="1")
    m.costs = BUSY
    run(tuner, m, 50)
    assert torch.get_num_threads() == 1 and tuner.summary()["how"] == "fixed" and len(tuner.history) == 1


@pytest.mark.parametrize("kwargs, name", [({"trial_steps": 0}, "trial_steps"), ({"drift": 1.0}, "drift")])
def test_bad_tuner_settings_raise(kwargs, name):
    with pytest.raises(NeuralBakeError, match=name):
        ThreadTuner(env="auto", **kwargs)


def test_training_loop_runs_on_the_measured_count(monkeypatch):
    """The training loop's steps are the probe's trials: on a machine where two threads are slower (a busy
    neighbour), the fit runs on one, and its result says which counts ran."""
    from neural_bake.fit.training import LoopConfig, train

    monkeypatch.setenv("NEURAL_BAKE_THREADS", "auto")
    monkeypatch.setattr("neural_bake.nets.threads.usable_cores", lambda: 2)
    m = Machine()
    m.costs = BUSY
    model = torch.nn.Linear(3, 1)
    x = torch.randn(64, 3)

    def step_fn(step, gen):
        m.work()
        loss = (model(x) ** 2).mean()
        return {"loss": loss}

    res = train(model, step_fn, LoopConfig(steps=30, lr=1e-3, progress=False), clock=m.clock)
    assert res.steps == 30
    assert res.threads["threads"] == 1 and res.threads["threads_used"] == [1, 2]
    assert res.threads["decisions"][0]["seconds_per_step"]["1"] == pytest.approx(BUSY[1])


def test_initial_probe_sets_the_first_steps_count_and_a_failing_one_is_skipped():
    """The quick probe of a slice of the loop's work picks the count of the untimed first steps; a slice that
    cannot run leaves them on every candidate thread."""
    m = Machine()
    m.costs = BUSY
    tuner = ThreadTuner(candidates=(2, 1), clock=m.clock, env="auto", warmup=3, initial=m.work)
    assert tuner.initial is not None and tuner.threads in (1, 2)  # timed in real seconds: either may win

    def broken():
        raise RuntimeError("mat1 and mat2 shapes cannot be multiplied")

    tuner = ThreadTuner(candidates=(2, 1), clock=m.clock, env="auto", warmup=3, initial=broken)
    assert tuner.initial is None and tuner.threads == 2 == torch.get_num_threads()
    assert tuner.summary()["initial"] is None


def test_the_probe_waits_for_the_heap_reserve(monkeypatch):
    """Pages being faulted in on another core would look like a busy neighbour: the probe joins that thread
    before it times anything."""
    from neural_bake.nets import heap

    order = []

    class Reserve:
        def join(self, timeout=None):
            order.append("joined")

    monkeypatch.setitem(heap._state, "thread", Reserve())
    choose_threads(lambda: order.append("work"), candidates=(1, 2), clock=iter(range(100)).__next__, env="auto")
    assert order[0] == "joined" and order.count("joined") == 1 and "work" in order
