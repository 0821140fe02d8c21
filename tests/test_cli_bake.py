"""`neural-bake bake`: end to end on a small generated sphere with a tiny model; outputs, atomicity, errors."""

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from neural_bake.mesh.coarse import coarse_mesh, parse_coarse
from neural_bake.bake.export import read_glb
from neural_bake.cli.main import main
from neural_bake.errors import NeuralBakeError
from neural_bake.io.images import read_image
from neural_bake.io.mesh_io import load_mesh
from neural_bake.fields import save_model
from neural_bake.nets.siren import Siren
from neural_bake.samples.shapes import get_sample


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A small sphere OBJ (the 'sphere' sample, low resolution) and tiny untrained SDF/texture models."""
    d = tmp_path_factory.mktemp("bake_cli")
    from neural_bake.samples.generate import write_sample

    sample = get_sample("sphere")
    obj = write_sample(sample.mesh(resolution=400, texture_size=64), d, "sphere")
    mesh = load_mesh(obj)
    gen = torch.Generator().manual_seed(0)
    sdf = save_model(Siren(16, 1, generator=gen), d / "s.sdf", kind="sdf", frame=mesh.frame.to_dict())
    tex = save_model(Siren(16, 1, out_dim=3, generator=gen), d / "t.tex", kind="texture", frame=mesh.frame.to_dict())
    return {"obj": str(obj), "sdf": str(sdf), "tex": str(tex), "dir": d}


def run(args, capsys):
    # --force: the fixture's SDF is an untrained network, not the sphere's (tests/bake/test_agreement.py checks
    # that a bake refuses it without)
    code = main(["bake", *args, "--force"])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_bake_writes_asset_maps_and_report(files, tmp_path, capsys):
    out = tmp_path / "out"
    code, stdout, err = run([files["obj"], "--sdf", files["sdf"], "--texture-model", files["tex"],
                             "--coarse", "decimate:200", "--size", "64", "--maps", "normal,albedo,vertex",
                             "--bits", "16", "--exr", "-o", str(out)], capsys)
    assert code == 0, err
    names = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    assert names == sorted(["asset.glb", "normal.png", "normal.exr", "albedo.png", "albedo.exr", "vertex.glb", "vertex.ply",
                            "report.json", "error_normal.png", "error_baseline.png", "miss.png", "hybrid.png",
                            "hybrid_color.png"])
    rep = json.loads((out / "report.json").read_text())
    # an untrained texture network is far from the sample's texture: its colours take the source's, and the
    # map is then closer to the texture than the network alone
    assert rep["hybrid"]["hybrid_color_fraction"] > 0.5
    assert rep["color_psnr_db"] > rep["neural_color_psnr_db"] + 10
    mask = read_image(out / "hybrid_color.png", colour="data")[..., 0] > 0.5
    assert mask.sum() == rep["hybrid"]["hybrid_color_texels"]
    assert rep["truth"] == "analytic (sphere sample)"
    assert rep["coarse"]["faces"] <= 220 and rep["bake"]["size"] == [64, 64]
    assert rep["baseline"]["vs_truth_deg"]["median"] < 2.0  # the classical bake of a fine sphere is good
    assert rep["vs_gradient_deg"]["max"] < 1.0  # the map holds ∇f of the (untrained) model
    assert set(rep["files"]) == set(names)
    nmap = read_image(out / "normal.png", colour="data")
    exr = read_image(out / "normal.exr", colour="data")
    assert nmap.shape == (64, 64, 3) and np.abs(nmap - exr).max() < 1e-4  # 16-bit PNG ~ float EXR
    gltf, arr, images = read_glb(out / "asset.glb")
    assert len(images) == 2 and {"TANGENT", "TEXCOORD_0"} <= set(arr)
    assert "normal error vs truth" in stdout and "wrote" in stdout
    scene = trimesh.load(out / "vertex.glb", process=False)
    assert len(scene.geometry) == 1


def test_failed_run_keeps_the_good_output(files, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run([files["obj"], "--sdf", files["sdf"], "--coarse", "decimate:200", "--size", "32",
                        "--maps", "normal", "--no-baseline", "--no-hybrid", "--delta", "1e-9", "-o", str(out)], capsys)
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert rep["miss_texels"] == rep["texels_covered"] > 0  # an untrained field is off any tiny band
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    # a texture model passed as --sdf: refused before anything is written
    code, _, err = run([files["obj"], "--sdf", files["tex"], "--size", "32", "-o", str(out)], capsys)
    assert code == 2 and "a TextureField file, expected an SDF" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # a failure in the middle (march of a field without a surface) leaves no staging folder behind
    model = Siren(4, 0, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():  # f = 1 everywhere: no surface to march
        model.layers[-1].weight.zero_()
        model.layers[-1].bias.fill_(1.0)
    flat = save_model(model, tmp_path / "flat.sdf", kind="sdf", frame={"center": [0, 0, 0], "scale": 1.0})
    code, _, err = run([files["obj"], "--sdf", str(flat), "--coarse", "march:8", "--size", "32", "-o", str(out)],
                       capsys)
    assert code == 2 and err.startswith("neural-bake: error:") and err.count("\n") == 1
    assert not any(p.name.startswith(".bake-") for p in out.iterdir())
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


@pytest.mark.parametrize(
    "args, message",
    [
        (["--sdf", "missing.sdf"], "--sdf missing.sdf: no such model file"),
        (["--coarse", "decimate:abc"], "--coarse 'decimate:abc': decimate needs a number"),
        (["--coarse", "melt:3"], "--coarse 'melt:3': unknown kind 'melt'"),
        (["--coarse", "decimate:nan"], "--coarse 'decimate:nan': decimate needs a finite number"),
        (["--coarse", "march:inf"], "--coarse 'march:inf': march needs a finite number"),
        (["--maps", "normal,height"], "--maps 'normal,height': unknown map 'height'"),
        (["--maps", "albedo"], "--maps albedo: needs a texture model file, and none is given"),
        (["--size", "0"], "--size 0: must be a whole number in 1..16384"),
        (["--truth", "sample:cube"], "--truth sample:cube: unknown sample 'cube'"),
        (["--truth", "oracle"], "--truth 'oracle': expected auto, mesh or sample:NAME"),
        (["--delta", "-1"], "--delta -1.0: must be a positive distance"),
        (["--report-samples", "0"], "--report-samples 0: must be a positive integer"),
        (["--hybrid-angle", "0"], "--hybrid-angle 0.0: must be in (0, 180] degrees"),
        (["--hybrid-tol", "-0.1"], "--hybrid-tol -0.1: must be a positive distance"),
        (["--hybrid-detail", "-1"], "--hybrid-detail -1: must be a whole number of texels ≥ 0 (0: never)"),
        (["--hybrid-color-tol", "0"], "--hybrid-color-tol 0.0: must be a positive ΔE (inf: no ΔE rule)"),
        (["--hybrid-color-within", "-1"], "--hybrid-color-within -1.0: must be a number of dB ≥ 0 (inf: no such rule)"),
        (["--hybrid-color-within", "nan"], "--hybrid-color-within nan: must be a number of dB ≥ 0 (inf: no such rule)"),
        (["--hybrid-color-psnr", "0"], "--hybrid-color-psnr 0.0: must be a positive number of dB"),
        (["--hybrid-color-psnr", "inf"], "--hybrid-color-psnr inf: must be a positive number of dB"),
        (["--tolerance", "0"], "--tolerance must be a number of degrees in (0, 90), got 0.0"),
        (["--tolerance", "nan"], "--tolerance must be a number of degrees in (0, 90), got nan"),
    ],
)
def test_user_errors_are_one_line(files, tmp_path, capsys, args, message):
    base = {"--sdf": files["sdf"], "--maps": "normal", "--size": "16", "--coarse": "keep", "--no-baseline": None}
    argv = [files["obj"]]
    given = {a for a in args if a.startswith("--")}
    for k, v in base.items():
        if k not in given:
            argv += [k] if v is None else [k, v]
    code, _, err = run(argv + args + ["-o", str(tmp_path / "o")], capsys)
    assert code == 2
    assert err.startswith("neural-bake: error:") and message in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_missing_mesh_and_folder(files, tmp_path, capsys):
    code, _, err = run([str(tmp_path / "nope.obj"), "--sdf", files["sdf"], "--maps", "normal", "-o",
                        str(tmp_path / "o")], capsys)
    assert code == 2 and "nope.obj: no such file" in err
    code, _, err = run([files["obj"], "--sdf", files["sdf"], "-o", str(tmp_path / "a" / "b")], capsys)
    assert code == 2 and "does not exist" in err


def test_parse_coarse():
    assert parse_coarse("decimate:2000") == ("decimate", 2000)
    assert parse_coarse("decimate:0.25") == ("decimate", 0.25)
    assert parse_coarse("march:64") == ("march", 64)
    assert parse_coarse("keep") == ("keep", None)
    with pytest.raises(NeuralBakeError, match="decimate needs a face count >= 4 or a ratio"):
        parse_coarse("decimate:2")
    with pytest.raises(NeuralBakeError, match=r"march needs a resolution in \[4, 1024\]"):
        parse_coarse("march:2.5")
    with pytest.raises(NeuralBakeError, match="keep takes no value"):
        parse_coarse("keep:3")


def test_coarse_march_and_keep(files):
    mesh = load_mesh(files["obj"])
    from neural_bake.fields import SdfField

    with pytest.raises(NeuralBakeError, match="march needs an SDF model"):
        coarse_mesh(mesh, "march:16", SdfField(lambda p: p.norm(dim=1) - 0.5))
    model = Siren(4, 0)
    with torch.no_grad():  # f(p) = sin(x) - 0.5: the plane x = π/6
        model.layers[0].weight.zero_()
        model.layers[0].weight[0, 0] = 1.0 / model.omega_0
        model.layers[0].bias.zero_()
        model.layers[1].weight.zero_()
        model.layers[1].weight[0, 0] = 1.0
        model.layers[1].bias.fill_(-0.5)
    marched, info = coarse_mesh(mesh, "march:16", SdfField.from_model(model))
    assert marched.n_faces > 0 and info["faces"] == marched.n_faces and "march" in info
    assert np.allclose(marched.vertices[:, 0], np.pi / 6, atol=2e-3)
    kept, info = coarse_mesh(mesh, "keep")
    assert kept is mesh and info["faces"] == mesh.n_faces


def test_console_script(files, tmp_path):
    exe = Path(__file__).resolve().parents[1] / ".venv" / "bin" / "neural-bake"
    if not exe.exists():
        pytest.skip("console script not installed")
    res = subprocess.run([str(exe), "bake", files["obj"], "--sdf", files["tex"], "-o", str(tmp_path / "o")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "expected an SDF" in res.stderr and "Traceback" not in res.stderr


def test_bench_bake_shrunken_run():
    from neural_bake.bench.bake import run

    res = run(quick=True, sizes=[32], faces=[300], map_sizes=[32], autograd=True, anchor=False)
    assert res["name"] == "bake" and set(res["tables"]) == {"throughput", "error vs time"}
    (t,) = res["tables"]["throughput"]
    assert t["texels"] > 0 and t["texels/s"] > 0 and t["speed-up"] > 0
    (e,) = res["tables"]["error vs time"]
    # the analytic field baked into an 8-bit map beats both the coarse geometry and the ray-cast baseline
    assert e["ours med°"] < 1.0 and e["ours med°"] < e["baseline med°"] < e["geometry med°"]
    assert 0 < e["map vs ∇f med°"] < 1.0  # 8-bit quantisation of the analytic field's own normals
    assert any("random initialisation" in n for n in res["notes"])
    assert any(n.startswith("target: median angular error") and "(met)" in n for n in res["notes"])


def test_delta_defaults_to_the_texture_models_band(files, tmp_path, capsys):
    """With no δ on the SDF and no --delta, the texture model's band flags texels off |f| <= δ."""
    from neural_bake.nets.model_io import load_model

    model, meta = load_model(files["tex"])
    tex = save_model(model, tmp_path / "band.tex", **{**meta, "delta": 1e-9})
    out = tmp_path / "out"
    code, stdout, err = run([files["obj"], "--sdf", files["sdf"], "--texture-model", str(tex), "--coarse", "keep",
                             "--size", "32", "--no-baseline", "-o", str(out)], capsys)
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert rep["bake"]["delta"] == pytest.approx(1e-9)
    assert rep["bake"]["texture_at"] == "point"  # baked onto the source: the colours are read where they were fitted
    assert "from band.tex" in stdout
    # an untrained net is nowhere near 0 on the sphere: every covered texel is off the band
    assert rep["miss_texels"] == rep["texels_covered"] > 0


