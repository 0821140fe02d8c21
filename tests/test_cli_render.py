"""`neural-bake render`: end to end on a small fitted sphere SDF; outputs, stats, scene files, errors."""

import json

import numpy as np
import pytest
import torch

from neural_bake.cli.main import main
from neural_bake.io.images import read_image
from neural_bake.fields import save_model
from neural_bake.nets.siren import Siren
from neural_bake.types import Frame


@pytest.fixture(scope="module")
def models(tmp_path_factory, fit_sphere_siren):
    """A sphere SDF (radius 0.7 in the unit frame; frame scale 0.5: radius 1.4 in source units) and a
    random texture network."""
    d = tmp_path_factory.mktemp("render_cli")
    frame = Frame((0.0, 0.0, 0.0), 0.5).to_dict()
    sdf = save_model(fit_sphere_siren(r=0.7, width=32, steps=300), d / "s.sdf", kind="sdf", frame=frame)
    tex = save_model(Siren(16, 1, out_dim=3, generator=torch.Generator().manual_seed(0)), d / "t.tex",
                     kind="texture", frame=frame)
    return {"sdf": str(sdf), "tex": str(tex), "dir": d}


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def run(args, capsys):
    code = main(["render", *args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_render_writes_the_image_channels_and_stats(models, tmp_path, capsys):
    out = tmp_path / "shot.png"
    code, stdout, err = run([models["sdf"], "-o", str(out), "--size", "48x40", "--camera", "0,0,6",
                             "--look-at", "0,0,0", "--fov", "35", "--channels", "color,depth,normal,hit,iterations",
                             "--stats", str(tmp_path / "stats.json")], capsys)
    assert code == 0, err
    for name in ("shot.png", "shot.depth.png", "shot.normal.png", "shot.hit.png", "shot.iterations.png"):
        assert (tmp_path / name).is_file(), name
    img = read_image(out)
    assert img.shape == (40, 48, 3)
    hit = read_image(tmp_path / "shot.hit.png", colour="data")[..., 0] > 0.5
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert stats["pixels"]["hit"] == int(hit.sum()) > 100
    ev = stats["evaluations"]["points"]
    assert set(ev) == {"f (32,1)"} and ev["f (32,1)"]["normals"] == int(hit.sum())
    assert set(stats["evaluations"]["totals"]) == {"trace", "normals"}
    # the sphere of radius 1.4 (source units) seen from 6 units away spans 2·asin(1.4/6) ≈ 27° of the 35° fov
    cols = np.nonzero(hit.any(axis=0))[0]
    assert abs((cols[-1] - cols[0] + 1) - 40 * 2 * np.degrees(np.arcsin(1.4 / 6)) / 35) <= 2.5
    assert img[~hit].min() > 0.99  # white background


def test_texture_adds_only_texture_evaluations(models, tmp_path, capsys):
    args = [models["sdf"], "--size", "32", "--stats"]
    code, _, err = run([*args, str(tmp_path / "a.json"), "-o", str(tmp_path / "a.png")], capsys)
    assert code == 0, err
    code, _, err = run([*args, str(tmp_path / "b.json"), "-o", str(tmp_path / "b.png"), "--texture", models["tex"]],
                       capsys)
    assert code == 0, err
    a = json.loads((tmp_path / "a.json").read_text())["evaluations"]["points"]
    b = json.loads((tmp_path / "b.json").read_text())["evaluations"]["points"]
    tex_name = next(k for k in b if k.startswith("texture"))
    assert b[tex_name] == {"texture": json.loads((tmp_path / "b.json").read_text())["pixels"]["hit"]}
    assert {k: v for k, v in b.items() if k != tex_name} == a


def test_scene_file_and_exr_channels(models, tmp_path, capsys):
    scene = tmp_path / "scene.toml"
    scene.write_text('effects = ["shading", "shadows"]\nchannels = ["color", "depth"]\n'
                     '[camera]\nposition = [0, 1, 6]\nwidth = 24\nheight = 24\n[trace]\nmode = "fixed"\n'
                     'iterations = [40]\n')
    out = tmp_path / "s.png"
    code, _, err = run([models["sdf"], "-o", str(out), "--scene", str(scene), "--channel-format", "exr",
                        "--stats", str(tmp_path / "s.json")], capsys)
    assert code == 0, err
    depth = read_image(tmp_path / "s.depth.exr")
    hit = depth[..., 0] > 0
    assert hit.any() and depth.shape[:2] == (24, 24)
    # depth is the distance from the eye: at least |eye| − radius
    assert depth[hit].min() > np.hypot(1, 6) - 1.4 - 0.05
    stats = json.loads((tmp_path / "s.json").read_text())
    assert stats["mode"] == "fixed" and stats["evaluations"]["totals"]["shadows"] > 0


@pytest.mark.parametrize("extra, match", [
    (["--effects", "sparkle"], "unknown"),
    (["--channels", "alpha"], "unknown channel 'alpha'"),
    (["--size", "0"], "--size"),
    (["--camera", "1,2"], "--camera: expected X,Y,Z"),
    (["--iterations", "a,b"], "--iterations"),
    (["--effects", "texture"], "no texture field"),
    (["--iterations", "10,10"], "2 values for 1 levels"),
])
def test_bad_options_exit_2_with_one_line(models, tmp_path, capsys, extra, match):
    code, _, err = run([models["sdf"], "-o", str(tmp_path / "x.png"), "--size", "8", *extra], capsys)
    assert code == 2 and match in err and err.count("\n") == 1
    assert not (tmp_path / "x.png").exists()


def test_bad_inputs_exit_2(models, tmp_path, capsys):
    code, _, err = run([str(tmp_path / "none.sdf"), "-o", str(tmp_path / "x.png")], capsys)
    assert code == 2 and "no such model file" in err
    code, _, err = run([models["tex"], "-o", str(tmp_path / "x.png")], capsys)
    assert code == 2 and "texture field" in err
    code, _, err = run([models["sdf"], "-o", str(tmp_path / "x.gif")], capsys)
    assert code == 2 and "space-time" in err
    code, _, err = run([models["sdf"], "-o", str(tmp_path / "missing" / "x.png"), "--size", "8"], capsys)
    assert code == 2 and "does not exist" in err
    code, _, err = run([models["sdf"], "-o", str(tmp_path / "x.png"), "--scene", str(tmp_path / "no.toml")], capsys)
    assert code == 2 and "no such scene file" in err


def test_nested_sequence_file_renders_with_normal_mapping(tmp_path, capsys, fit_sphere_siren):
    from neural_bake.fields import NestedSequence

    levels = [fit_sphere_siren(r=0.7, width=8, steps=150), fit_sphere_siren(r=0.7, width=32, steps=300)]
    path = tmp_path / "s.nested"
    NestedSequence(levels=levels, frame=Frame(), levels_info=[{"delta": 0.06}, {"delta": 0.001}]).save(path)
    stats = tmp_path / "n.json"
    code, _, err = run([str(path), "-o", str(tmp_path / "n.png"), "--size", "24", "--mode", "fixed",
                        "--iterations", "40,0", "--effects", "shading,normal_mapping", "--stats", str(stats)], capsys)
    assert code == 0, err
    s = json.loads(stats.read_text())
    pts = s["evaluations"]["points"]
    assert set(pts) == {"h1 (8,1)", "f (32,1)"}
    assert pts["f (32,1)"] == {"normal_mapping": s["pixels"]["hit"]} and s["pixels"]["hit"] > 0
    assert set(pts["h1 (8,1)"]) == {"trace"}
    # δ overrides from a scene file: a δ per level
    scene = tmp_path / "d.toml"
    scene.write_text(f'[[objects]]\nmodel = "{path}"\ndeltas = [0.0, 0.0]\n')
    code, _, err = run([str(path), "-o", str(tmp_path / "d.png"), "--size", "16", "--scene", str(scene)], capsys)
    assert code == 0, err


def test_print_config_is_the_resolved_scene_and_renders_the_same_image(models, tmp_path, capsys):
    import tomllib

    opts = ["--size", "40x32", "--fov", "30", "--effects", "shading,shadows", "--iterations", "40", "--mode",
            "fixed"]
    code, text, err = run([models["sdf"], *opts, "--print-config"], capsys)
    assert code == 0, err
    scene = tomllib.loads(text)
    assert scene["effects"] == ["shading", "shadows"] and scene["trace"]["iterations"] == [40]
    assert (scene["camera"]["width"], scene["camera"]["height"], scene["camera"]["fov_deg"]) == (40, 32, 30.0)
    f = tmp_path / "scene.toml"
    f.write_text(text)
    code, again, err = run([models["sdf"], "--config", str(f), "--print-config"], capsys)
    assert code == 0 and again == text, err
    assert run([models["sdf"], *opts, "-o", str(tmp_path / "a.png")], capsys)[0] == 0
    assert run([models["sdf"], "--config", str(f), "-o", str(tmp_path / "b.png")], capsys)[0] == 0
    assert np.array_equal(read_image(tmp_path / "a.png"), read_image(tmp_path / "b.png"))
    # options override the file; a bad key is one line naming the file and the key
    code, text, err = run([models["sdf"], "--config", str(f), "--effects", "shading", "--print-config"], capsys)
    assert code == 0 and tomllib.loads(text)["effects"] == ["shading"]
    f.write_text("effekts = ['shading']\n")
    code, _, err = run([models["sdf"], "--config", str(f), "--print-config"], capsys)
    assert code == 2 and err.startswith(f"neural-bake: error: {f}: unknown key 'effekts'") and err.count("\n") == 1
    code, _, err = run([models["sdf"]], capsys)
    assert code == 2 and "missing -o/--output" in err


@pytest.fixture(scope="module")
def growing(models):
    """A space-time file f(x, t) = g(x) − c·sin(sin(τ)), τ = 2t − 1 over the time range [0, 1], built exactly
    from the fitted sphere g (radius 0.7) by one more neuron per layer carrying τ: the radius grows with t."""
    from neural_bake.fields import NestedSequence, load_field

    g = load_field(models["sdf"]).model
    w, d = g.width, g.depth
    net = Siren(w + 1, d, in_dim=4, omega_0=g.omega_0, hidden_omega=g.hidden_omega)
    c = 0.15 / np.sin(np.sin(1.0))  # radius 0.55 at t = 0, 0.85 at t = 1 (unit frame)
    with torch.no_grad():
        for i, (new, old) in enumerate(zip(net.layers, g.layers)):
            new.weight.zero_()
            new.bias.zero_()
            new.weight[:old.out_features, :old.in_features] = old.weight
            new.bias[:old.out_features] = old.bias
            if i == 0:
                new.weight[w, 3] = 1.0 / g.omega_0  # sin(τ)
            elif i < len(net.layers) - 1:
                new.weight[w, w] = 1.0 / g.hidden_omega  # sin(sin(τ))
            else:
                new.weight[0, w] = -c
    path = models["dir"] / "grow.nested"
    NestedSequence(levels=[net], frame=Frame((0.0, 0.0, 0.0), 0.5), levels_info=[{"delta": 0.0}],
                   metadata={"spacetime": {"time_range": [0.0, 1.0], "time_extent": 1.0}}).save(path)
    return str(path)


def test_one_time_of_a_space_time_model_is_a_still_with_its_channels(growing, tmp_path, capsys):
    opts = ["--size", "24", "--channels", "color,depth,hit", "--channel-format", "exr"]
    code, _, err = run([growing, "-o", str(tmp_path / "one.png"), "--t", "0.75", *opts,
                        "--stats", str(tmp_path / "one.json")], capsys)
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "cache") == [
        "one.depth.exr", "one.hit.exr", "one.json", "one.png"]
    stats = json.loads((tmp_path / "one.json").read_text())
    hit = read_image(tmp_path / "one.hit.exr", colour="data")[..., 0] > 0.5
    assert stats["time"] == 0.75 and stats["pixels"]["hit"] == int(hit.sum()) > 0
    # the same time through the frames path gives the same numbers
    frames = tmp_path / "frames"
    code, _, err = run([growing, "-o", str(frames), "--t", "0.25,0.75", *opts], capsys)
    assert code == 0, err
    for c in ("png", "depth.exr", "hit.exr"):
        np.testing.assert_allclose(read_image(frames / f"frame_0001.{c}", colour="data"),
                                   read_image(tmp_path / f"one.{c}", colour="data"), atol=1e-5)
    before = read_image(frames / "frame_0000.hit.exr", colour="data")[..., 0] > 0.5
    depth = [read_image(frames / f"frame_{i:04d}.depth.exr", colour="data")[..., 0] for i in (0, 1)]
    assert before.sum() < hit.sum() and (before <= hit).all()  # the sphere grows with t …
    assert depth[0][12, 12] > depth[1][12, 12] > 0  # … towards the eye


def test_channels_of_an_animation_go_beside_its_frames(growing, tmp_path, capsys):
    import imageio.v3 as iio

    from neural_bake.io.outdir import MANIFEST

    code, _, err = run([growing, "-o", str(tmp_path / "a.gif"), "--t", "0:1:2", "--size", "16",
                        "--channels", "color,hit,depth"], capsys)
    assert code == 0, err
    names = sorted(f"frame_{i:04d}.{c}.png" for i in (0, 1) for c in ("hit", "depth")) + [
        "frame_0000.png", "frame_0001.png"]
    listed = json.loads((tmp_path / "a_frames" / MANIFEST).read_text())["files"]
    assert sorted(listed) == sorted(names) == sorted(p.name for p in (tmp_path / "a_frames").iterdir()
                                                     if p.name != MANIFEST)
    assert iio.imread(tmp_path / "a.gif", index=None).shape[:3] == (2, 16, 16)


@pytest.mark.parametrize("extra, match", [
    (["--t", "0:1:3"], "-o {out}: an image holds one time; 3 times of a space-time model go to a folder"),
    ([], "-o {out}: an image holds one time; 24 times"),
    (["--t", "2"], "--t = 2 is outside the fitted time range [0, 1]"),
    (["--t", "0.5", "--time-range", "0,3"], "--time-range: t = 3 is outside the fitted time range [0, 1]"),
])
def test_times_an_image_cannot_hold_exit_2_with_one_line(growing, tmp_path, capsys, extra, match):
    out = tmp_path / "x.png"
    code, _, err = run([growing, "-o", str(out), "--size", "8", *extra], capsys)
    assert code == 2 and err.count("\n") == 1 and match.format(out=out) in err, err
    assert not out.exists()


def test_a_space_time_model_with_a_feature_grid_texture_renders_its_colours(growing, models, tmp_path, capsys):
    """A grid texture network (not a SIREN) beside a space-time SDF is read through its field's colours: the
    hit pixels take its colour (a constant one here: the grid's output bias), the background stays."""
    from neural_bake.nets.grid import GridNet

    net = GridNet(levels=2, features=2, log2_table=6, base_resolution=2, max_resolution=4, width=8, depth=1,
                  generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
        net.layers[-1].bias.copy_(torch.tensor([0.9, 0.2, 0.1]))
    tex = save_model(net, tmp_path / "g.tex", kind="texture", frame=Frame((0.0, 0.0, 0.0), 0.5).to_dict())
    code, _, err = run([growing, "-o", str(tmp_path / "g.png"), "--t", "0.5", "--size", "24", "--texture", str(tex),
                        "--effects", "texture", "--channels", "color,hit", "--channel-format", "exr"], capsys)
    assert code == 0, err
    img = read_image(tmp_path / "g.png")
    hit = read_image(tmp_path / "g.hit.exr", colour="data")[..., 0] > 0.5
    assert hit.sum() > 0 and np.ptp(img[hit][:, :3], axis=0).max() < 1e-6  # one colour over the sphere


def _tiled_sphere(fit_sphere_siren, scale):
    """The fixture's sphere SIREN as the coarse level of a tiled SDF whose tiles (a 4³ grid over the sphere) add
    ``scale`` × a random residual (0: the sphere itself)."""
    from neural_bake.nets.tiles import TiledSdf, TileGrid, TiledSiren

    gen = torch.Generator().manual_seed(3)
    tiles = TiledSiren(TileGrid([-0.8, -0.8, -0.8], 0.4, 4, 0.1, torch.arange(64)), 8, 1, zero_output=False,
                       generator=gen)
    with torch.no_grad():
        tiles.weights[-1].mul_(scale)
        tiles.biases[-1].mul_(scale)
    return TiledSdf(fit_sphere_siren(r=0.7, width=32, steps=300), tiles).eval()


@pytest.mark.parametrize("mode", [[], ["--guaranteed"], ["--no-skip"]])
def test_render_draws_a_tiled_sdf(models, fit_sphere_siren, tmp_path, capsys, mode):
    frame = Frame((0.0, 0.0, 0.0), 0.5).to_dict()
    same = save_model(_tiled_sphere(fit_sphere_siren, 0.0), tmp_path / "t0.sdf", kind="sdf", frame=frame)
    view = ["--size", "32", "--camera", "0,0,6", "--look-at", "0,0,0", "--channels", "color,hit"]
    code, _, err = run([models["sdf"], "-o", str(tmp_path / "s.png"), *view, *mode], capsys)
    assert code == 0, err
    code, _, err = run([str(same), "-o", str(tmp_path / "t0.png"), *view, "--stats", str(tmp_path / "st.json"),
                        *mode], capsys)
    assert code == 0, err
    # a tile level of zeros: the sphere SIREN's image
    hit_s = read_image(tmp_path / "s.hit.png", colour="data")[..., 0] > 0.5
    hit_t = read_image(tmp_path / "t0.hit.png", colour="data")[..., 0] > 0.5
    assert hit_s.sum() > 100 and (hit_s == hit_t).all()
    assert np.abs(read_image(tmp_path / "s.png") - read_image(tmp_path / "t0.png")).max() < 2e-3
    stats = json.loads((tmp_path / "st.json").read_text())
    assert set(stats["evaluations"]["points"]) == {"f 32x1+64x(8x1)"}
    # tiles that move the surface: still drawn, the silhouette moved a little
    moved = save_model(_tiled_sphere(fit_sphere_siren, 0.05), tmp_path / "t1.sdf", kind="sdf", frame=frame)
    code, _, err = run([str(moved), "-o", str(tmp_path / "t1.png"), *view, *mode], capsys)
    assert code == 0, err
    hit_m = read_image(tmp_path / "t1.hit.png", colour="data")[..., 0] > 0.5
    assert 0 < (hit_m != hit_s).sum() < 0.2 * hit_s.sum()
