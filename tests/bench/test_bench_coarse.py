"""The coarse-mesh benchmark in its smallest configuration: a tiny SIREN, a few steps, small grids."""

import math

import pytest

from neural_bake.bench.coarse import COLUMNS, run
from neural_bake.errors import NeuralBakeError

SMALL_FIT = dict(pool_surface=4000, pool_near=4000, pool_uniform=1000, batch=512, batch_near=512,
                 batch_uniform=128)


def test_shrunken_run():
    res = run(quick=True, network="16x1", minutes=None, steps=30, fit_overrides=SMALL_FIT, faces=[300],
              resolutions=[16, 48], samples=2000, scans=[])
    assert res["name"] == "coarse" and res["quick"] is True and "cores" in res["machine"]
    rows = res["tables"]["coarse meshes"]
    assert all(set(r) <= set(COLUMNS) for r in rows)
    assert [(r["method"], r["setting"]) for r in rows] == [
        ("decimate", "300 faces"),
        ("march dense", "16³"), ("march pruned", "16³"), ("march auto", "16³"),
        ("march dense", "48³"), ("march pruned", "48³"), ("march auto", "48³"),
    ]
    dec = rows[0]
    assert dec["mesh"] == "bumpy_sphere" and abs(dec["faces"] - 300) <= 10 and dec["seconds"] > 0
    assert 0 < dec["chamfer-L1"] <= dec["hausdorff"] < 0.1  # 300 faces of a radius-0.9 bumpy sphere
    by = {(r["method"], r["setting"]): r for r in rows}
    for res_ in (16, 48):
        dense = by[("march dense", f"{res_}³")]
        assert dense["evaluations"] == (res_ + 1) ** 3 and dense["fewer evals ×"] == 1.0
        assert dense["time ÷ dense"] == 1.0 and dense["levels bounded"] == 0
        for mode in ("pruned", "auto"):
            r = by[(f"march {mode}", f"{res_}³")]
            # same triangles (then cleaned the same way): same faces and errors as the dense run
            assert r["faces"] == dense["faces"] > 0
            assert r["chamfer-L1"] == dense["chamfer-L1"] and r["hausdorff"] == dense["hausdorff"]
            assert r["evaluations"] <= dense["evaluations"]
            assert r["fewer evals ×"] == pytest.approx(dense["evaluations"] / r["evaluations"])
            assert math.isfinite(r["time ÷ dense"]) and r["time ÷ dense"] > 0
    assert by[("march pruned", "16³")]["levels bounded"] >= 1
    assert "grid too small" in by[("march auto", "16³")]["note"]
    assert any("trained a (16, 1) SIREN" in n for n in res["notes"])
    assert {(e["method"], e["setting"]) for e in res["levels"]} >= {("march pruned", "16³"), ("march auto", "48³")}


def test_a_large_mesh_decimated_beside_pymeshlab_alone(tmp_path):
    import trimesh

    path = tmp_path / "big.obj"
    trimesh.creation.icosphere(6).export(path)  # 81,920 faces: the first pass runs
    res = run(quick=True, faces=[300], resolutions=[], samples=2000, scans=[str(path), str(tmp_path / "no.obj")],
              sdf_model=None, network="16x1", steps=5, fit_overrides=SMALL_FIT)
    big = [r for r in res["tables"]["coarse meshes"] if r["mesh"] == "big"]
    assert [r["method"] for r in big] == ["decimate pymeshlab alone", "decimate"]
    alone, first = big
    assert alone["setting"] == first["setting"] == "2000 faces"  # the quick run's one count
    assert abs(first["faces"] - 2000) <= 4 and first["watertight"] and alone["watertight"]
    assert first["÷ pymeshlab alone"] == pytest.approx(first["seconds"] / alone["seconds"])
    assert "first pass to 16000 faces" in first["note"]
    assert first["hausdorff"] < 0.05 and alone["hausdorff"] < 0.05
    assert any("no.obj" in n and "not found" in n for n in res["notes"])


def test_errors():
    with pytest.raises(NeuralBakeError, match="network must be WxD"):
        run(quick=True, network="big")
    with pytest.raises(NeuralBakeError, match="unknown marching mode"):
        run(quick=True, modes=("dense", "fast"))


def test_cli_verb_is_registered(capsys):
    from neural_bake.cli.main import main

    assert main(["bench", "coarse", "--help"]) == 0
    out = capsys.readouterr().out
    assert "--quick" in out and "--json" in out and "--sdf-model" in out