def test_streamed_bake_writes_a_sampled_report(files, tmp_path):
    """A map forced to stream gets the full report: per-sample errors on a uniform subsample (said so),
    coverage, misses, seams and error maps over every texel, equal to the cached run's."""
    from neural_bake.pipelines.bake_asset import BakeAssetConfig, bake_asset

    common = dict(coarse="decimate:200", size=64, maps="normal,albedo", delta=0.05, force=True)  # untrained SDF
    logs: list[str] = []
    cached = bake_asset(files["obj"], files["sdf"], tmp_path / "c", BakeAssetConfig(**common),
                        texture_model=files["tex"], log=lambda s: None)
    streamed = bake_asset(files["obj"], files["sdf"], tmp_path / "s",
                          BakeAssetConfig(**common, cache_texels=False, report_samples=300),
                          texture_model=files["tex"], log=logs.append)
    rep = json.loads((tmp_path / "s" / "report.json").read_text())
    m = cached["sampling"]["of"]
    assert cached["sampling"]["sampled"] == [] and cached["sampling"]["samples"] == m > 1000
    assert cached["bake"]["texture_at"] == rep["bake"]["texture_at"] == "surface"  # a decimation: its closest points
    assert rep["sampling"]["samples"] == 300 and rep["sampling"]["of"] == m and "note" not in rep
    assert streamed["sampling"]["samples"] == 300  # the returned report is the written one
    assert {"vs_truth_deg", "vs_gradient_deg", "color_psnr_db", "baseline.vs_truth_deg"} <= set(rep["sampling"]["sampled"])
    assert rep["truth"] == "analytic (sphere sample)" and rep["vs_truth_deg"]["count"] == 300
    lo, hi = rep["vs_truth_deg"]["median_ci95"]
    assert lo <= cached["vs_truth_deg"]["median"] <= hi
    assert abs(rep["color_psnr_db"] - cached["color_psnr_db"]) < 1.0
    assert rep["baseline"]["samples"] == 300 and rep["baseline"]["all_texels"]["samples"] == m
    assert rep["baseline"]["all_texels"]["fallback"] == cached["baseline"]["fallback"]
    for key in ("coverage", "texels_covered", "miss_texels", "invalid_gradients", "seams"):
        assert rep[key] == cached[key], key
    assert set(rep["files"]) == set(cached["files"])
    for name in ("error_normal.png", "error_baseline.png", "miss.png", "normal.png", "albedo.png"):
        a = read_image(tmp_path / "c" / name, colour="data")
        assert np.array_equal(a, read_image(tmp_path / "s" / name, colour="data")), name
    assert any("over all" in line for line in logs) and any(line.startswith("report: sampled 300 of") for line in logs)
    assert any("on 300 sampled of" in line for line in logs)
    # the fine mesh as truth (closest points, band by band for the error map)
    mesh_truth = bake_asset(files["obj"], files["sdf"], tmp_path / "m",
                            BakeAssetConfig(**common, cache_texels=False, report_samples=300, truth="mesh",
                                            baseline=False), texture_model=files["tex"], log=lambda s: None)
    assert mesh_truth["truth"] == "fine mesh, closest point" and mesh_truth["vs_truth_deg"]["count"] == 300
    assert "baseline" not in mesh_truth and "error_baseline.png" not in mesh_truth["files"]
    assert "error_normal.png" in mesh_truth["files"]


