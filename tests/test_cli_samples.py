"""`neural-bake samples`: writes loadable files, names and options, one-line errors."""

import subprocess
import sys
from pathlib import Path

import numpy as np

import neural_bake as nb
from neural_bake.cli.main import main
from neural_bake.samples import SAMPLES


def test_writes_the_named_samples(tmp_path, capsys):
    out = tmp_path / "new" / "dir"
    code = main(["samples", "--out", str(out), "--names", "sphere,torus", "--resolution", "400",
                 "--texture-size", "64"])
    assert code == 0
    printed = capsys.readouterr().out
    assert f"sphere: {out / 'sphere.obj'}" in printed and "torus:" in printed and "bumpy" not in printed
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == sorted(
        f"{n}.{e}" for n in ("sphere", "torus") for e in ("obj", "mtl", "png"))
    mesh = nb.load_mesh(out / "torus.obj")
    assert 300 <= mesh.n_faces <= 500 and mesh.texture.shape == (32, 64, 3) and mesh.watertight
    src = mesh.frame.to_source(mesh.vertices)
    assert np.abs(SAMPLES["torus"].sdf(src)).max() < 1e-5


def test_repeated_names_option(tmp_path):
    assert main(["samples", "--out", str(tmp_path), "--names", "sphere", "--names", "bumpy_sphere",
                 "--resolution", "200", "--texture-size", "32"]) == 0
    assert (tmp_path / "bumpy_sphere.obj").is_file() and (tmp_path / "sphere.png").is_file()


def test_unknown_name_is_a_one_line_error(tmp_path, capsys):
    code = main(["samples", "--out", str(tmp_path), "--names", "teapot"])
    assert code == 2
    err = capsys.readouterr().err
    assert err.strip() == ("neural-bake: error: unknown sample 'teapot' (known: sphere, bumpy_sphere, torus, jack, dots, "
                           "travelling_bumps, twisting_torus, splitting_sphere)")
    assert not any(tmp_path.iterdir())


def test_bad_resolution_and_out_is_a_file(tmp_path, capsys):
    assert main(["samples", "--out", str(tmp_path), "--resolution", "3"]) == 2
    assert "resolution must be an approximate face count >= 32, got 3" in capsys.readouterr().err
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["samples", "--out", str(f), "--names", "sphere"]) == 2  # click's own check
    assert "is a file" in capsys.readouterr().err
    assert main(["samples", "--out", str(tmp_path), "--texture-size", "2"]) == 2
    assert "texture size must be at least 8 texels, got 2" in capsys.readouterr().err


def test_console_script(tmp_path):
    exe = Path(sys.executable).with_name("neural-bake")
    r = subprocess.run([str(exe), "samples", "--out", str(tmp_path), "--names", "sphere", "--resolution", "100",
                        "--texture-size", "16"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "sphere.obj").is_file()
