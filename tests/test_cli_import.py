"""`neural-bake import`: reference SIREN weights become a model file that loads, nests, bakes and renders like a
fitted one; every refused input is one line with exit code 2 and nothing written."""

import json

import numpy as np
import pytest
import torch

from neural_bake.cli.main import main
from neural_bake.fields import NestedSequence, SdfField, load_field
from neural_bake.io.images import read_image
from neural_bake.io.mesh_io import load_mesh
from neural_bake.io.outdir import OutputLock
from neural_bake.samples.generate import write_sample
from neural_bake.samples.shapes import get_sample
from neural_bake.types import Frame


def _bvp_state(model):
    """The state dict a SingleBVPNet with ``model``'s weights saves (net.net.<i>.0.weight|bias)."""
    return {f"net.net.{i}.0.{p}": getattr(layer, p).detach().clone() for i, layer in enumerate(model.layers)
            for p in ("weight", "bias")}


@pytest.fixture(scope="module")
def files(tmp_path_factory, fit_sphere_siren):
    """A sphere SIREN (ω0 10, hidden ω 30, radius 0.9 in its input space) saved in the SingleBVPNet layout, the sphere
    sample mesh (radius 0.9 in its unit frame) and a few refused weight files."""
    d = tmp_path_factory.mktemp("import_cli")
    obj = write_sample(get_sample("sphere").mesh(resolution=200, texture_size=32), d, "sphere")
    sphere = fit_sphere_siren(r=0.9, width=32, steps=300)
    torch.save(_bvp_state(sphere), d / "sphere.pth")
    small = _bvp_state(fit_sphere_siren(r=0.9, width=8, steps=1))
    torch.save({**small, "net.net.1.0.weight": torch.zeros(8, 8, dtype=torch.int64)}, d / "int.pth")
    torch.save({**small, "net.net.0.0.weight": torch.zeros(8, 4), }, d / "xyzt.pth")
    torch.save({**small, "net.net.0.0.weight": torch.zeros(8, 63)}, d / "pe.pth")
    torch.save({**small, "net.net.1.0.bias": torch.full((8,), float("nan"))}, d / "nan.pth")
    torch.save({**small, "net.net.3.0.weight": torch.zeros(1, 1)}, d / "gap.pth")
    torch.save({**small, "optimizer": {"lr": 1e-4}}, d / "ckpt.pth")
    torch.save(get_sample, d / "code.pth")  # a pickled function: weights-only loading refuses it
    np.zeros(100, "<f4").tofile(d / "short.bin")
    return {"obj": str(obj), "pth": str(d / "sphere.pth"), "dir": d, "sphere": sphere}


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def run(args, capsys):
    code = main(list(args))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_imported_siren_loads_nests_bakes_and_renders(files, tmp_path, capsys):
    model = tmp_path / "sphere.sdf"
    code, out, err = run(["import", files["pth"], "-o", str(model), "--omega0", "10", "--hidden-omega0", "30",
                          "--frame-from", files["obj"]],
                         capsys)
    assert code == 0, err
    assert "torch state dict (SingleBVPNet), SIREN 32x1 of (x, y, z) -> f, ω0 10, hidden ω 30, float32" in out
    assert f"wrote {model}" in out
    field = load_field(model)
    assert isinstance(field, SdfField) and field.frame == load_mesh(files["obj"]).frame
    assert (field.model.width, field.model.depth, field.model.omega_0, field.model.hidden_omega) == (32, 1, 10.0, 30.0)
    x = torch.rand(200, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1
    with torch.no_grad():
        assert torch.equal(field.value(x), files["sphere"](x)[:, 0])  # the network that was trained

    shot = tmp_path / "shot.png"
    code, out, err = run(["render", str(model), "-o", str(shot), "--size", "32", "--camera", "0,0,6", "--look-at",
                          "0,0,0", "--fov", "40", "--channels", "color,hit", "--stats", str(tmp_path / "s.json")],
                         capsys)
    assert code == 0, err
    hit = read_image(tmp_path / "shot.hit.png", colour="data")[..., 0] > 0.5
    cols = np.nonzero(hit.any(axis=0))[0]  # radius 0.9 seen from 6 units away spans 2·asin(0.9/6) of the 40° fov
    assert abs((cols[-1] - cols[0] + 1) - 32 * 2 * np.degrees(np.arcsin(0.9 / 6)) / 40) <= 2.5
    assert json.loads((tmp_path / "s.json").read_text())["pixels"]["hit"] == int(hit.sum())

    nested = tmp_path / "sphere.nested"
    code, out, err = run(["fit", "nested", str(model), "-o", str(nested), "--levels", "8x0", "--steps", "20",
                          "--max-boxes", "400", "--no-progress"], capsys)
    assert code == 0, err
    seq = NestedSequence.load(nested)
    assert len(seq.levels) == 2 and seq.frame == field.frame

    bake = tmp_path / "bake"
    code, out, err = run(["bake", files["obj"], "--sdf", str(model), "--coarse", "decimate:100", "--size", "16",
                          "--maps", "normal", "--no-baseline", "--force", "-o", str(bake)], capsys)
    assert code == 0, err
    rep = json.loads((bake / "report.json").read_text())
    assert rep["vs_gradient_deg"]["max"] < 1.0


def test_raw_file_and_given_frame(files, tmp_path, capsys):
    sd = torch.load(files["pth"], weights_only=True)
    flat = np.concatenate([np.concatenate([sd[f"net.net.{i}.0.weight"].numpy().ravel(),
                                           sd[f"net.net.{i}.0.bias"].numpy()]) for i in range(3)]).astype("<f4")
    flat.tofile(tmp_path / "w.bin")
    model = tmp_path / "raw.sdf"
    code, out, err = run(["import", str(tmp_path / "w.bin"), "-o", str(model), "--raw", "--width", "32", "--depth",
                          "1", "--omega0", "10", "--hidden-omega0", "30", "--frame-center", "1,-2,0.5",
                          "--frame-scale", "0.5"], capsys)
    assert code == 0, err
    assert "raw float32" in out and "frame: centre 1, -2, 0.5, scale 0.5" in out
    field = load_field(model)
    assert field.frame == Frame((1.0, -2.0, 0.5), 0.5)
    for p in ("weight", "bias"):
        assert torch.equal(getattr(field.model.layers[1], p), sd[f"net.net.1.0.{p}"])


def _bad_cases():
    d = "{dir}"
    pth, out = f"{d}/sphere.pth", f"{d}/out/x.sdf"
    ok = ["-o", out, "--omega0", "30"]
    return [
        (["import", f"{d}/none.pth", *ok], "none.pth: no such weights file"),
        (["import", f"{d}/code.pth", *ok], "code.pth: holds pickled Python objects"),
        (["import", f"{d}/ckpt.pth", *ok], "ckpt.pth: unknown keys optimizer; not a plain SIREN"),
        (["import", f"{d}/int.pth", *ok], "int.pth: net.net.1.0.weight has dtype torch.int64, expected a float type"),
        (["import", f"{d}/xyzt.pth", *ok], "xyzt.pth: a network of 4 inputs (a space-time SDF?)"),
        (["import", f"{d}/pe.pth", *ok], "pe.pth: a network of 63 inputs (a positional encoding?)"),
        (["import", f"{d}/nan.pth", *ok], "nan.pth: net.net.1.0.bias holds NaN or infinite values"),
        (["import", f"{d}/gap.pth", *ok], "gap.pth: layer 3 has no bias"),
        (["import", f"{d}/short.bin", *ok, "--raw", "--width", "8", "--depth", "1"],
         "short.bin: 400 bytes, a raw float32 8x1 SIREN of (x, y, z) -> f has 452 (113 values)"),
        (["import", f"{d}/short.bin", *ok, "--raw", "--width", "0", "--depth", "1"],
         "--width = 0: must be an integer from 1 to"),
        (["import", f"{d}/short.bin", *ok, "--raw", "--width", "8"], "--raw needs --width and --depth"),
        (["import", pth, *ok, "--depth", "1"], "--width and --depth describe a --raw file"),
        (["import", pth, "-o", out], "Missing option '--omega0'"),
        (["import", pth, "-o", out, "--omega0", "0"], "--omega0 0.0: must be a positive number"),
        (["import", pth, *ok, "--hidden-omega0", "nan"], "--hidden-omega0 nan: must be a positive number"),
        (["import", pth, *ok, "--kind", "texture"], "Invalid value for '--kind'"),
        (["import", pth, *ok, "--frame-center", "1,2"], "--frame-center '1,2': must be X,Y,Z, three finite numbers"),
        (["import", pth, *ok, "--frame-center", "1,2,inf"], "--frame-center '1,2,inf': must be X,Y,Z"),
        (["import", pth, *ok, "--frame-scale", "-2"], "--frame-scale -2.0: must be a positive number"),
        (["import", pth, *ok, "--frame-from", f"{d}/sphere.obj", "--frame-scale", "2"],
         "give --frame-from or --frame-center/--frame-scale, not both"),
        (["import", pth, *ok, "--frame-from", f"{d}/none.obj"], "none.obj"),
        (["import", pth, "-o", f"{d}/nope/x.sdf", "--omega0", "30"], "does not exist"),
        (["import", pth, "-o", d, "--omega0", "30"], "is a directory"),
    ]


@pytest.mark.parametrize("args,message", _bad_cases())
def test_refused_input_is_one_line_exit_2_and_nothing_written(files, capsys, args, message):
    (files["dir"] / "out").mkdir(exist_ok=True)
    code, out, err = run([a.format(dir=files["dir"]) for a in args], capsys)
    assert code == 2 and err.startswith("neural-bake: error: ") and err.count("\n") == 1, err
    assert message in err and "Traceback" not in err, err
    assert not any((files["dir"] / "out").iterdir())


def test_an_output_another_run_writes_is_refused(files, tmp_path, capsys):
    out = tmp_path / "held.sdf"
    with OutputLock(out):
        code, _, err = run(["import", files["pth"], "-o", str(out), "--omega0", "10"], capsys)
    assert code == 1 and err.count("\n") == 1 and "held.sdf" in err, err
    assert not out.exists()