def test_report_samples_must_be_positive(files, tmp_path):
    from neural_bake.pipelines.bake_asset import BakeAssetConfig, bake_asset

    with pytest.raises(NeuralBakeError, match="report_samples 0: must be a positive integer"):
        bake_asset(files["obj"], files["sdf"], tmp_path / "o", BakeAssetConfig(report_samples=0), log=lambda s: None)
    assert not (tmp_path / "o").exists()


def test_cli_texels_and_report_samples(files, tmp_path, capsys):
    """--texels stream with --report-samples N: the report says it measured N sampled texel samples."""
    out = tmp_path / "out"
    code, stdout, err = run([files["obj"], "--sdf", files["sdf"], "--coarse", "decimate:200", "--size", "32",
                             "--maps", "normal", "--no-baseline", "--texels", "stream", "--report-samples", "200",
                             "-o", str(out)], capsys)
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert rep["sampling"]["samples"] == 200 < rep["sampling"]["of"] and rep["vs_truth_deg"]["count"] == 200
    code, _, err = run([files["obj"], "--sdf", files["sdf"], "--coarse", "decimate:200", "--size", "32",
                        "--maps", "normal", "--no-baseline", "--texels", "cache", "-o", str(tmp_path / "c")], capsys)
    assert code == 0, err
    rep = json.loads((tmp_path / "c" / "report.json").read_text())
    assert rep["sampling"]["samples"] == rep["sampling"]["of"] and rep["sampling"]["sampled"] == []


