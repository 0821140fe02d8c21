"""The normals benchmark's parts: exact cost counts, the roofline, and a shrunken run."""

import math

import pytest
import torch

from neural_bake.bench.normals import run
from neural_bake.bench.roofline import best_rates, measure_roofline, roofline_seconds, siren_cost


def test_siren_cost_counts():
    # (W, D) = (4, 1), in 3, out 1, n = 10: GEMMs 2·10·(3·4 + 4·4 + 4·1) = 640, biases 10·(2·4 + 1) = 90
    c = siren_cost(4, 1, 10)
    assert c == {"flops": 730.0, "sines": 80.0, "gemm_flops": 640.0}
    r = siren_cost(4, 1, 10, "reverse")  # + back GEMMs 2·10·(16 + 12) = 560, products 10·2·4 = 80
    assert r == {"flops": 730.0 + 560 + 80, "sines": 160.0, "gemm_flops": 1200.0}
    f = siren_cost(4, 1, 10, "forward")  # + 3 streams: 2·10·3·(16 + 4) = 1200, products 10·3·2·4 = 240
    assert f == {"flops": 730.0 + 1200 + 240, "sines": 160.0, "gemm_flops": 1840.0}
    assert siren_cost(4, 1, 10, "fd")["flops"] == 7 * 730.0
    with pytest.raises(ValueError, match="siren_cost: grad must be None, 'reverse', 'forward' or 'fd', got 'x'"):
        siren_cost(4, 1, 10, "x")


def test_roofline_seconds_and_measurement():
    roof = {"gflops_sgemm": 2.0, "gsin_per_s": 1.0, "gmul_per_s": 0.5}
    cost = {"flops": 3e9, "gemm_flops": 2e9, "sines": 1e9}
    assert roofline_seconds(cost, roof) == pytest.approx(1.0 + 1.0 + 2.0)
    m = measure_roofline(quick=True, repeat=1)
    for key in ("gflops_sgemm", "gsin_per_s", "gcos_per_s", "gmul_per_s"):
        assert math.isfinite(m[key]) and m[key] > 0
    assert m["gflops_sgemm"] == max(m["gflops_square"], m["gflops_siren_shape"])
    assert m["threads"] == torch.get_num_threads()


def test_shrunken_run():
    res = run(quick=True, repeat=1, networks=[(8, 1)], points=[256], sweep=False)
    assert res["name"] == "normals" and res["quick"] is True
    rows = res["tables"]["gradients"]
    assert [r["method"] for r in rows] == ["autograd", "torch.func", "central FD", "gemm forward",
                                           "gemm reverse", "forward pass"]
    by = {r["method"]: r for r in rows}
    assert by["autograd"]["speed-up"] == 1.0 and by["forward pass"]["÷ fwd"] == 1.0
    for name in ("autograd", "torch.func", "gemm forward", "gemm reverse"):
        assert by[name]["max angle°"] < 0.05  # float32 against float64
    assert by["central FD"]["max angle°"] < 5.0
    assert all(r["seconds"] > 0 and math.isfinite(r["roofline"]) and "_cost" not in r and "_roof" not in r
               for r in rows)
    # one roofline probe per group, read in its rounds, never above the run's overall peak
    assert len({r["sgemm GF/s"] for r in rows}) == 1
    assert rows[0]["sgemm GF/s"] <= res["roofline"]["gflops_sgemm"]
    for name in ("before", "after"):
        assert res[f"roofline_{name}"]["gflops_sgemm"] <= res["roofline"]["gflops_sgemm"]
    # the stricter reading prices the forward pass at the run's best rates: never a larger fraction
    t = res["targets"]
    assert t["forward_roofline_fraction_worst_w256_run_peak"] <= t["forward_roofline_fraction_worst_w256"] + 1e-12
    assert t["forward_roofline_fraction_worst_w256"] == pytest.approx(by["forward pass"]["roofline"])
    # the residual network by block against its merged matrices: the same normals
    blocks = res["tables"]["residual networks"]
    assert [r["path"] for r in blocks] == ["gemm reverse", "forward pass"]
    for r in blocks:
        assert r["points"] == 256 and r["merged s"] > 0 and r["by block s"] > 0
        assert r["by block ÷ merged"] == pytest.approx(r["by block s"] / r["merged s"])
    assert blocks[0]["max angle °"] < 0.05  # float32 rounding in another order


def test_best_rates_take_the_best_reading_of_each_rate():
    a = {"gflops_sgemm": 100.0, "gsin_per_s": 1.2, "threads": 2, "dtype": "float32"}
    b = {"gflops_sgemm": 150.0, "gsin_per_s": 0.9, "threads": 2, "dtype": "float32"}
    assert best_rates([a, b]) == {"gflops_sgemm": 150.0, "gsin_per_s": 1.2, "threads": 2, "dtype": "float32"}


def test_cli_verb_is_registered(capsys):
    from neural_bake.cli.main import main

    assert main(["bench", "normals", "--help"]) == 0
    out = capsys.readouterr().out
    assert "--quick" in out and "--json" in out and "GEMM normals" in out


def test_load_note_states_the_load():
    from neural_bake.bench.common import load_note

    note = load_note()
    assert note.startswith("timings: best of repeats") and "cores" in note
    assert note.endswith("quiet") or "upper bounds" in note


def test_best_rates_skip_rates_a_reading_did_not_measure():
    a = {"gsin_kernel_per_s": float("nan"), "gsin_per_s": 1.0}
    b = {"gsin_kernel_per_s": 2.0, "gsin_per_s": 1.5}
    assert best_rates([a, b]) == {"gsin_kernel_per_s": 2.0, "gsin_per_s": 1.5}
    assert math.isnan(best_rates([a])["gsin_kernel_per_s"])


def test_roofline_sine_rate_is_the_faster_of_torch_and_the_kernel():
    m = measure_roofline(quick=True, repeat=1)
    rates = [m["gsin_torch_per_s"]] + ([m["gsin_kernel_per_s"]] if m["gsin_kernel_per_s"] == m["gsin_kernel_per_s"] else [])
    assert m["gsin_per_s"] == max(rates)
