"""The comparison page of several bakes: figures, texel-by-texel pairs, errors, and the page in a real browser
(headless Chromium driven by Playwright, as the report's browser test): every viewer draws its GLB and the
viewers orbit together."""

import json
import re
import shutil

import numpy as np
import pytest

from neural_bake.cli.main import main
from neural_bake.constants import BROWSER_MASK_MIN_IOU
from neural_bake.io.images import read_image
from neural_bake.render.camera import Camera
from neural_bake.samples.generate import sample_path
from neural_bake.view import ViewError, image_metrics, render_mesh, view_mesh_from_glb
from neural_bake.view.comparison import CompareConfig, figures_rows, write_comparison
from neural_bake.view.compare import silhouette_iou


def _report(faces: int, seconds: float) -> dict:
    return {"mesh": str(sample_path("bumpy_sphere")), "coarse": {"faces": faces},
            "bake": {"size": [128, 128], "supersample": 1}, "truth": "analytic",
            "vs_truth_deg": {"median": 3000 / faces, "p95": 6000 / faces},
            "seconds": {"load": 1.0, "prepare": 2.0, "unwrap": 1.5, "bake": seconds - 4, "sdf": (seconds - 4) / 2},
            "seconds_total": seconds, "files": ["asset.glb", "report.json"]}


@pytest.fixture(scope="module")
def bakes(tmp_path_factory, make_analytic_bake):
    """Two bake folders of the bumpy sphere (coarse meshes of 600 and 1500 faces) and a third on the first's
    mesh and layout whose normal map is the constant tangent-space normal tilted 20° about the bitangent."""
    from neural_bake.bake.export import export_glb

    root = tmp_path_factory.mktemp("cmp")
    out = []
    for name, faces, secs in (("few", 600, 10.0), ("many", 1500, 30.0)):
        folder = root / name
        folder.mkdir()
        bake = make_analytic_bake(folder, faces=faces, size=128)
        (folder / "report.json").write_text(json.dumps(_report(faces, secs)))
        out.append((folder, bake))
    folder, bake = out[0]
    flat, tilted = root / "flat", root / "tilted"
    for f, angle in ((flat, 0.0), (tilted, 20.0)):
        f.mkdir()
        a = np.radians(angle)
        nmap = np.empty((128, 128, 3), dtype=np.float32)
        nmap[:] = (np.array([np.sin(a), 0.0, np.cos(a)]) + 1) / 2
        export_glb(f / "asset.glb", bake.baker.mesh, normal_map=nmap, albedo=bake.result.albedo,
                   tangents=bake.baker.tangents)
        (f / "report.json").write_text(json.dumps(_report(600, 12.0)))
    return root, [f for f, _ in out], flat, tilted


def test_figures_rows_read_the_report_the_files_and_the_fits(bakes, fit_sphere_siren):
    from neural_bake.fit.sdf import SdfFit
    from neural_bake.types import Frame

    root, (few, _), _, _ = bakes
    folder = root / "with-fit"
    shutil.copytree(few, folder)
    SdfFit(model=fit_sphere_siren(steps=10), frame=Frame(), steps=123, seconds=4.5).save(folder / "f.sdf")
    rep = {**_report(600, 10.0), "sdf": "f.sdf"}
    row = figures_rows(folder, rep)
    assert row["normal_median_deg"] == 5.0 and row["normal_p95_deg"] == 10.0
    assert row["map_size"] == [128, 128] and row["coarse_faces"] == 600
    assert row["glb_bytes"] == (folder / "asset.glb").stat().st_size
    assert row["files_bytes"] == row["glb_bytes"] + (folder / "report.json").stat().st_size
    assert row["fits"] == [{"fit": "SDF", "steps": 123, "seconds": 4.5, "budget_seconds": None,
                            "expected_steps": None}]
    assert row["seconds_total"] == 10.0 and row["seconds_with_fits"] == pytest.approx(14.5)