def test_hybrid_bake_report_map_and_warnings(files, tmp_path, capsys):
    """An untrained field is unfaithful nearly everywhere: the hybrid map is the classical bake's, the report
    says how many texels took it; without the hybrid, the report warns that the map does not beat the coarse
    mesh's own normals."""
    out = tmp_path / "h"
    code, stdout, err = run([files["obj"], "--sdf", files["sdf"], "--coarse", "decimate:200", "--size", "48",
                             "--maps", "normal", "-o", str(out)], capsys)
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    h = rep["hybrid"]
    assert h["hybrid_texels"] > 0.9 * rep["texels_covered"] and h["replaced"] == h["hybrid_samples"]
    assert h["sdf_tol"] == 0.01 and h["angle_deg"] == 5.0 and h["samples"] == rep["bake"]["samples"]
    # the untrained field alone is far off; the hybrid map is as good as the classical bake
    assert rep["neural_vs_truth_deg"]["median"] > 20.0
    assert rep["vs_truth_deg"]["median"] < rep["baseline"]["vs_truth_deg"]["median"] + 0.5
    hmap = read_image(out / "hybrid.png", colour="data")
    assert int((hmap[..., 0] > 0.5).sum()) == h["hybrid_texels"]
    assert "hybrid bake:" in stdout and "took the classical normal" in stdout
    # without the hybrid: the neural map, no hybrid map, and a warning that it does not beat the coarse mesh
    out2 = tmp_path / "n"
    code, stdout, err = run([files["obj"], "--sdf", files["sdf"], "--coarse", "decimate:200", "--size", "48",
                             "--maps", "normal", "--no-hybrid", "-o", str(out2)], capsys)
    assert code == 0, err
    rep2 = json.loads((out2 / "report.json").read_text())
    assert "hybrid" not in rep2 and not (out2 / "hybrid.png").exists()
    assert len(rep2["warnings"]) == 1 and "does not beat the coarse mesh's own normals" in rep2["warnings"][0]
    assert sum(line.startswith("warning: ") for line in stdout.splitlines()) == 1


