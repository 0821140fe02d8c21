"""bench contention: the competitor is a real process started with setsid, the table's ratios and targets come
from the measured figures, and a shrunken run measures the real fit command quiet and busy."""

import os

import pytest

from neural_bake.bench.contention import competitor, rows_from, run
from neural_bake.errors import NeuralBakeError


def test_competitor_runs_detached_with_setsid_and_is_killed():
    with competitor() as pid:
        assert pid is not None and os.getsid(pid) == pid != os.getsid(0)  # setsid: its own process group, apart from ours
        with open(f"/proc/{pid}/stat") as fh:
            assert fh.read().split()[2] in "RS"  # running (or just preempted)
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
    with competitor(busy=False) as none:
        assert none is None


def test_rows_ratios_and_targets():
    measured = {"fit": {"default": {"quiet": 400, "busy": 52}, "measured": {"quiet": 396, "busy": 190}},
                "bake": {"default": {"quiet": 10.0, "busy": 60.0}, "measured": {"quiet": 10.2, "busy": 23.0}}}
    rows = {(r["command"], r["threads"]): r for r in rows_from(measured)}
    fit = rows[("fit", "measured")]
    assert fit["busy ÷ quiet"] == pytest.approx(190 / 396) and fit["met"] is True and fit["target"] == ">= 0.45"
    assert fit["idle ÷ default"] == pytest.approx(400 / 396)  # steps lost idle
    assert rows[("fit", "default")]["met"] is None  # targets are the measured setting's
    bake = rows[("bake", "measured")]
    assert bake["busy ÷ quiet"] == pytest.approx(23.0 / 10.2) and bake["met"] is False
    assert bake["idle ÷ default"] == pytest.approx(1.02)


def test_unknown_workload_is_refused():
    with pytest.raises(NeuralBakeError, match="workload"):
        run(workloads=("nosuch",))


@pytest.mark.slow
def test_shrunken_fit_run_measures_steps_quiet_and_busy(tmp_path):
    """The real fit command, quiet and beside the competitor, with both thread settings: four real runs
    whose step counts fill the table (no timing is asserted)."""
    from neural_bake.samples.generate import write_sample
    from neural_bake.samples.shapes import get_sample

    mesh = write_sample(get_sample("bumpy_sphere").mesh(resolution=200, texture_size=16), tmp_path, "bumpy_sphere")
    small = ("--width", "32", "--coarse-width", "8", "--depth", "1", "--batch", "256", "--batch-near", "256", "--batch-uniform", "64",
             "--pool-surface", "2000", "--pool-near", "2000", "--pool-uniform", "500")
    res = run(quick=True, workloads=("fit",), fit_seconds=2.0, mesh=mesh, fit_args=small)
    rows = [r for r in res["rows"] if r["command"] == "fit"]
    assert [r["threads"] for r in rows] == ["default", "measured"]
    for r in rows:
        assert r["quiet"] > 0 and r["busy"] > 0 and r["busy ÷ quiet"] == pytest.approx(r["busy"] / r["quiet"])
    assert rows[1]["met"] in (True, False) and res["measured"]["fit"]["measured"]["busy"] == rows[1]["busy"]
