"""Blender's Cycles bake in its own process: the real worker under the real Blender venv (skipped where
``make setup-blender`` has not been run), the decoder of its maps, and the parent side's error paths."""

import stat
import sys

import numpy as np
import pytest
import trimesh

from neural_bake.bake.baker import Baker
from neural_bake.bench import blender
from neural_bake.fields import SdfField
from neural_bake.mesh.unwrap import unwrap
from neural_bake.types import Mesh

R = 0.7


def sphere(subdivisions: int, uv: bool) -> Mesh:
    ico = trimesh.creation.icosphere(subdivisions=subdivisions, radius=R)
    m = Mesh(vertices=np.asarray(ico.vertices, dtype=np.float64), faces=np.asarray(ico.faces, dtype=np.int64))
    return unwrap(m, resolution=256) if uv else m


def angle_deg(a, b):
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


@pytest.fixture(scope="module")
def sphere_pair():
    """A 320-face coarse sphere (split at its UV seams, 64² texels) and a 20,480-face fine one."""
    baker = Baker(sphere(2, uv=True), 64, normal_space="object")
    return baker, sphere(5, uv=False)


def _script(tmp_path, body: str):
    path = tmp_path / "python"
    path.write_text("#!/bin/sh\n" + body + "\n")
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return path


# -- the real Blender ---------------------------------------------------------------------------------------

BLENDER_PYTHON = blender.find_python()
needs_blender = pytest.mark.skipif(
    not BLENDER_PYTHON.exists(),
    reason=f"no Blender interpreter at {BLENDER_PYTHON} ({blender.SETUP_HINT}; not run in CI: a download of "
           f"several hundred MB)")


@needs_blender
@pytest.mark.parametrize("space", ["tangent", "object"])
def test_cycles_bake_of_a_sphere_decodes_to_its_analytic_normals(sphere_pair, space):
    baker, fine = sphere_pair
    ok, version = blender.available()
    assert ok, version  # the venv exists: a bpy that does not import is a broken set-up, not a skip
    res = blender.cycles_bake(baker.mesh, fine, 64, normal_space=space, threads=1)
    assert res.normal_map.shape == (64, 64, 3) and res.normal_map.dtype == np.float32
    assert np.isfinite(res.normal_map).all() and res.normal_map.min() >= 0.0 and res.normal_map.max() <= 1.0
    assert (res.frames is not None) == (space == "tangent")
    if res.frames is not None:
        assert res.frames.shape == (baker.mesh.n_faces, 3, 7)
    t = res.timings
    assert t["version"] in version
    assert all(t[k] >= 0 for k in ("import", "setup", "bake", "read", "script", "process", "whole"))
    assert t["bake"] <= t["script"] and t["whole"] <= t["process"]

    tx = baker.texels
    err = angle_deg(blender.decode_samples(res, tx, bits=8), tx.points)  # the sphere's normal is p / |p|
    inside = ~np.asarray(tx.border)  # border samples read Blender's margin, not its bake
    assert np.median(err) < 0.5  # 8-bit steps are 0.45°
    assert err[inside].max() < 2.0
    if space == "tangent":  # its margin continues each chart in its own frame
        assert err.max() < 3.0


# -- the decoder, without Blender -------------------------------------------------------------------------------


TILT = np.array([0.24, 0.32, 0.0])  # a field tilted off the sphere's normal: the map's x and y matter


def tilted(p):
    return (p / np.linalg.norm(p, axis=1, keepdims=True) + TILT).astype(np.float64)