def test_coarse_keep_warns(files, tmp_path, capsys):
    out = tmp_path / "k"
    code, stdout, err = run([files["obj"], "--sdf", files["sdf"], "--coarse", "keep", "--size", "32",
                             "--maps", "normal", "--no-baseline", "-o", str(out)], capsys)
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert len(rep["warnings"]) == 1 and rep["warnings"][0].startswith("--coarse keep:")  # one line, not two
    assert [line for line in stdout.splitlines() if line.startswith("warning:")] == ["warning: " + rep["warnings"][0]]


def test_adaptive_bake_reports_its_evaluated_share_and_error(files, tmp_path, capsys):
    out_on, out_off = tmp_path / "on", tmp_path / "off"
    common = [files["obj"], "--sdf", files["sdf"], "--coarse", "decimate:200", "--size", "128", "--no-baseline",
              "--no-hybrid", "--precision", "fp32"]
    code, stdout, err = run(common + ["--tolerance", "0.5", "-o", str(out_on)], capsys)
    assert code == 0, err
    on = json.loads((out_on / "report.json").read_text())["bake"]
    assert on["adaptive"]["tolerance_deg"] == 0.5 and 0 < on["evaluated_fraction"] <= 1
    control = on["error_control"]
    assert control["samples"] > 0 and control["angle_deg"]["max"] <= 0.5
    assert "adaptive evaluation:" in stdout and "% of the texel samples evaluated" in stdout
    code, stdout, err = run(common + ["--adaptive", "off", "-o", str(out_off)], capsys)
    assert code == 0, err
    off = json.loads((out_off / "report.json").read_text())["bake"]
    assert off["adaptive"] is None and off["evaluated_fraction"] == 1.0 and "error_control" not in off
    assert "adaptive evaluation:" not in stdout and "precision: fp32 (float32 asked for)" in stdout
    assert off["precision"]["sdf"] == "fp32"


