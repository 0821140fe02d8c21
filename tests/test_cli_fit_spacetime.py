"""`neural-bake fit morph` / `fit sequence`: tiny end-to-end runs writing loadable space-time model files, the
frames.json folder form, and one-line errors."""

import importlib.util
import json

import numpy as np
import pytest

from neural_bake.cli.main import main
from neural_bake.errors import ModelFileError, TimeRangeError
from neural_bake.fit.spacetime import load_spacetime, parse_times
from neural_bake.samples import generate

TINY = ["--width", "16", "--depth", "1", "--steps", "30", "--pool", "3000", "--no-progress"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("shapes")
    written = generate(d, ["sphere", "torus", "splitting_sphere"], resolution=300, texture_size=16)
    return written


def test_fit_morph_writes_a_space_time_model(files, tmp_path, capsys):
    out = tmp_path / "morph.safetensors"
    assert main(["fit", "morph", str(files["sphere"]), str(files["torus"]), "-o", str(out), "--method",
                 "interpolate", *TINY]) == 0
    printed = capsys.readouterr().out
    assert "fit morph 16x1 (interpolate): 30 steps" in printed and "metrics at t = 1" in printed
    fit = load_spacetime(out)
    assert fit.kind == "morph" and fit.method == "interpolate" and fit.time_range == (0.0, 1.0)
    assert fit.model.in_dim == 4 and fit.steps == 30
    with pytest.raises(TimeRangeError, match=r"t = 2 is outside the fitted time range \[0, 1\]"):
        fit.at(2.0)


def test_fit_sequence_from_a_frames_folder_and_from_files(files, tmp_path, capsys):
    folder = files["splitting_sphere"]
    out = tmp_path / "seq.safetensors"
    assert main(["fit", "sequence", str(folder), "-o", str(out), "--no-metrics", *TINY]) == 0
    fit = load_spacetime(out)
    assert fit.kind == "sequence" and fit.times == [0.0, 0.25, 0.5, 0.75, 1.0] and fit.method == "interpolate"
    frames = sorted(folder.glob("*.obj"))[:2]
    assert main(["fit", "sequence", *map(str, frames), "--times", "2,5", "-o", str(out), "--no-metrics",
                 "--method", "eikonal", *TINY]) == 0
    fit = load_spacetime(out)
    assert fit.time_range == (2.0, 5.0) and fit.method == "eikonal"


def test_errors(files, tmp_path, capsys):
    a = str(files["sphere"])
    assert main(["fit", "sequence", a, a, "--times", "0:1:3", "-o", str(tmp_path / "m"), *TINY]) == 2
    assert capsys.readouterr().err.strip() == "neural-bake: error: --times: 3 times for 2 frames"
    assert main(["fit", "sequence", a, "--times", "zero", "-o", str(tmp_path / "m"), *TINY]) == 2
    assert "--times: 'zero' is not START:STOP:COUNT" in capsys.readouterr().err
    assert main(["fit", "morph", a, a, "-o", str(tmp_path / "missing" / "m"), *TINY]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["fit", "sequence", str(tmp_path), "-o", str(tmp_path / "m"), *TINY]) == 2
    assert "a folder without frames.json" in capsys.readouterr().err
    with pytest.raises(ModelFileError, match="not a space-time SDF model file"):
        from neural_bake.fields.files import save_model
        from neural_bake.nets.siren import Siren

        save_model(Siren(8, 1, in_dim=4), tmp_path / "x.safetensors", kind="sdf")
        load_spacetime(tmp_path / "x.safetensors")


def test_parse_times():
    np.testing.assert_allclose(parse_times("0:1:5"), [0, 0.25, 0.5, 0.75, 1])
    assert parse_times("3:9:1") == [3.0] and parse_times("0.5, 2") == [0.5, 2.0]
    for bad in ("0:1:0", "a,b", "0:1", "", "nan"):
        with pytest.raises(Exception, match="times"):
            parse_times(bad)


def test_bake_frames_verb(files, tmp_path, capsys):
    model = tmp_path / "seq.nbm"
    assert main(["fit", "sequence", str(files["splitting_sphere"]), "-o", str(model), "--no-metrics", "--width",
                 "32", "--depth", "1", "--steps", "150", "--lr", "1e-3", "--pool", "4000", "--no-progress"]) == 0
    out = tmp_path / "frames"
    assert main(["bake-frames", str(model), "--t", "0:1:3", "-o", str(out), "--resolution", "24"]) == 0
    assert "baked 3 frames" in capsys.readouterr().out
    assert sorted(p.name for p in out.glob("*.ply")) == [f"frame_{i:04d}.ply" for i in range(3)]
    if importlib.util.find_spec("pxr") is not None:  # usd-core is in the test extras: one stage, sizes stated
        anim = tmp_path / "anim"
        assert main(["bake-frames", str(model), "--t", "0:1:3", "-o", str(anim), "--resolution", "24", "--format",
                     "usd", "--fps", "12"]) == 0
        printed = capsys.readouterr().out
        sizes = json.loads((anim / "frames.json").read_text())["sizes"]
        assert f"frame.usd: {sizes['file_bytes'] / 1e6:.2f} MB (the 3 per-frame PLY files would be " \
               f"{sizes['ply_bytes'] / 1e6:.2f} MB, counted, not written); the network seq.nbm: " \
               f"{model.stat().st_size / 1e6:.2f} MB" in printed
        assert sorted(p.name for p in anim.iterdir() if not p.name.startswith(".")) == ["frame.usd", "frames.json"]
        assert main(["bake-frames", str(model), "--t", "0", "-o", str(anim), "--format", "usd", "--fps", "0"]) == 2
        assert capsys.readouterr().err == "neural-bake: error: --fps 0.0: must be a positive number of frames per " \
                                          "second\n"
    assert main(["bake-frames", str(model), "--t", "0,2", "-o", str(out)]) == 2
    assert "t = 2 is outside the fitted time range [0, 1]" in capsys.readouterr().err
    assert main(["bake-frames", str(files["sphere"]).replace(".obj", ".png"), "--t", "0", "-o", str(out)]) == 2
    capsys.readouterr()

    # --texture: a texture model (identity frame: its unit points are source points) gives per-vertex colours
    import torch
    import trimesh

    from neural_bake.fields import TextureField, save_field
    from neural_bake.io.colour import linear_to_srgb
    from neural_bake.nets.siren import Siren
    from neural_bake.types import Frame

    siren = Siren(8, 1, in_dim=3, out_dim=3, omega_0=3.0, generator=torch.Generator().manual_seed(1))
    tex = save_field(TextureField.from_model(siren, frame=Frame(), name="tex"), tmp_path / "tex.nbm")
    assert main(["bake-frames", str(model), "--t", "0,1", "-o", str(out), "--resolution", "24", "--texture",
                 str(tex)]) == 0
    for f in sorted(out.glob("*.ply")):
        tm = trimesh.load(f, process=False)
        with torch.no_grad():
            lin = siren(torch.as_tensor(np.asarray(tm.vertices), dtype=torch.float32)).double().numpy()
        want = np.round(linear_to_srgb(np.clip(lin, 0, 1)) * 255)
        assert np.abs(np.asarray(tm.visual.vertex_colors)[:, :3] - want).max() <= 1
    assert main(["bake-frames", str(model), "--t", "0", "-o", str(out), "--texture", str(model)]) == 2
    assert "not a texture model" in capsys.readouterr().err