def test_decode_samples_reads_a_tangent_map_with_the_frames_it_is_given(sphere_pair):
    """Our tangent-space bake of a tilted normal field on the sphere, given as Blender's output with our own
    per-corner frames (MikkTSpace-style), decodes to that field through :func:`blender.decode_samples`; with
    the bitangent signs flipped it does not."""
    import torch

    baker, _ = sphere_pair
    tangent_baker = Baker(baker.mesh, 64, normal_space="tangent")
    tilt = torch.as_tensor(TILT)
    res = tangent_baker.bake(SdfField(lambda p: p.norm(dim=1) - R,
                                      lambda p: torch.nn.functional.normalize(
                                          torch.nn.functional.normalize(p, dim=1) + tilt.to(p.dtype), dim=1)))
    mesh, tan = tangent_baker.mesh, tangent_baker.tangents
    corners = np.concatenate([tan[mesh.faces][..., :3], tan[mesh.faces][..., 3:4], mesh.vertex_normals[mesh.faces]],
                             axis=2)
    bake = blender.CyclesBake(normal_map=res.normal_map, normal_space="tangent", frames=corners.astype(np.float32))
    tx = tangent_baker.texels
    err = angle_deg(blender.decode_samples(bake, tx, bits=None), tilted(tx.points))
    assert np.percentile(err, 99) < 0.5 and err.max() < 2.0
    flipped = blender.CyclesBake(normal_map=res.normal_map, normal_space="tangent", frames=corners * [1, 1, 1, -1, 1, 1, 1])
    assert np.median(angle_deg(blender.decode_samples(flipped, tx, bits=None), tilted(tx.points))) > 5.0


# -- error paths: no Blender needed ------------------------------------------------------------------------------


def test_missing_interpreter_is_one_line(tmp_path, sphere_pair):
    baker, fine = sphere_pair
    missing = tmp_path / "no" / "python"
    ok, why = blender.available(missing)
    assert not ok and str(missing) in why and "\n" not in why
    with pytest.raises(blender.BlenderError, match="no Blender interpreter at .*make setup-blender") as info:
        blender.cycles_bake(baker.mesh, fine, 16, python=missing)
    assert "\n" not in str(info.value)


def test_interpreter_from_argument_then_environment(tmp_path, monkeypatch):
    monkeypatch.setenv(blender.ENV_VAR, str(tmp_path / "env-python"))
    assert blender.find_python() == tmp_path / "env-python"
    assert blender.find_python(tmp_path / "arg-python") == tmp_path / "arg-python"
    monkeypatch.delenv(blender.ENV_VAR)
    assert blender.find_python().parts[-4:] == (".cache", "blender-venv", "bin", "python")


def test_worker_exit_code_becomes_one_line_error(sphere_pair):
    """Our own interpreter has no bpy: the real worker exits non-zero on its import."""
    baker, fine = sphere_pair
    ok, why = blender.available(sys.executable)
    assert not ok and "bpy does not import" in why and "No module named 'bpy'" in why and "\n" not in why
    with pytest.raises(blender.BlenderError, match=r"failed \(exit code 1\): ModuleNotFoundError: No module named 'bpy'"
                       ) as info:
        blender.cycles_bake(baker.mesh, fine, 16, python=sys.executable)
    assert "\n" not in str(info.value)


def test_worker_stderr_last_line_and_timeout(tmp_path, sphere_pair):
    baker, fine = sphere_pair
    crash = _script(tmp_path, 'echo "Traceback (most recent call last):" >&2; echo "  File x" >&2; '
                              'echo "RuntimeError: Cycles gave up" >&2; exit 3')
    with pytest.raises(blender.BlenderError, match=r"^Blender's bake failed \(exit code 3\): RuntimeError: Cycles gave up$"):
        blender.cycles_bake(baker.mesh, fine, 16, python=crash)
    silent = _script(tmp_path, "exit 0")  # exits cleanly but writes nothing
    with pytest.raises(blender.BlenderError, match="wrote no readable result"):
        blender.cycles_bake(baker.mesh, fine, 16, python=silent)
    slow = _script(tmp_path, "exec sleep 30")
    with pytest.raises(blender.BlenderError, match="over its timeout of 0.5 s"):
        blender.cycles_bake(baker.mesh, fine, 16, python=slow, timeout=0.5)


def test_bad_arguments(sphere_pair):
    baker, fine = sphere_pair
    with pytest.raises(blender.BlenderError, match="normal_space must be"):
        blender.cycles_bake(baker.mesh, fine, 16, normal_space="world")
    with pytest.raises(blender.BlenderError, match="size must be a positive integer"):
        blender.cycles_bake(baker.mesh, fine, 0)
    with pytest.raises(blender.BlenderError, match="no UVs"):
        blender.cycles_bake(fine, fine, 16)