def test_bench_bake_anchor_table_shrunken():
    from neural_bake.bench.bake import run
    from neural_bake.fields import SdfField
    from neural_bake.nets.siren import Siren

    field = SdfField.from_model(Siren(32, 1, generator=torch.Generator().manual_seed(0)), name="tiny")
    res = run(quick=True, sizes=[16], faces=[300], map_sizes=[16], autograd=False, anchor_sizes=[96],
              anchor_model=field, repeats=2)
    rows = res["tables"]["against the anchor"]
    methods = [r["method"] for r in rows]
    assert methods[:4] == ["ours full fp32", "ours adaptive fp32", "ours adaptive auto", "open3d mesh-to-mesh"]
    full, adaptive = rows[0], rows[1]
    assert full["vs full fp32 med°"] == 0.0 and full["evaluated"] == 1.0 and 0 < adaptive["evaluated"] <= 1.0
    assert adaptive["vs full fp32 med°"] < 0.5  # an untrained field at 96²: the tolerance holds per sample
    base = rows[3]
    assert base["vs source med°"] < 1.0 < base["vs full fp32 med°"]  # the classical bake is the source's normals
    assert all(r["÷ open3d s"] > 0 for r in rows) and base["÷ open3d s"] == 1.0
    assert all(r["bake s"] > 0 and r["set-up s"] > 0 for r in rows if r["set-up s"] is not None)
    notes = " ".join(res["notes"])
    assert "against the anchor:" in notes and "Blender Cycles:" in notes
    assert "quality vs source unchanged within 0.05° median" in notes
    # the user's command: the real `neural-bake bake` as its own process, its wall and report stages
    cmd = [r for r in res["tables"]["the user's command"] if r["method"].startswith("neural-bake bake")]
    assert len(cmd) == 1 and cmd[0]["map"] == "96²"
    c = cmd[0]
    assert c["wall s"] > c["bake s"] > 0 and c["prepare s"] > 0 and c["load s"] > 0 and 0 < c["evaluated"] <= 1.0
    assert c["vs source med°"] is not None and "the user's command:" in notes
    # its own process forks the preloading one: the mesh read, decimated and unwrapped there, none of it here
    assert c["preload s"] > 0 and c["coarse s"] == 0.0 and "preload s:" in notes
    # two rounds: the wall and the bake stage are each the best of them, their ranges beside
    assert c["rounds"] == 2 and "best of the rounds" in notes
    for key in ("wall", "bake"):
        low, high = (float(v) for v in c[f"{key} range s"].split("–"))
        assert low <= high and abs(c[f"{key} s"] - low) <= 0.05
    # each round also bakes again with the coarse mesh and layout from the cache (only runs that read it count)
    (again,) = [r for r in res["tables"]["the user's command"] if r["method"].startswith("the same bake again")]
    assert again["rounds"] == 2 and again["map"] == "96²" and again["vs source med°"] == c["vs source med°"]
    assert "a first bake" in c["method"] and "--no-layout-cache" in notes


