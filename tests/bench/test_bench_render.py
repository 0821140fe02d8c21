"""`neural-bake bench render` in a shrunken form: tiny cached networks, tiny images; the table's structure."""

import json

import numpy as np
import pytest

from neural_bake.bench.render import TARGETS, run
from neural_bake.cli.main import main
from neural_bake.fit.nested import NestedSequence
from neural_bake.types import Frame


@pytest.fixture(scope="module")
def cache(tmp_path_factory, fit_sphere_siren):
    """A cached three-level sequence of small sphere SDFs, named as the quick bench looks for it."""
    d = tmp_path_factory.mktemp("bench_render")
    levels = [fit_sphere_siren(r=0.6, width=8, steps=150), fit_sphere_siren(r=0.6, width=16, steps=200),
              fit_sphere_siren(r=0.6, width=32, steps=300)]
    info = [{"delta": 0.08}, {"delta": 0.05}, {"delta": 0.001}]
    NestedSequence(levels=levels, frame=Frame(), levels_info=info).save(d / "bumpy_sphere-quick-seed0.nested")
    return d


def test_bench_render_table_structure(cache, tmp_path):
    plot = tmp_path / "p.png"
    res = run(quick=True, sizes=(16,), cache_dir=cache, plot=plot, guaranteed_size=8)
    rows = res["tables"]["configurations"]
    configs = [(r["config"], r["iterations"]) for r in rows]
    assert configs == [("coarse only", "40"), ("fine only", "40"), ("fine only", "15"), ("normal mapping", "40,0"),
                       ("normal mapping, auto precision", "40,0"), ("multiscale", "30,10"), ("multiscale", "30,20"), ("multiscale", "30,30"),
                       ("three levels", "30,10,10"), ("straightforward (baseline)", "40")]
    fine40 = rows[1]
    assert fine40["speedup_vs_fine40"] == 1.0
    assert all(np.isfinite(r["mse"]) and r["seconds"] > 0 for r in rows)
    assert rows[-1]["trace_evals"] == 16 * 16 * 41 > max(r["trace_evals"] for r in rows[:-1])
    savings = {r["what"]: r for r in res["tables"]["savings"]}
    assert savings["live-ray compaction"]["evals_off"] > savings["live-ray compaction"]["evals_on"]
    assert savings["empty-space skipping"]["evals_off"] >= savings["empty-space skipping"]["evals_on"]
    g = res["tables"]["guaranteed"]
    assert g[1]["boxes"] > 0 and g[1]["cost_ratio"] > 0
    (check,) = res["tables"]["targets"]
    assert check["ms_30_30_met"] == (check["ms_30_30_mse"] <= TARGETS["ms_30_30_mse_max"])
    assert check["nm_auto_speedup_met"] == (check["nm_auto_speedup"] >= TARGETS["nm_speedup_min"])
    auto = rows[4]
    assert auto["trace_evals"] == rows[3]["trace_evals"]  # the same trace; only f's normals change precision
    assert abs(auto["mse"] - rows[3]["mse"]) < 0.05 * rows[3]["mse"] + 1e-6
    assert any(n.startswith("normal mapping, auto precision: f's normals in ") for n in res["notes"])
    assert plot.is_file() and plot.stat().st_size > 1000
    assert any("read from the cache" in n for n in res["notes"])


def test_bench_render_cli_writes_json(cache, tmp_path, capsys):
    out = tmp_path / "r.json"
    code = main(["bench", "render", "--quick", "--size", "8", "--cache", str(cache), "--plot",
                 str(tmp_path / "p.png"), "--json", str(out)])
    assert code == 0, capsys.readouterr().err
    data = json.loads(out.read_text())
    assert data["name"] == "render" and data["quick"] is True


def test_bench_render_writes_no_file_into_the_working_folder(cache, tmp_path, monkeypatch, capsys):
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    out = tmp_path / "r.json"
    code = main(["bench", "render", "--quick", "--size", "8", "--cache", str(cache), "--json", str(out)])
    assert code == 0, capsys.readouterr().err
    assert list(work.iterdir()) == []
    assert (tmp_path / "r.png").stat().st_size > 1000  # the plot goes beside the JSON
    res = run(quick=True, sizes=(8,), cache_dir=cache, guaranteed_size=8)
    assert list(work.iterdir()) == [] and any(n.startswith("plot: none") for n in res["notes"])
