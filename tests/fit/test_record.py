"""FitRecord: the training table every fit writes and reads back; the fit configs' loop settings."""

import pytest

from neural_bake.fit.record import HISTORY_KEPT, FitRecord
from neural_bake.fit.sdf import SdfFit
from neural_bake.fit.sdf_config import SdfFitConfig
from neural_bake.fit.spacetime import SpaceTimeFit
from neural_bake.fit.spacetime_config import SpaceTimeFitConfig
from neural_bake.fit.texture import TextureFit, TextureFitConfig
from neural_bake.fit.training import LoopConfig
from neural_bake.nets.siren import Siren
from neural_bake.types import Frame


def test_training_table_round_trips_for_every_fit_result():
    history = [{"step": s, "loss": 1.0 / s} for s in range(1, HISTORY_KEPT + 11)]
    for cls in (SdfFit, SpaceTimeFit):
        fit = cls(model=Siren(8, 0, in_dim=4 if cls is SpaceTimeFit else 3), frame=Frame(), history=history,
                  steps=210, seconds=1.23456, stopped_reason="time budget", restarts=2, threads={"threads": 1})
        table = fit.training()
        assert table["final"] == history[-1] and table["history"] == history[-HISTORY_KEPT:]
        assert table["seconds"] == 1.235 and table["threads"] == {"threads": 1}
        back = FitRecord.training_fields(table)
        assert back == {"history": history[-HISTORY_KEPT:], "steps": 210, "seconds": 1.235,
                        "stopped_reason": "time budget", "restarts": 2, "threads": {"threads": 1}}
    assert FitRecord.training_fields(None)["steps"] == 0 and FitRecord.training_fields({"threads": 3})["threads"] is None
    with pytest.raises(ValueError):
        FitRecord.training_fields({"steps": "many"})


def test_a_texture_file_keeps_the_finite_rows_of_its_training_table():
    rows = [{"step": 1, "loss": 0.5}, {"step": 2, "loss": float("nan")}]
    fit = TextureFit(model=Siren(8, 0, 3, 3), frame=Frame(), history=rows, steps=2, seconds=0.5)
    training = fit.metadata()["training"]
    assert training["history"] == rows[:1] and training["final"] == rows[0] and training["steps"] == 2
    assert FitRecord.training_fields(training)["stopped_reason"] == "steps"


def test_every_fit_config_makes_its_loop_config_from_its_own_fields():
    sdf = SdfFitConfig(steps=7, lr=3e-4, lr_min_factor=0.01, seed=5, checkpoint="c.ckpt", resume=True, log_every=3)
    loop = sdf.loop_config("fit sdf")
    assert (loop.steps, loop.lr, loop.lr_min_factor, loop.seed, loop.checkpoint, loop.resume, loop.log_every,
            loop.desc) == (7, 3e-4, 0.01, 5, "c.ckpt", True, 3, "fit sdf")
    tex = TextureFitConfig(max_restarts=1, progress=True).loop_config("fit texture", max_restarts=1)
    assert tex.max_restarts == 1 and tex.progress and tex.steps == 2000
    st = SpaceTimeFitConfig(minutes=2.0).loop_config("fit morph", minutes=1.5)
    assert (st.steps, st.lr, st.minutes, st.checkpoint) == (3000, 2e-4, 1.5, None)
    assert isinstance(st, LoopConfig)
