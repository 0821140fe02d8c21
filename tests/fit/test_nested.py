"""fit_nested: δ by Prop. 1 (estimated and certified), keep-best, NestedSequence files, CLI."""

import warnings

import pytest
import torch

from neural_bake.cli.main import main
from neural_bake.errors import FitError, ModelFileError, NeuralBakeWarning
from neural_bake.fit.nested import (NestedSequence, band_samples, certify_sup_norm, estimate_sup_norm, fit_nested,
                                    parse_levels)
from neural_bake.fit.sdf import SdfFit
from neural_bake.nets.siren import Siren
from neural_bake.types import Frame

SMALL = dict(steps=120, pool=8000, batch=1024, eval_every=40, eval_samples=2000, n_estimate=5000,
             stability_samples=(500, 2000), stability_bands=(0.1, 0.2), max_boxes=3000, progress=False)


@pytest.fixture(scope="module")
def fine(fit_sphere_siren):
    return fit_sphere_siren()


@pytest.fixture(scope="module")
def seq(fine):
    frame = Frame((1.0, 2.0, 3.0), 0.5)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        s = fit_nested(SdfFit(model=fine, frame=frame), levels=[(8, 0), (16, 1)], warn_ratio=1.0, **SMALL)
    s.metadata["warnings"] = [str(w.message) for w in rec if issubclass(w.category, NeuralBakeWarning)]
    return s


def test_structure(seq, fine):
    assert len(seq.levels) == 3 and seq.levels[-1] is fine
    assert [(m.width, m.depth) for m in seq.levels] == [(8, 0), (16, 1), (32, 1)]
    assert seq.frame == Frame((1.0, 2.0, 3.0), 0.5)
    assert seq.iterations == [120, 120, 0]
    assert all(info["best_step"] in (40, 80, 120) for info in seq.levels_info[:2])
    assert [len(rows) for rows in seq.stability] == [4, 4]


def test_deltas_follow_prop1(seq):
    info = seq.levels_info
    assert info[2]["delta_estimated"] == seq.eps
    for i in (1, 0):
        assert info[i]["delta_estimated"] == pytest.approx(info[i]["sup_estimated"] + info[i + 1]["delta_estimated"])
        assert info[i]["delta_certified"] == pytest.approx(info[i]["sup_certified"] + info[i + 1]["delta_certified"])
    used = seq.eps
    for i in (1, 0):  # δ to render with: certified sup where certification met its target, else the estimate
        tight = info[i]["certify"]["complete"]
        used += info[i]["sup_certified"] if tight else info[i]["sup_estimated"]
        assert info[i]["delta_source"] == ("certified" if tight else "estimated")
        assert seq.deltas[i] == pytest.approx(used)
    assert seq.deltas[2] == seq.eps
    assert all(c >= e for c, e in zip(seq.deltas_certified, seq.deltas_estimated))
    assert seq.deltas[0] > seq.deltas[1] > seq.deltas[2] > 0


def test_certified_bounds_every_sample_and_estimate_bounds_its_own(seq):
    for i in range(2):
        h, g = seq.levels[i], seq.levels[i + 1]
        info = seq.levels_info[i]
        assert info["sup_certified"] >= info["sup_estimated"] > 0
        # the estimate is the max over its own samples: a prefix of them gives no more
        assert estimate_sup_norm(h, g, band=seq.band, n=1000, seed=17 * i) <= info["sup_estimated"]
        # the certified bound holds for any point of the band (fresh, denser samples)
        x = band_samples([h, g], 40_000, seq.band, seed=999 + i)
        with torch.no_grad():
            sampled = float((h(x) - g(x)).abs().max())
        assert sampled <= info["sup_certified"]


def test_warns_when_certified_exceeds_estimate(seq):
    assert any("certified |h - g| bound" in w for w in seq.metadata["warnings"])


def test_save_load_round_trip(seq, tmp_path):
    path = seq.save(tmp_path / "sphere.nested")
    back = NestedSequence.load(path)
    assert back.frame == seq.frame and back.band == seq.band and back.eps == seq.eps
    assert back.deltas == seq.deltas and back.iterations == seq.iterations
    assert back.stability == seq.stability
    # each level keeps its loss history (the curve a report draws): steps up to the level's last, time rising
    for info, kept in zip(seq.levels_info[:2], back.levels_info[:2]):
        assert kept["history"] == info["history"] and info["history"][-1]["step"] == 120
        assert all(a["seconds"] <= b["seconds"] for a, b in zip(info["history"], info["history"][1:]))
    x = torch.rand(64, 3) * 2 - 1
    with torch.no_grad():
        for a, b in zip(back.levels, seq.levels):
            assert torch.equal(a(x), b(x))


