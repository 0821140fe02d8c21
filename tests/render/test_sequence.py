"""Dynamic previews: an analytic space-time SDF (a sphere morphing into a torus) → numbered PNGs + GIF/MP4."""

import json

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from neural_bake.cli.main import main
from neural_bake.errors import TimeRangeError
from neural_bake.io.colour import linear_to_srgb
from neural_bake.io.images import read_image
from neural_bake.io.outdir import MANIFEST
from neural_bake.nets.siren import Siren
from neural_bake.render.asset import RenderAsset, RenderError, SpaceTimeAsset, analytic_level
from neural_bake.render.camera import Camera
from neural_bake.render.renderer import render
from neural_bake.render.scene import Scene
from neural_bake.render.sequence import frame_times, render_sequence, render_time
from neural_bake.types import Frame

from render_cases import exact_sphere_hits

CAM = Camera(position=(0.0, 0.0, 2.5), width=32, height=32)


def _sphere(p):
    return p.norm(dim=1) - 0.5


def _torus(p):  # around the view axis z: seen from +z, a ring with a hole
    q = torch.stack([p[:, :2].norm(dim=1) - 0.5, p[:, 2]], 1)
    return q.norm(dim=1) - 0.2


def morph() -> SpaceTimeAsset:
    """f(x, t) = (1 − t) sphere + t torus: 1-Lipschitz at every t (a convex mix of distance functions)."""
    return SpaceTimeAsset(lambda t: RenderAsset([analytic_level(lambda p: (1 - t) * _sphere(p) + t * _torus(p),
                                                                name="morph")]), (0.0, 1.0))


def test_frames_and_gif_of_a_sphere_morphing_into_a_torus(tmp_path):
    seen = []
    res = render_sequence(morph(), Scene(camera=CAM, skip=False, effects=()), tmp_path / "frames", frames=4,
                          animation=tmp_path / "morph.gif", fps=8, progress=lambda i, n, s: seen.append((i, n)))
    assert [p.name for p in res.frames] == [f"frame_{i:04d}.png" for i in range(4)]
    assert res.times == [0.0, 1 / 3, 2 / 3, 1.0] and seen == [(i, 4) for i in range(1, 5)]
    first = read_image(res.frames[0])
    last = read_image(res.frames[-1])
    sphere_hit, _ = exact_sphere_hits(CAM, 0.5)
    assert np.array_equal(first.min(axis=-1) < 0.99, sphere_hit)  # flat albedo on a white background
    centre = last[14:18, 14:18].min(axis=-1)  # the torus's hole shows the background
    assert (centre > 0.99).all() and (first[14:18, 14:18].min(axis=-1) < 0.99).all()
    gif = iio.imread(tmp_path / "morph.gif", index=None)
    assert gif.shape[0] == 4 and gif.shape[1:3] == (32, 32)
    assert res.stats["evaluations"]["totals"]["trace"] > 0 and len(res.stats["frames"]) == 4


def test_mp4_animation(tmp_path):
    res = render_sequence(morph(), Scene(camera=CAM, skip=False), tmp_path / "f", frames=3,
                          animation=tmp_path / "m.mp4")
    frames = iio.imread(tmp_path / "m.mp4", index=None, plugin="FFMPEG")
    assert frames.shape[0] == 3 and res.animation.stat().st_size > 0


def test_a_failed_sequence_leaves_the_old_frames(tmp_path):
    out = tmp_path / "frames"
    render_sequence(morph(), Scene(camera=CAM, skip=False), out, frames=2)
    before = sorted(p.name for p in out.iterdir())

    def broken(t):
        if t > 0.5:
            raise RenderError("broken frame")
        return morph().at(t)

    with pytest.raises(RenderError, match="broken frame"):
        render_sequence(SpaceTimeAsset(broken, (0.0, 1.0)), Scene(camera=CAM, skip=False), out, frames=3)
    assert sorted(p.name for p in out.iterdir()) == before
    assert [p.name for p in tmp_path.iterdir()] == ["frames"]  # no temporary folder left


