"""Per-frame baking of a space-time SDF: numbered PLY/GLB frames whose vertices lie on f(·, t) = 0 and whose
normals are ∇f(·, t) at the same t; TimeRangeError before anything is written; the folder is a unit."""

import json

import numpy as np
import pytest
import torch
import trimesh

from neural_bake.bake.export import read_glb
from neural_bake.bake.frames import bake_frames
from neural_bake.errors import NeuralBakeError, TimeRangeError
from neural_bake.fit.spacetime import fit_sequence
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.samples import ANIMATED


@pytest.fixture(scope="module")
def splitting():
    anim = ANIMATED["splitting_sphere"]
    frames = [mesh_from_arrays(*anim.mesh(t, 600)) for t in (0.0, 0.5, 1.0)]
    return anim, fit_sequence(frames, [0.0, 0.5, 1.0], width=32, depth=1, lr=1e-3, steps=200, progress=False,
                              pool_surface=6000, pool_near=6000, pool_uniform=1500, batch=1024, batch_near=1024,
                              batch_uniform=256, batch_between=512)


def test_ply_frames_follow_the_field_at_each_t(splitting, tmp_path):
    anim, fit = splitting
    out = tmp_path / "frames"
    res = bake_frames(fit.at, fit.at, fit.frame, [0.0, 0.5, 1.0], out, resolution=40, pruned=False)
    assert [f.name for f in res.files] == [f"frame_{i:04d}.ply" for i in range(3)]
    index = json.loads((out / "frames.json").read_text())
    assert index["times"] == [0.0, 0.5, 1.0] and len(index["stats"]) == 3
    for t, f in zip(res.times, res.files):
        tm = trimesh.load(f, process=False)
        unit = fit.frame.to_unit(np.asarray(tm.vertices, dtype=np.float64))
        sl = fit.at(t)
        with torch.no_grad():
            v = sl(torch.as_tensor(unit, dtype=torch.float32))[:, 0].numpy()
        assert np.abs(v).max() < 0.02  # marching-cubes vertices on the zero set (linear interpolation error)
        # the written normals are ∇f(·, t) normalised at the vertices
        from neural_bake.nets.gemm import gemm_gradient

        _, g = gemm_gradient(sl, torch.as_tensor(unit, dtype=torch.float32))
        g = g.double().numpy()
        g /= np.linalg.norm(g, axis=1, keepdims=True)
        n = np.asarray(tm.vertex_normals)  # trimesh reads the PLY's nx ny nz
        assert np.mean((n * g).sum(1) > 0.999) > 0.99
        # against the analytic animation
        assert np.median(np.abs(anim.sdf(np.asarray(tm.vertices), t))) < 0.03
    assert len(trimesh.load(res.files[-1]).split(only_watertight=False)) == 2


def test_glb_frames_and_errors(splitting, tmp_path):
    _, fit = splitting
    out = tmp_path / "glb"
    res = bake_frames(fit.at, fit.at, fit.frame, [1.0], out, resolution=24, fmt="glb", pruned=False)
    _, arrays, _ = read_glb(res.files[0])
    assert arrays["POSITION"].shape[0] == res.stats[0]["vertices"] and "NORMAL" in arrays
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(TimeRangeError, match=r"t = 1.5 is outside the fitted time range \[0, 1\]"):
        bake_frames(fit.at, fit.at, fit.frame, [0.5, 1.5], out, resolution=24)
    assert sorted(p.name for p in out.iterdir()) == before  # the old set is untouched
    with pytest.raises(NeuralBakeError, match="fmt: expected one of ply, glb"):
        bake_frames(fit.at, fit.at, fit.frame, [0.0], out, fmt="obj")
    with pytest.raises(NeuralBakeError, match="does not exist"):
        bake_frames(fit.at, fit.at, fit.frame, [0.0], tmp_path / "no" / "dir")
    with pytest.raises(NeuralBakeError, match=r"t = 1: march: the level set f = 0 does not cross the grid"):
        bake_frames(lambda t: _shifted(fit.at(t)), fit.at, fit.frame, [1.0], out, resolution=24, pruned=False)
    assert sorted(p.name for p in out.iterdir()) == before
    with pytest.raises(NeuralBakeError, match="times: give at least one frame time"):
        bake_frames(fit.at, fit.at, fit.frame, [], out)


def _shifted(model):
    """The model plus 10: a field without a zero crossing."""
    with torch.no_grad():
        model.layers[-1].bias.add_(10.0)
    return model


def _albedo_field(anim, fit, t):
    """The animation's analytic colour g(·, t) as a texture field in the fit's unit frame."""
    from neural_bake.fields.texture import TextureField

    def fn(p):
        return torch.as_tensor(anim.albedo(fit.frame.to_source(p.double().cpu().numpy()), t))

    return TextureField(fn, frame=fit.frame, name=f"albedo t={t:g}")