def test_comparison_page_stays_offline_and_measures_texel_pairs(bakes, tmp_path):
    root, (few, many), flat, tilted = bakes
    index = write_comparison([few, many, flat, tilted], tmp_path / "cmp", CompareConfig(views=2, size=64),
                             log=lambda m: None)
    page = index.read_text()
    refs = re.findall(r"""(?:src|href)=['"]([^'"#]+)['"]""", page)
    assert refs and all((index.parent / r).is_file() for r in refs), refs
    assert "http://" not in page and "https://" not in page
    summary = json.loads((index.parent / "comparison.json").read_text())
    names = [b["name"] for b in summary["bakes"]]
    assert names == ["few", "many", "flat", "tilted"]
    b0, b1 = summary["bakes"][:2]
    assert b0["render_psnr_vs_source_db"] > 25 and b1["render_psnr_vs_first_db"] > 25
    assert b0["colour_error_levels"]["median"] < 3  # the analytic albedo against the sample's texture
    # each bake's stage bar sums to its wall time
    for b in summary["bakes"]:
        assert sum(c["seconds"] for c in b["stages"]["children"]) == pytest.approx(b["seconds_total"])
    # pairs only where the coarse mesh and layout are shared; the tilt is measured texel by texel
    pairs = {(p["a"], p["b"]): p for p in summary["pairs"]}
    assert ("few", "many") not in pairs
    assert pairs[("flat", "tilted")]["normal_map_angle_deg"]["median"] == pytest.approx(20.0, abs=0.5)
    assert pairs[("flat", "tilted")]["albedo_error_levels"]["max"] == 0
    assert pairs[("few", "flat")]["albedo_error_levels"]["max"] == 0
    assert page.count("<svg class='stages'") == 4 and "<svg class='errtime'" in page
    assert page.count("<model-viewer id='viewer") == 4


def test_a_folder_that_is_not_a_bake_is_one_line_and_nothing_is_written(bakes, tmp_path, capsys):
    root, (few, _), _, _ = bakes
    not_bake = tmp_path / "empty"
    not_bake.mkdir()
    other = tmp_path / "other"
    other.mkdir()
    (other / "report.json").write_text(json.dumps({"format": "neural_bake.batch.v1"}))
    for bad, why in ((not_bake, "not a bake output folder (no report.json)"), (other, "not a bake report"),
                     (tmp_path / "nope", "no such bake output folder")):
        out = tmp_path / "out"
        assert main(["compare", str(few), str(bad), "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(bad) in err and why in err, err
        assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]
    with pytest.raises(ViewError, match="at least two"):
        write_comparison([few], tmp_path / "out")


@pytest.fixture(scope="module")
def browser_page(bakes, tmp_path_factory, browser_ready):
    root, (few, many), _, _ = bakes
    out = tmp_path_factory.mktemp("cmp-page")
    assert main(["compare", str(few), str(many), "-o", str(out / "page"), "--views", "1", "--size", "192"]) == 0
    return out / "page" / "index.html"


def test_the_comparison_page_in_a_browser_draws_each_bake_and_orbits_them_together(browser_page, tmp_path):
    from neural_bake.view.browser import drag_linked_viewers

    info = drag_linked_viewers(browser_page, tmp_path, drag=(90.0, 0.0), settle_ms=2500)
    assert not [e for e in info["console"] if e[0] in ("error", "pageerror")], info["console"]
    assert info["viewers"] == 2
    summary = json.loads((browser_page.parent / "comparison.json").read_text())
    cam = Camera.from_dict(summary["camera"])
    bg = np.asarray(read_image(browser_page.parent / "views" / "bake0_0.png", colour="data"))[0, 0, :3]
    shots = {(w, i): read_image(tmp_path / f"{w}_{i}.png", colour="data")[..., :3]
             for w in ("before", "after") for i in range(2)}
    for i in range(2):  # each viewer draws its own GLB where our renderer draws it
        drawn = np.abs(shots[("before", i)] - bg).max(axis=2) > 6 / 255
        ours = render_mesh(view_mesh_from_glb(browser_page.parent / f"bake{i}.glb"), cam)
        assert drawn.mean() > 0.2 and silhouette_iou(drawn, ours.mask) >= BROWSER_MASK_MIN_IOU
    # one drag on the first viewer turned both, the same way
    before, after = np.array(info["orbits_before"]), np.array(info["orbits_after"])
    assert np.allclose(after[0], after[1], atol=1e-6)
    assert abs(np.angle(np.exp(1j * (after[0, 0] - before[0, 0])))) > np.radians(10)

    def psnr(a, b):
        return image_metrics(a, b)["psnr_db"]

    for i in range(2):
        assert psnr(shots[("before", i)], shots[("after", i)]) < 40  # the picture changed
    # the two viewers now show the same turn: their pictures agree far better with each other than either
    # does with the other viewer's picture from before the drag
    assert psnr(shots[("after", 0)], shots[("after", 1)]) > psnr(shots[("after", 0)], shots[("before", 1)]) + 3
