"""`neural-bake bake --formats glb,usd,usdz` and `bake --sdf MODEL` without a source mesh: a small sphere
model marched, baked and written in every format; the USD files read back as the GLB beside them; one-line
errors (unknown format, missing extra, no surface, keep without a mesh, unwritable output)."""

import errno
import json
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from neural_bake.bake.export import read_glb
from neural_bake.cli.main import main
from neural_bake.fields import save_model
from neural_bake.nets.siren import Siren
from neural_bake.types import Frame

pytest.importorskip("pxr", reason="usd-core (the extra usd) is in the test extras")
from pxr import Usd, UsdGeom, UsdShade  # noqa: E402

FRAME = Frame((1.0, 2.0, 3.0), 0.5)  # unit = (source − centre) · 0.5: the sphere of radius 0.7 is 1.4 in source units
BAKE = ["--coarse", "march:24", "--size", "64"]


@pytest.fixture(scope="module")
def models(tmp_path_factory, fit_sphere_siren):
    d = tmp_path_factory.mktemp("usd_bake")
    sdf = save_model(fit_sphere_siren(width=16, steps=150), d / "sphere.sdf", kind="sdf", frame=FRAME.to_dict())
    tex = save_model(Siren(16, 1, out_dim=3, generator=torch.Generator().manual_seed(0)), d / "t.tex",
                     kind="texture", frame=FRAME.to_dict())
    empty = Siren(8, 1, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        empty.layers[-1].weight.zero_()
        empty.layers[-1].bias.fill_(5.0)  # f = 5 everywhere: no surface
    nothing = save_model(empty, d / "nothing.sdf", kind="sdf", frame=FRAME.to_dict())
    return {"sdf": str(sdf), "tex": str(tex), "nothing": str(nothing), "dir": d}


def run(args, capsys):
    code = main(["bake", *args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_model_alone_bakes_every_format_and_usd_reads_back_as_the_glb(models, tmp_path, capsys):
    out = tmp_path / "out"
    code, stdout, err = run(["--sdf", models["sdf"], "--texture-model", models["tex"], *BAKE,
                             "--formats", "glb,usd,usdz", "-o", str(out)], capsys)
    assert code == 0, err
    assert {"asset.glb", "asset.usd", "asset.usdz", "normal.png", "albedo.png", "report.json"} <= \
        {p.name for p in out.iterdir()}
    rep = json.loads((out / "report.json").read_text())
    assert rep["mesh"] is None and "baseline" not in rep and "vs_truth_deg" not in rep
    assert rep["truth"].startswith("none: no source mesh") and rep["coarse"]["spec"] == "march:24"
    assert rep["vs_gradient_deg"]["p95"] < 2.0  # the 8-bit map holds ∇f
    assert "normal map vs ∇f of the finest level (no source mesh, no baseline)" in stdout
    _, glb, _ = read_glb(out / "asset.glb")
    # analytic oracle: the marched vertices lie on the sphere of radius 0.7 / 0.5 about the frame's centre
    r = np.linalg.norm(glb["POSITION"] - np.asarray(FRAME.center), axis=1)
    assert np.abs(r - 1.4).max() < 0.05
    for name in ("asset.usd", "asset.usdz"):
        stage = Usd.Stage.Open(str(out / name))
        assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
        mesh = UsdGeom.Mesh(stage.GetDefaultPrim().GetChild("mesh"))
        np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get()), glb["POSITION"], atol=1e-6)
        assert np.array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), glb["indices"])
        np.testing.assert_allclose(np.asarray(mesh.GetNormalsAttr().Get()), glb["NORMAL"], atol=1e-6)
        st = np.asarray(UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").Get())
        np.testing.assert_allclose(st, np.c_[glb["TEXCOORD_0"][:, 0], 1 - glb["TEXCOORD_0"][:, 1]], atol=1e-6)
        material, _ = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()
        surface = material.ComputeSurfaceSource()[0]
        for inp, png in (("diffuseColor", "albedo.png"), ("normal", "normal.png")):
            tex = UsdShade.Shader(surface.GetInput(inp).GetConnectedSources()[0][0].source.GetPrim())
            resolved = tex.GetInput("file").Get().resolvedPath
            if name.endswith("usdz"):
                assert resolved.endswith(f"[{png}]")
                assert zipfile.ZipFile(out / name).read(png) == (out / png).read_bytes()
            else:
                assert resolved == str(out / png)
    # the report shows the neural preview beside the bake (no source mesh to show)
    assert main(["view", str(out), "--no-open", "--views", "1", "--size", "16"]) == 0
    view = json.loads((out / "report" / "view.json").read_text())
    assert view["neural"] and list(view["metrics"]) == ["baked_vs_neural"]


def test_format_and_mesh_errors_are_one_line(models, tmp_path, capsys):
    out = tmp_path / "out"
    cases = [
        (["--sdf", models["sdf"], "--formats", "glb,fbx"], "--formats 'glb,fbx': unknown format 'fbx' (choose from "
                                                           "glb, usd, usdz)"),
        (["--sdf", models["sdf"], "--coarse", "keep"], "--coarse 'keep': keep bakes onto the source mesh, and none "
                                                       "is given"),
        (["--sdf", models["nothing"], "--coarse", "march:16"], f"{models['nothing']}: no surface to bake from the "
                                                              "model alone (march: the level set f = 0 does not "
                                                              "cross the grid"),
        ([str(tmp_path / "none.obj"), "--sdf", models["sdf"]], f"{tmp_path / 'none.obj'}: no such file"),
    ]
    for args, message in cases:
        code, _, err = run([*args, "--size", "32", "-o", str(out)], capsys)
        assert code == 2 and err.startswith(f"neural-bake: error: {message}") and err.count("\n") == 1, err
    assert not out.exists()


def test_missing_extra_is_one_line_exit_1_before_any_work(models, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pxr", None)  # `from pxr import …` fails as without usd-core
    out = tmp_path / "out"
    code, _, err = run(["--sdf", models["sdf"], *BAKE, "--formats", "glb,usdz", "-o", str(out)], capsys)
    assert code == 1
    assert err == "neural-bake: error: USD output needs usd-core: pip install 'neural-bake[usd]' (Pixar's usd-core)\n"
    assert not out.exists()


def test_a_failed_usd_write_keeps_the_good_folder(models, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    assert run(["--sdf", models["sdf"], *BAKE, "--formats", "usd,usdz", "-o", str(out)], capsys)[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert "asset.glb" not in before and "asset.usdz" in before

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    from neural_bake.io import usd as usd_io

    monkeypatch.setattr(usd_io, "_material", disk_full)
    code, _, err = run(["--sdf", models["sdf"], *BAKE, "--formats", "usd", "-o", str(out)], capsys)
    assert code == 1 and err == f"neural-bake: error: {out}: No space left on device\n"
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_unwritable_output_is_one_line_exit_1(models):
    if os.geteuid() == 0 and shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: no way to be refused a write")
    prefix = ["setpriv", "--inh-caps=-dac_override,-dac_read_search",
              "--bounding-set=-dac_override,-dac_read_search"] if os.geteuid() == 0 else []
    locked = Path(tempfile.mkdtemp(prefix="nb-readonly-"))
    os.chmod(locked, 0o555)
    try:
        exe = Path(sys.executable).with_name("neural-bake")
        r = subprocess.run([*prefix, str(exe), "bake", "--sdf", models["sdf"], *BAKE, "--formats", "usd,usdz", "-o",
                            str(locked / "out")], capture_output=True, text=True, timeout=300)
        assert r.returncode == 1 and r.stderr == f"neural-bake: error: {locked / 'out'}: Permission denied\n"
        assert list(locked.iterdir()) == []
    finally:
        os.chmod(locked, 0o755)
        shutil.rmtree(locked, ignore_errors=True)