def test_frames_through_a_symlinked_folder_replace_its_targets_frames_and_keep_the_link(tmp_path):
    target, link = tmp_path / "frames", tmp_path / "latest"
    render_sequence(morph(), Scene(camera=CAM, skip=False), target, frames=3)
    link.symlink_to("frames")
    res = render_sequence(morph(), Scene(camera=CAM, skip=False), link, frames=2)
    assert link.is_symlink() and res.frames == [link / "frame_0000.png", link / "frame_0001.png"]
    assert sorted(p.name for p in target.iterdir() if not p.name.startswith(".")) == ["frame_0000.png",
                                                                                      "frame_0001.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames", "latest"]  # no staging or old set left


@pytest.mark.parametrize("kwargs, match", [
    (dict(frames=0), "frames"),
    (dict(animation="a.avi"), "unknown animation format"),
    (dict(fps=0), "fps"),
])
def test_bad_sequence_settings(tmp_path, kwargs, match):
    if "animation" in kwargs:
        kwargs["animation"] = tmp_path / kwargs["animation"]
    with pytest.raises(RenderError, match=match):
        render_sequence(morph(), Scene(camera=CAM), tmp_path / "f", **kwargs)
    with pytest.raises(RenderError, match="space-time asset"):
        render_sequence(morph().at(0.0), Scene(camera=CAM), tmp_path / "f")
    with pytest.raises(RenderError, match="time_range"):
        SpaceTimeAsset(lambda t: None, (1.0, 0.0))
    assert frame_times(1, (0.2, 0.9)) == [0.2]