def test_bench_bake_anchor_tables_on_another_mesh(files):
    # --anchor-mesh: the anchor table and the user's command read that mesh (here the fixture's sphere) instead of
    # Spot, at the sizes asked for
    from neural_bake.bench.bake import run
    from neural_bake.fields import SdfField
    from neural_bake.nets.siren import Siren

    field = SdfField.from_model(Siren(32, 1, generator=torch.Generator().manual_seed(0)), name="tiny")
    res = run(quick=True, sizes=[16], faces=[300], map_sizes=[16], autograd=False, anchor_sizes=[64],
              anchor_model=field, anchor_mesh=files["obj"], repeats=1)
    notes = " ".join(res["notes"])
    assert "against the anchor: sphere," in notes
    assert {r["map"] for r in res["tables"]["against the anchor"]} == {"64²"}
    (cmd,) = [r for r in res["tables"]["the user's command"] if r["method"].startswith("neural-bake bake")]
    assert cmd["map"] == "64²" and cmd["wall s"] > cmd["bake s"] > 0


def test_bench_bake_anchor_options_refuse_bad_values(tmp_path, capsys):
    # a missing anchor mesh and a map size below the range are usage errors, before any work
    assert main(["bench", "bake", "--anchor-mesh", str(tmp_path / "missing.obj")]) == 2
    assert "missing.obj" in capsys.readouterr().err
    assert main(["bench", "bake", "--anchor-size", "8"]) == 2
    assert "--anchor-size" in capsys.readouterr().err


