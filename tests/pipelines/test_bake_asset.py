"""The bake pipeline's own steps (its end-to-end runs are in tests/test_cli_bake.py)."""

import threading

import pytest

from neural_bake.pipelines.bake_asset import _beside


def test_beside_returns_both_results_and_runs_the_first_in_another_thread():
    here = threading.get_ident()
    first, second = _beside(lambda: threading.get_ident(), lambda: threading.get_ident())
    assert second == here and first != here


def test_an_error_of_the_second_waits_for_the_first_to_finish():
    started, failing, finished = threading.Event(), threading.Event(), []

    def first():
        started.set()
        failing.wait()  # still writing when the second fails
        finished.append(True)

    def second():
        started.wait()
        failing.set()
        raise ValueError("report failed")

    with pytest.raises(ValueError, match="report failed"):
        _beside(first, second)
    assert finished == [True]  # nothing is left writing into the stage folder when the error propagates


def test_an_error_of_the_first_is_raised_after_the_second_finishes():
    done = []

    def first():
        raise OSError(28, "No space left on device", "out/normal.png")

    with pytest.raises(OSError, match="No space left on device"):
        _beside(first, lambda: done.append(True))
    assert done == [True]
