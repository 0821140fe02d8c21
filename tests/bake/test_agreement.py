"""Item 4: bake refuses an SDF that does not describe the mesh (frames, median |f| on its surface); --force."""

import json

import numpy as np
import pytest
import torch

from neural_bake.bake.agreement import check_sdf_describes_mesh, sdf_agreement
from neural_bake.cli.main import main
from neural_bake.constants import FRAME_MISMATCH_TOL, SDF_MISMATCH_MEDIAN
from neural_bake.errors import NeuralBakeError
from neural_bake.fields import SdfField, save_field
from neural_bake.io.mesh_io import load_mesh
from neural_bake.nets.siren import Siren
from neural_bake.samples.generate import sample_path
from neural_bake.samples.shapes import get_sample
from neural_bake.types import Frame


@pytest.fixture(scope="module")
def torus():
    return load_mesh(sample_path("torus"))


def _analytic(sample, frame, name):
    def fn(p):
        return torch.as_tensor(sample.sdf(frame.to_source(p.cpu().numpy())) * frame.scale, dtype=p.dtype)

    return SdfField(fn, frame=frame, name=name)


def test_the_mesh_own_sdf_passes(torus):
    a = check_sdf_describes_mesh(torus, _analytic(get_sample("torus"), torus.frame, "torus"))
    assert a["passed"] and a["frame_mismatch"] == 0.0
    assert a["median_abs_f"] < 0.1 * SDF_MISMATCH_MEDIAN  # only the faceting of the mesh


def test_sphere_sdf_on_the_torus_is_refused_with_the_median(torus):
    sphere = SdfField(lambda p: p.norm(dim=1) - 0.9, frame=torus.frame, name="sphere.sdf")
    a = sdf_agreement(torus, sphere)
    # the torus (R + r = 0.9 in the unit frame) reads |f| = 0.9 - |x|, from 0 on its outer equator to 2r
    assert SDF_MISMATCH_MEDIAN < a["median_abs_f"] < 0.9
    with pytest.raises(NeuralBakeError, match=r"^sphere\.sdf: does not describe .*torus\.obj: median \|f\| on the "
                                              r"mesh's surface is 0\.\d+ \(unit frame, 4096 samples; threshold 0\.02\); "
                                              r"fit the SDF on this mesh, or force=True bakes anyway$"):
        check_sdf_describes_mesh(torus, sphere)
    forced = check_sdf_describes_mesh(torus, sphere, force=True)
    assert not forced["passed"] and forced["median_abs_f"] == pytest.approx(a["median_abs_f"])


def test_another_frame_is_refused(torus):
    f = torus.frame
    moved = Frame((f.center[0] + 10 * FRAME_MISMATCH_TOL / f.scale, f.center[1], f.center[2]), f.scale)
    field = _analytic(get_sample("torus"), moved, "moved.sdf")
    # the field still describes the torus (evaluated through the frames), but it was fitted elsewhere
    with pytest.raises(NeuralBakeError, match=r"moved\.sdf: does not describe .*: the frames differ by 0\.01 "
                                              r"\(tolerance 0\.001\)"):
        check_sdf_describes_mesh(torus, field)
    scaled = _analytic(get_sample("torus"), Frame(f.center, f.scale * 1.5), "scaled.sdf")
    with pytest.raises(NeuralBakeError, match=r"the frames differ by 0\.5 "):
        check_sdf_describes_mesh(torus, scaled)


def _sphere_siren():
    """A small Siren fitted to |x| - 0.9 (the sphere sample's SDF in its unit frame)."""
    gen = torch.Generator().manual_seed(0)
    net = Siren(32, 1, omega_0=5.0, generator=gen)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    for _ in range(200):
        x = torch.rand(2048, 3, generator=gen) * 2 - 1
        loss = ((net(x)[:, 0] - (x.norm(dim=1) - 0.9)) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net.eval()


def test_cli_bake_refuses_then_force_bakes(torus, tmp_path, capsys):
    path = save_field(SdfField.from_model(_sphere_siren(), frame=torus.frame), tmp_path / "sphere.sdf")
    argv = ["bake", str(sample_path("torus")), "--sdf", str(path), "--coarse", "decimate:300", "--size", "32",
            "--no-baseline", "-o", str(tmp_path / "out")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "median |f| on the mesh's surface is" in err
    assert "--force bakes anyway" in err and not (tmp_path / "out").exists()
    assert main(argv + ["--force"]) == 0
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["sdf_check"]["passed"] is False and report["sdf_check"]["median_abs_f"] > SDF_MISMATCH_MEDIAN
    # the sphere's own mesh passes with the same file (frames differ only if the samples' frames differ)
    sphere = load_mesh(sample_path("sphere"))
    ok = save_field(SdfField.from_model(_sphere_siren(), frame=sphere.frame), tmp_path / "own.sdf")
    assert main(["bake", str(sample_path("sphere")), "--sdf", str(ok), "--coarse", "decimate:300", "--size", "32",
                 "--no-baseline", "-o", str(tmp_path / "own")]) == 0
    report = json.loads((tmp_path / "own" / "report.json").read_text())
    assert report["sdf_check"]["passed"] and report["sdf_check"]["median_abs_f"] < SDF_MISMATCH_MEDIAN
    assert np.isfinite(report["sdf_check"]["p95_abs_f"])
