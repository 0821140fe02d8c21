"""`bench batch --quick`: the verbs one after another against the batch, same settings, same results."""

import pytest

from neural_bake.bench.batch import COLUMNS, run


@pytest.mark.slow
def test_bench_batch_quick_rows():
    result = run(quick=True, workers=(2,))
    rows = {(r["method"], r["workers"]): r for r in result["rows"]}
    verbs, batch, cached = rows[("verbs one after another", 1)], rows[("batch", 2)], rows[("batch, all cached", 2)]
    for r in result["rows"]:
        assert set(r) == set(COLUMNS)
        assert r["ok"] == r["assets"] == 2 and r["seconds"] > 0
        assert r["assets/hour"] == pytest.approx(3600 * 2 / r["seconds"])
    assert verbs["× verbs"] == 1.0
    assert batch["× verbs"] == pytest.approx(batch["assets/hour"] / verbs["assets/hour"])
    assert batch["threads"] == 1  # 2 workers x 1 thread on 2 cores (CI), never more threads than cores
    # the same stages with the same seeds and steps: the same models up to thread-count rounding
    assert batch["normal err median °"] == pytest.approx(verbs["normal err median °"], abs=0.5)
    assert cached["normal err median °"] is None
    assert any("same settings" in n for n in result["notes"])