def test_cli_renders_a_space_time_network(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    from neural_bake.fields import NestedSequence

    nets = [Siren(w, 1, in_dim=4, omega_0=5.0, generator=torch.Generator().manual_seed(w)) for w in (8, 16)]
    path = tmp_path / "st.nested"  # a space-time nested sequence: 4-input networks with their time mapping animate
    NestedSequence(levels=nets, frame=Frame(), levels_info=[{"delta": 0.05}, {"delta": 0.001}],
                   metadata={"spacetime": {"time_range": [0.0, 1.0], "time_extent": 1.0}}).save(path)
    code = main(["render", str(path), "-o", str(tmp_path / "a.gif"), "--frames", "3", "--size", "16",
                 "--time-range", "0,0.5", "--stats", str(tmp_path / "a.json")])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert sorted(p.name for p in (tmp_path / "a_frames").iterdir() if p.name != MANIFEST) == [
        f"frame_{i:04d}.png" for i in range(3)]
    assert iio.imread(tmp_path / "a.gif", index=None).shape[0] == 3
    assert "frame 3/3" in captured.err
    code = main(["render", str(path), "-o", str(tmp_path / "a.png")])
    assert code == 2 and "space-time" in capsys.readouterr().err


def test_space_time_levels_fix_time():
    net = Siren(8, 0, in_dim=4, generator=torch.Generator().manual_seed(0))
    from neural_bake.render.asset import siren_level

    x = torch.rand(5, 3)
    lv = siren_level(net, time=0.25)
    want = net(torch.cat([x, torch.full((5, 1), 0.25)], 1)).detach()[:, 0]
    torch.testing.assert_close(lv.value(x), want)
    v, g = lv.value_and_gradient(x)
    torch.testing.assert_close(v, want) and g.shape == (5, 3)
    r = render(RenderAsset([lv]), Scene(camera=Camera(width=4, height=4), channels=("color",)))
    assert np.isfinite(r["color"]).all()


CAM24 = Camera(position=(0.0, 0.0, 2.5), width=24, height=24)


def grow() -> SpaceTimeAsset:
    """f(x, t) = |x| − (0.3 + 0.3 t): a sphere whose radius grows from 0.3 to 0.6 over [0, 1]."""
    return SpaceTimeAsset(lambda t: RenderAsset([analytic_level(lambda p: p.norm(dim=1) - (0.3 + 0.3 * t),
                                                                name="grow")]), (0.0, 1.0))


def test_frames_carry_their_channels_and_match_single_time_renders(tmp_path):
    scene = Scene(camera=CAM24, skip=False, effects=(), channels=("color", "depth", "hit"))
    res = render_sequence(grow(), scene, tmp_path / "grow_frames", frames=3, animation=tmp_path / "grow.gif",
                          channel_format="exr")
    names = [f"frame_{i:04d}.{c}" for i in range(3) for c in ("png", "depth.exr", "hit.exr")]
    on_disk = sorted(p.name for p in (tmp_path / "grow_frames").iterdir())
    assert on_disk == sorted(names + [MANIFEST])
    listed = json.loads((tmp_path / "grow_frames" / MANIFEST).read_text())["files"]
    assert sorted(listed) == sorted(names)  # the channel files are part of the committed set
    assert res.channels == {c: [tmp_path / "grow_frames" / f"frame_{i:04d}.{c}.exr" for i in range(3)]
                            for c in ("depth", "hit")}
    gif = iio.imread(tmp_path / "grow.gif", index=None)
    assert gif.shape[:3] == (3, 24, 24)  # the animation is the colour frames alone
    areas, centre = [], []
    for i, t in enumerate(res.times):
        hit = read_image(res.channels["hit"][i], colour="data")[..., 0] > 0.5
        depth = read_image(res.channels["depth"][i], colour="data")[..., 0]
        want_hit, want_t = exact_sphere_hits(CAM24, 0.3 + 0.3 * t)
        assert np.array_equal(hit, want_hit)
        np.testing.assert_allclose(depth[hit], want_t[hit], atol=2e-3)
        assert (depth[~hit] == 0).all()
        areas.append(int(hit.sum()))
        centre.append(float(depth[12, 12]))
        one = render_time(grow(), scene, t)  # the same time rendered alone gives the same numbers
        assert one.stats["time"] == t and np.array_equal(one["hit"], hit)
        np.testing.assert_array_equal(np.where(one["hit"], one["depth"], 0).astype(np.float32), depth)
        np.testing.assert_array_equal(np.round(read_image(res.frames[i], colour="data") * 255),
                                      np.round(np.clip(linear_to_srgb(np.clip(one["color"], 0, 1)), 0, 1) * 255))
    assert areas[0] < areas[1] < areas[2]  # the sphere grows …
    assert centre[0] > centre[1] > centre[2]  # … towards the eye


def test_png_channels_of_frames_and_the_default_camera(tmp_path):
    scene = Scene(skip=False, effects=(), channels=("color", "hit", "depth"))
    res = render_sequence(grow(), scene, tmp_path / "f", times=[0.0, 1.0], size=(24, 16))
    assert sorted(res.channels) == ["depth", "hit"] and len(res.channels["hit"]) == 2
    hits = [read_image(p, colour="data")[..., 0] > 0.5 for p in res.channels["hit"]]
    assert hits[0].shape == (16, 24) and hits[0].sum() < hits[1].sum() and (hits[0] <= hits[1]).all()
    one = render_time(grow(), scene, 1.0, size=(24, 16))  # the camera framing the asset is the sequence's
    assert np.array_equal(one["hit"], hits[1])


def test_single_time_and_channel_errors(tmp_path):
    scene = Scene(camera=CAM24, skip=False)
    with pytest.raises(TimeRangeError, match=r"^t = 1.5 is outside the fitted time range \[0, 1\]$"):
        render_time(grow(), scene, 1.5)
    with pytest.raises(RenderError, match="^t nan: must be a finite number"):
        render_time(grow(), scene, float("nan"))
    with pytest.raises(RenderError, match="space-time asset"):
        render_time(grow().at(0.0), scene, 0.0)
    with pytest.raises(RenderError, match="^channel_format 'tif'"):
        render_sequence(grow(), scene, tmp_path / "f", frames=2, channel_format="tif")
    with pytest.raises(RenderError, match="must ask for the color channel"):
        render_sequence(grow(), scene.with_(channels=("depth",)), tmp_path / "f", frames=2)
    assert list(tmp_path.iterdir()) == []  # refused before any output