def test_frames_carry_the_colours_of_a_space_time_texture_at_each_t(splitting, tmp_path):
    from neural_bake.io.colour import linear_to_srgb

    anim, fit = splitting
    out = tmp_path / "colours"
    res = bake_frames(fit.at, fit.at, fit.frame, [0.0, 1.0], out, resolution=32, pruned=False,
                      texture=lambda t: _albedo_field(anim, fit, t))
    assert all(s["colours_s"] >= 0 for s in res.stats)
    for t, f in zip(res.times, res.files):
        tm = trimesh.load(f, process=False)
        v = np.asarray(tm.vertices, dtype=np.float64)
        want = np.round(linear_to_srgb(anim.albedo(v, t)) * 255)
        got = np.asarray(tm.visual.vertex_colors)[:, :3].astype(np.float64)
        assert got.shape == want.shape and np.abs(got - want).max() <= 1  # 8-bit sRGB of g(vertex, t)
    # the colour moves with each ball: a static field of position would not give the same colours at t = 1
    v1 = np.asarray(trimesh.load(res.files[1], process=False).vertices, dtype=np.float64)
    assert np.abs(anim.albedo(v1, 1.0) - anim.albedo(v1, 0.0)).max() > 0.2

    glb = bake_frames(fit.at, fit.at, fit.frame, [0.5], tmp_path / "glb", resolution=24, fmt="glb", pruned=False,
                      texture=_albedo_field(anim, fit, 0.5))  # one static field: evaluated on the moving surface
    _, arrays, _ = read_glb(glb.files[0])
    # linear COLOR_0 at the source-frame positions
    np.testing.assert_allclose(arrays["COLOR_0"][:, :3], anim.albedo(arrays["POSITION"].astype(np.float64), 0.5),
                               atol=1e-5)


def test_texture_errors_leave_the_old_frames(splitting, tmp_path):
    anim, fit = splitting
    out = tmp_path / "frames"
    bake_frames(fit.at, fit.at, fit.frame, [0.0], out, resolution=16, pruned=False)
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(NeuralBakeError, match="texture: at t = 0 expected a TextureField, got str"):
        bake_frames(fit.at, fit.at, fit.frame, [0.0], out, resolution=16, texture=lambda t: "red")
    from neural_bake.fields.texture import TextureField

    two = TextureField(lambda p: p[:, :2], name="two")
    with pytest.raises(NeuralBakeError, match=r"texture: two gives \(2,\) values per point, expected 3 or 4"):
        bake_frames(fit.at, fit.at, fit.frame, [0.0], out, resolution=16, texture=two)
    assert sorted(p.name for p in out.iterdir()) == before


def test_usd_frames_are_one_stage_equal_to_the_ply_frames_at_each_time(splitting, tmp_path, monkeypatch):
    pytest.importorskip("pxr", reason="usd-core (the extra usd) is in the test extras")
    import sys

    from pxr import Usd, UsdGeom, UsdValidation

    from neural_bake.errors import MissingExtraError

    anim, fit = splitting
    times = [0.0, 0.5, 1.0]
    texture = lambda t: _albedo_field(anim, fit, t)  # noqa: E731
    ply = bake_frames(fit.at, fit.at, fit.frame, times, tmp_path / "ply", resolution=24, pruned=False, texture=texture)
    res = bake_frames(fit.at, fit.at, fit.frame, times, tmp_path / "usd", resolution=24, pruned=False, fmt="usd",
                      fps=30, texture=texture)
    assert [f.name for f in res.files] == ["frame.usd"] and res.times == times
    assert sorted(p.name for p in (tmp_path / "usd").iterdir() if not p.name.startswith(".")) == ["frame.usd",
                                                                                                 "frames.json"]
    # the per-frame PLY size it reports is what the PLY frames take on disk
    assert res.sizes["ply_bytes"] == sum(f.stat().st_size for f in ply.files) == ply.sizes["file_bytes"]
    assert res.sizes["file_bytes"] == res.files[0].stat().st_size
    index = json.loads((tmp_path / "usd" / "frames.json").read_text())
    assert index["format"] == "usd" and index["sizes"] == res.sizes
    context = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    stage = Usd.Stage.Open(str(res.files[0]))
    assert [e.GetMessage() for e in context.Validate(stage)] == []
    assert stage.GetTimeCodesPerSecond() == 30 and (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 2)
    mesh = UsdGeom.Mesh(stage.GetDefaultPrim().GetChild("mesh"))
    counts = set()
    for i, f in enumerate(ply.files):  # frame i at time code i equals the i-th PLY frame
        tm = trimesh.load(f, process=False)
        np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get(i)), tm.vertices, atol=1e-5)
        faces = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(i)).reshape(-1, 3)
        assert np.array_equal(faces, tm.faces) and (np.asarray(mesh.GetFaceVertexCountsAttr().Get(i)) == 3).all()
        np.testing.assert_allclose(np.asarray(mesh.GetNormalsAttr().Get(i)), tm.vertex_normals, atol=1e-5)
        colours = np.asarray(mesh.GetDisplayColorPrimvar().Get(i))  # linear; the PLY holds 8-bit sRGB
        from neural_bake.io.colour import linear_to_srgb

        assert np.abs(np.round(linear_to_srgb(colours) * 255) - tm.visual.vertex_colors[:, :3]).max() <= 1
        counts.add(len(faces))
    assert len(counts) == 3  # the topology changes from frame to frame, and each time holds its own
    monkeypatch.setitem(sys.modules, "pxr", None)
    with pytest.raises(MissingExtraError, match="pip install 'neural-bake\\[usd\\]'"):
        bake_frames(fit.at, fit.at, fit.frame, times, tmp_path / "none", fmt="usd")
    assert not (tmp_path / "none").exists()
    with pytest.raises(NeuralBakeError, match="fps -1: must be a positive number"):
        bake_frames(fit.at, fit.at, fit.frame, times, tmp_path / "none", fmt="usd", fps=-1)