def test_infinite_colour_rules_keep_the_networks_colours(files, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run([files["obj"], "--sdf", files["sdf"], "--texture-model", files["tex"], "--coarse", "decimate:200",
                        "--size", "32", "--maps", "normal,albedo", "--no-baseline", "--hybrid-color-tol", "inf",
                        "--hybrid-color-within", "inf", "-o", str(out)], capsys)
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert not (out / "hybrid_color.png").exists() and "hybrid_color_texels" not in rep["hybrid"]
    assert rep["hybrid"]["color_tol"] is None and rep["hybrid"]["color_within"] is None
    assert "neural_color_psnr_db" not in rep


def test_a_repeated_bake_reads_its_coarse_mesh_and_layout_from_the_cache(files, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("NEURAL_BAKE_CACHE_DIR", str(tmp_path / "cache"))
    args = [files["obj"], "--sdf", files["sdf"], "--coarse", "decimate:200", "--size", "64", "--no-baseline"]
    maps = {}
    for name, extra in (("off", ["--no-layout-cache"]), ("first", []), ("again", [])):
        code, stdout, err = run([*args, *extra, "-o", str(tmp_path / name)], capsys)
        assert code == 0, err
        rep = json.loads((tmp_path / name / "report.json").read_text())
        assert rep["coarse"].get("cached", False) == (name == "again")
        assert ("from the layout cache" in stdout) == (name == "again")
        maps[name] = read_image(tmp_path / name / "normal.png", colour="data")
        if name == "off":  # nothing kept
            assert not (tmp_path / "cache" / "layouts").exists()
    entries = sorted(p.name.split("-")[0] for p in (tmp_path / "cache" / "layouts").glob("*.npz"))
    assert entries == ["coarse", "unwrap"]
    assert np.array_equal(maps["off"], maps["first"]) and np.array_equal(maps["first"], maps["again"])
    # another size unwraps again (the layout depends on it) but keeps the decimated mesh
    code, stdout, err = run([*args[:-3], "--size", "32", "--no-baseline", "-o", str(tmp_path / "small")], capsys)
    assert code == 0, err
    assert "from the layout cache" in stdout
    assert len(list((tmp_path / "cache" / "layouts").glob("unwrap-*.npz"))) == 2


def test_a_marched_coarse_mesh_is_cached_by_its_model_file(files, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("NEURAL_BAKE_CACHE_DIR", str(tmp_path / "cache"))
    sdf = tmp_path / "s.sdf"
    sdf.write_bytes(Path(files["sdf"]).read_bytes())
    args = [files["obj"], "--sdf", str(sdf), "--coarse", "march:24", "--size", "32", "--no-baseline", "--no-hybrid"]
    for i in range(2):
        code, _, err = run([*args, "-o", str(tmp_path / f"o{i}")], capsys)
        assert code == 0, err
    reps = [json.loads((tmp_path / f"o{i}" / "report.json").read_text()) for i in range(2)]
    assert [r["coarse"]["cached"] for r in reps] == [False, True]
    assert reps[0]["coarse"]["faces"] == reps[1]["coarse"]["faces"]
    save_model(Siren(16, 1, generator=torch.Generator().manual_seed(5)), sdf, kind="sdf",
               frame=load_mesh(files["obj"]).frame.to_dict())  # another model in the same file
    code, _, err = run([*args, "-o", str(tmp_path / "o2")], capsys)
    assert code == 0, err
    assert json.loads((tmp_path / "o2" / "report.json").read_text())["coarse"]["cached"] is False


def test_the_command_preloads_the_mesh_in_a_fork_and_bakes_the_same_map(files, tmp_path):
    """As a user runs it (its own process, torch not yet imported): the source mesh is read, decimated and
    unwrapped in a forked process while torch is imported, and the maps and the report's figures are those of the
    same bake without the preload (``NEURAL_BAKE_PRELOAD=0``). A mesh the loader refuses gives the same one-line
    error either way."""
    import os
    import sys

    from neural_bake.bake.preload import ENV_SWITCH

    def bake(out, switch, mesh=files["obj"]):
        env = {k: v for k, v in os.environ.items() if k != ENV_SWITCH}
        if switch is not None:
            env[ENV_SWITCH] = switch
        return subprocess.run([sys.executable, "-m", "neural_bake.cli.main", "bake", str(mesh), "--sdf", files["sdf"],
                               "--force", "--coarse", "decimate:200", "--size", "64", "--no-layout-cache",
                               "-o", str(out)], capture_output=True, text=True, timeout=600, env=env)

    runs = {switch: bake(tmp_path / f"out-{switch}", switch) for switch in (None, "0")}
    for r in runs.values():
        assert r.returncode == 0, r.stderr
    with_pre, without = (json.loads((tmp_path / f"out-{s}" / "report.json").read_text()) for s in (None, "0"))
    assert with_pre["preload"]["failure"] is None and set(with_pre["preload"]["seconds"]) == {"load", "coarse", "unwrap"}
    assert without["preload"] is None
    assert (tmp_path / "out-None" / "normal.png").read_bytes() == (tmp_path / "out-0" / "normal.png").read_bytes()
    assert with_pre["vs_truth_deg"] == without["vs_truth_deg"] and with_pre["coarse"]["faces"] == without["coarse"]["faces"]
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    errors = {switch: bake(tmp_path / f"bad-{switch}", switch, bad) for switch in (None, "0")}
    assert errors[None].returncode == errors["0"].returncode == 2
    assert errors[None].stderr == errors["0"].stderr and errors[None].stderr.count("\n") == 1
    assert errors[None].stderr.startswith(f"neural-bake: error: {bad}")
    assert not (tmp_path / "bad-None").exists()


def test_bake_takes_a_tiled_sdf(files, tmp_path, capsys):
    from neural_bake.nets.tiles import TiledSdf, TileGrid, TiledSiren

    gen = torch.Generator().manual_seed(4)
    mesh = load_mesh(files["obj"])
    tiles = TiledSiren(TileGrid([-1.0, -1.0, -1.0], 0.5, 4, 0.1, torch.arange(0, 64, 2)), 8, 1, zero_output=False,
                       generator=gen)
    sdf = save_model(TiledSdf(Siren(16, 1, generator=gen), tiles), tmp_path / "t.sdf", kind="sdf",
                     frame=mesh.frame.to_dict())
    out = tmp_path / "out"
    code, stdout, err = run([files["obj"], "--sdf", str(sdf), "--coarse", "decimate:200", "--size", "64",
                             "--maps", "normal", "--precision", "auto", "-o", str(out)], capsys)
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert rep["vs_gradient_deg"]["max"] < 1.0  # the map holds ∇f of h + r, tiles and seams included
    assert "a tiled SDF's networks run in float32" in stdout
