"""`bench nested` in its smallest form: distilled and direct-fit rows, their ratios, the stability table, JSON."""

from __future__ import annotations

import json
import math


from neural_bake.cli.main import main
from neural_bake.fit.sdf import SdfFit
from neural_bake.types import Frame


def test_bench_nested_smallest_run(tmp_path, capsys, fit_sphere_siren):
    model = SdfFit(model=fit_sphere_siren(0.8, width=16, steps=150), frame=Frame()).save(tmp_path / "fine.sdf")
    out = tmp_path / "nested.json"
    code = main(["bench", "nested", "--quick", "--model", str(model), "--mesh", "sphere", "--levels", "8x0",
                 "--steps", "30", "--json", str(out)])
    assert code == 0, capsys.readouterr().err
    text = capsys.readouterr().out
    assert "Nested sequences" in text and "direct fit (baseline)" in text
    res = json.loads(out.read_text())
    rows = res["tables"]["levels"]
    assert [r["method"] for r in rows] == ["distilled", "direct fit (baseline)"]
    distilled, direct = rows
    assert all(r["level"] == "8x0" and r["mesh"] == "sphere" and r["seconds"] > 0 for r in rows)
    assert direct["sup_estimated"] > 0 and direct["delta"] is None and direct["steps"] >= 1
    assert distilled["sup_estimated"] > 0 and distilled["delta"] >= distilled["sup_estimated"]
    assert math.isclose(distilled["sup_vs_direct"], distilled["sup_estimated"] / direct["sup_estimated"],
                        rel_tol=1e-9)
    assert distilled["sup_certified"] >= distilled["sup_estimated"]
    assert distilled["certify_s"] > 0 and distilled["estimate_s"] > 0
    assert math.isclose(distilled["certified_over_estimated"],
                        distilled["sup_certified"] / distilled["sup_estimated"], rel_tol=1e-9)
    stab = res["tables"]["estimate stability (distilled)"]
    assert {(r["samples"], r["band"]) for r in stab} >= {(1000, 0.1), (10000, 0.1)}
    assert any("loaded from" in n for n in res["notes"])


def test_bench_nested_bad_model_is_one_line(tmp_path, capsys):
    assert main(["bench", "nested", "--quick", "--model", str(tmp_path / "none.sdf")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none.sdf" in err[0]