def test_load_errors(seq, tmp_path, fine):
    with pytest.raises(ModelFileError, match=r"none\.nested: no such model file"):
        NestedSequence.load(tmp_path / "none.nested")
    bad = tmp_path / "bad.nested"
    bad.write_bytes(b"\x00" * 40)
    with pytest.raises(ModelFileError, match=r"bad\.nested: not a readable model file"):
        NestedSequence.load(bad)
    sdf = SdfFit(model=fine, frame=Frame()).save(tmp_path / "f.sdf")
    with pytest.raises(ModelFileError, match=r"f\.sdf: not a nested-sequence file \(a SdfField\)"):
        NestedSequence.load(sdf)
    good = seq.save(tmp_path / "good.nested")
    data = good.read_bytes()
    (tmp_path / "cut.nested").write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelFileError, match=r"cut\.nested: (not a readable|corrupt or truncated) model file"):
        NestedSequence.load(tmp_path / "cut.nested")


def test_certify_refines_within_its_budget(fine):
    # h = g: the true sup is 0; affine arithmetic gives each network its own non-linear noise symbols, so the
    # bound is not 0 but must shrink as the box budget grows, and the budget is respected
    small = certify_sup_norm(fine, fine, band=0.1, estimate=0.0, max_boxes=600)
    large = certify_sup_norm(fine, fine, band=0.1, estimate=0.0, max_boxes=2400)
    assert small["boxes_bounded"] <= 600 and large["boxes_bounded"] <= 2400
    assert 0 <= large["sup_certified"] <= small["sup_certified"]
    assert not small["complete"] and small["target"] == 1e-9
    easy = certify_sup_norm(fine, fine, band=0.1, estimate=10.0, max_boxes=600)  # target above any bound
    assert easy["complete"] and easy["boxes_bounded"] == 8 ** 3  # the initial grid only, nothing split


def test_parse_levels():
    assert parse_levels("64x1, 256X1") == [(64, 1), (256, 1)]
    for bad in ("64", "64x", "ax1", "0x1", ""):
        with pytest.raises(FitError, match="is not WIDTHxDEPTH"):
            parse_levels(bad)


@pytest.mark.parametrize("kw, msg", [
    ({"levels": [(0, 1)]}, "is not \\(width >= 1, depth >= 0\\)"), ({"levels": []}, "at least one coarse level"),
    ({"band": 0.0}, "band must be positive"), ({"steps": 0}, "steps must be a positive integer"),
    ({"eps": -1.0}, "eps must be non-negative"),
])
def test_bad_arguments(fine, kw, msg):
    with pytest.raises(FitError, match=msg):
        fit_nested(fine, **{"levels": [(8, 0)], **kw})
    with pytest.raises(FitError, match="must be a Siren, a TiledSdf or an SdfFit"):
        fit_nested("model.sdf")


def test_no_surface_in_the_cube():
    far = Siren(8, 0)
    with torch.no_grad():
        for p in far.parameters():
            p.zero_()
        far.layers[-1].bias.fill_(5.0)
    with pytest.raises(FitError, match="fine model has no point of"):
        fit_nested(far, levels=[(8, 0)], steps=2, pool=100, batch=16, eval_samples=10, n_estimate=100, progress=False,
                   certify=False, stability_samples=())


def test_cli_fit_nested(tmp_path, capsys, fine):
    model = SdfFit(model=fine, frame=Frame()).save(tmp_path / "f.sdf")
    out = tmp_path / "f.nested"
    code = main(["fit", "nested", str(model), "-o", str(out), "--levels", "8x0", "--steps", "20",
                 "--max-boxes", "400", "--no-progress"])
    assert code == 0, capsys.readouterr().err
    assert "wrote" in capsys.readouterr().out
    back = NestedSequence.load(out)
    assert len(back.levels) == 2 and back.iterations == [20, 0]
    assert main(["fit", "nested", str(model), "-o", str(out), "--levels", "8by0"]) == 2
    assert "is not WIDTHxDEPTH" in capsys.readouterr().err
    assert main(["fit", "nested", str(tmp_path / "none.sdf"), "-o", str(out)]) == 2
