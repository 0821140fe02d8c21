"""The HTML report of a bake folder, the batch index over several folders, and the `view` verb."""

import json
import re
import shutil

import numpy as np
import pytest

from neural_bake.cli.main import main
from neural_bake.samples.generate import sample_path
from neural_bake.view import ViewError, write_batch_index
from neural_bake.view.report import ReportConfig, write_asset_report


@pytest.fixture(scope="module")
def bake_folder(tmp_path_factory, make_analytic_bake):
    """A bake folder: the analytic bumpy-sphere bake, a report.json naming its source, an error map."""
    folder = tmp_path_factory.mktemp("bake")
    bake = make_analytic_bake(folder, faces=800, size=128)
    from neural_bake.io.images import write_image

    write_image(folder / "error_normal.png", np.tile(np.linspace(0, 1, 128, dtype=np.float32)[None, :, None],
                                                     (128, 1, 3)), colour="data")
    (folder / "report.json").write_text(json.dumps({
        "mesh": str(sample_path("bumpy_sphere")), "vs_truth_deg": {"median": 1.5, "p95": 3.0, "max": 9.0},
        "faces_vs_truth_deg": {"median": 0.25, "p95": 7.5, "max": 40.0},
        "coverage": 0.7, "seconds": {"load": 0.5, "bake": 2.0, "total": 3.0}, "seconds_total": 3.0}))
    return folder, bake


def _referenced_files(page: str) -> list[str]:
    return re.findall(r"""(?:src|href)=['"]([^'"#]+)['"]""", page)


def test_report_renders_compares_and_stays_offline(bake_folder):
    folder, _ = bake_folder
    index = write_asset_report(folder, ReportConfig(views=2, size=64), log=lambda m: None)
    assert index == folder / "report" / "index.html"
    page = index.read_text()
    # offline: every file the page uses is beside it, nothing is fetched from the network
    refs = _referenced_files(page)
    assert refs and all((index.parent / r).is_file() for r in refs), refs
    assert "http://" not in page and "https://" not in page
    # the bake's figures, with the source's own faces against its shading (the exact SDF's floor)
    assert "source face normals vs truth (its exact SDF), °</td><td>0.25</td><td>7.5" in page
    models_js = (index.parent / "models.js").read_text()
    assert "data:model/gltf-binary;base64," in models_js and "#sun.hdr" in models_js
    view = json.loads((index.parent / "view.json").read_text())
    m = view["metrics"]
    # the baked maps bring the coarse mesh much closer to the source than the bare coarse mesh
    assert m["baked_vs_source"]["interior"]["psnr_db"] > m["bare_vs_source"]["interior"]["psnr_db"] + 5
    assert m["baked_vs_source"]["silhouette_iou"] > 0.95
    assert view["source"] == str(sample_path("bumpy_sphere")) and not view["neural"]
    for name in ("source_0.png", "baked_1.png", "bare_0.png", "diff_baked_vs_source_0.png"):
        assert (index.parent / "views" / name).is_file()
    assert (index.parent / "heat_model_0.png").is_file() and "<svg" in page
    # the slot says why (report.json names no SDF model); report.json's figures are shown
    assert "No neural preview: report.json names no SDF model" in page and "1.50" in page


def test_report_with_the_neural_preview_compares_all_three(bake_folder):
    from neural_bake.view.analytic import analytic_render_asset
    from neural_bake.view.neural import neural_renderer

    folder, bake = bake_folder
    preview = neural_renderer(analytic_render_asset(bake))
    index = write_asset_report(folder, ReportConfig(views=1, size=64), neural=preview, log=lambda m: None)
    view = json.loads((index.parent / "view.json").read_text())
    m = view["metrics"]
    assert view["neural"] and (index.parent / "views" / "neural_0.png").is_file()
    assert (index.parent / "views" / "diff_baked_vs_neural_0.png").is_file()
    # the bake holds the fields the preview draws: baked and preview agree better than either with the mesh
    assert m["baked_vs_neural"]["interior"]["psnr_db"] > 40
    assert m["baked_vs_neural"]["interior"]["psnr_db"] > m["neural_vs_source"]["interior"]["psnr_db"]
    assert "No neural preview" not in index.read_text()
    with pytest.raises(ViewError, match="expected a renderer"):
        write_asset_report(folder, neural="yes please")


def test_report_replaces_the_old_one_whole_and_a_failure_keeps_it(bake_folder, monkeypatch):
    folder, _ = bake_folder
    first = write_asset_report(folder, ReportConfig(views=1, size=32), log=lambda m: None)
    assert json.loads((first.parent / "view.json").read_text())["views"] == 1
    import neural_bake.view.report as report_mod

    def boom(*args, **kwargs):
        raise RuntimeError("render failed")

    monkeypatch.setattr(report_mod, "render_mesh", boom)
    with pytest.raises(RuntimeError):
        write_asset_report(folder, ReportConfig(views=3, size=32), log=lambda m: None)
    assert json.loads((first.parent / "view.json").read_text())["views"] == 1  # the old report, whole
    assert not [p for p in folder.iterdir() if p.name.startswith(".report")]  # no staging left behind


def test_report_errors(tmp_path):
    with pytest.raises(ViewError, match="no such output folder"):
        write_asset_report(tmp_path / "nope")
    with pytest.raises(ViewError, match="no asset.glb"):
        write_asset_report(tmp_path)


def test_batch_index_over_two_bakes_and_failures(bake_folder, tmp_path, make_analytic_bake):
    folder, _ = bake_folder
    write_asset_report(folder, ReportConfig(views=1, size=32), log=lambda m: None)
    second = tmp_path / "second"
    second.mkdir()
    make_analytic_bake(second, name="sphere", faces=300, size=32)
    (second / "report.json").write_text(json.dumps({"vs_truth_deg": {"median": 0.4, "p95": 0.9}}))
    failed = tmp_path / "failed"
    failed.mkdir()
    (failed / "error.txt").write_text("bunny.obj: face index 812 out of range\n")
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    out = tmp_path / "index" / "index.html"
    out.parent.mkdir()
    write_batch_index([folder, second, failed, unfinished, tmp_path / "missing"], out)
    rows = json.loads(out.with_suffix(".json").read_text())
    assert [r["status"] for r in rows] == ["ok", "ok", "failed", "failed", "failed"]
    assert rows[1]["normal_median_deg"] == 0.4
    assert rows[2]["reason"] == "bunny.obj: face index 812 out of range"
    assert rows[3]["reason"] == "no asset.glb" and rows[4]["reason"] == "no such folder"
    page = out.read_text()
    assert "2 of 5 assets baked" in page
    refs = _referenced_files(page)
    thumbs = [r for r in refs if r.startswith("thumbs/")]
    links = [r for r in refs if not r.startswith("thumbs/")]
    assert len(thumbs) == 2 and all((out.parent / r).is_file() for r in thumbs)
    assert links[0].endswith("report/index.html") and all((out.parent / r).exists() for r in links[:4])
    with pytest.raises(ViewError, match="no output folders"):
        write_batch_index([], out)
    with pytest.raises(ViewError, match="does not exist"):
        write_batch_index([folder], tmp_path / "no" / "index.html")
    with pytest.raises(ViewError, match="1 names for 2 folders"):
        write_batch_index([folder, second], out, names=["a"])
    # a caller's reason and name win over what the folder says
    write_batch_index([folder, second], out, names=["first", "second"], reasons=[None, "sdf: diverged"])
    named = json.loads(out.with_suffix(".json").read_text())
    assert [(r["name"], r["status"], r["reason"]) for r in named] == [("first", "ok", None),
                                                                       ("second", "failed", "sdf: diverged")]


def test_view_verb_writes_the_report_or_headless_frames(bake_folder, tmp_path, capsys):
    folder, bake = bake_folder
    assert main(["view", str(folder), "--no-open", "--views", "1", "--size", "32"]) == 0
    assert (folder / "report" / "index.html").is_file()
    out = tmp_path / "frames"
    assert main(["view", str(bake.glb), "--headless", "--views", "3", "--size", "24", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["frame_000.png", "frame_001.png", "frame_002.png", "turntable.gif"]
    # a GLB outside a bake folder gets a folder of its own beside it
    loose = tmp_path / "loose.glb"
    shutil.copy2(bake.glb, loose)
    assert main(["view", str(loose), "--no-open", "--views", "1", "--size", "32"]) == 0
    assert (tmp_path / "loose-view" / "report" / "index.html").is_file()
    capsys.readouterr()
    for bad, msg in ((tmp_path / "nothing", "no such file or folder"), (tmp_path, "no asset.glb"),
                     (sample_path("sphere"), "expected a bake's output folder or a .glb")):
        assert main(["view", str(bad), "--no-open"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("neural-bake: error:") and msg in err and err.count("\n") == 1
    assert main(["view", str(folder), "--headless", "--views", "0"]) == 2
    assert "whole number" in capsys.readouterr().err


def test_headless_frames_through_a_symlink_keep_the_link(bake_folder, tmp_path):
    _, bake = bake_folder
    link = tmp_path / "latest"
    link.symlink_to("frames-1")  # dangling: the folder is made where it points
    assert main(["view", str(bake.glb), "--headless", "--views", "1", "--size", "16", "--out", str(link)]) == 0
    assert link.is_symlink() and sorted(p.name for p in (tmp_path / "frames-1").iterdir()) == [
        "frame_000.png", "turntable.gif"]


def test_view_holds_the_bake_folders_lock_while_it_writes(bake_folder, capsys):
    from neural_bake.io.outdir import OutputLock

    folder, _ = bake_folder
    before = sorted(p.name for p in folder.iterdir())
    with OutputLock(folder):  # a bake into the folder is under way
        assert main(["view", str(folder), "--no-open", "--views", "1", "--size", "32"]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "is writing it" in err and str(folder.name) in err
        assert main(["view", str(folder), "--headless", "--views", "1", "--size", "24"]) == 1
        assert "is writing it" in capsys.readouterr().err
    assert sorted(p.name for p in folder.iterdir()) == before  # nothing written, nothing left behind
    assert main(["view", str(folder), "--headless", "--views", "1", "--size", "24"]) == 0  # free again


def test_a_report_written_in_a_staging_folder_names_the_output(bake_folder, tmp_path):
    """A report built inside a staging folder (the demo commits the report with its bake) is titled after
    the output folder the staging folder becomes, never after the staging folder."""
    folder, _ = bake_folder
    stage = tmp_path / ".demo-out.stage-1-abc"
    shutil.copytree(folder, stage, ignore=shutil.ignore_patterns("report"))
    index = write_asset_report(stage, ReportConfig(views=1, size=32), neural=None, log=lambda m: None,
                               name=tmp_path / "demo-out")
    page = index.read_text()
    assert "<title>neural-bake report: demo-out</title>" in page and ".stage-" not in page
    assert json.loads((index.parent / "view.json").read_text())["folder"] == str(tmp_path / "demo-out")


def test_a_preview_that_cannot_draw_leaves_its_slot_with_the_reason(bake_folder):
    folder, _ = bake_folder

    def broken(camera):
        raise RuntimeError("no surface\nat all")

    index = write_asset_report(folder, ReportConfig(views=2, size=32), neural=broken, log=lambda m: None)
    view = json.loads((index.parent / "view.json").read_text())
    assert not view["neural"] and view["neural_note"] == "the preview renderer failed: no surface at all"
    assert "neural_vs_source" not in view["metrics"]


def test_report_captions_colour_section_and_every_fit_curve(bake_folder, tmp_path, fit_sphere_siren):
    from neural_bake.fit.nested import fit_nested
    from neural_bake.fit.sdf import SdfFit
    from neural_bake.types import Frame
    from neural_bake.view.report import fit_histories

    src, _ = bake_folder
    folder = tmp_path / "bake"
    folder.mkdir()
    for name in ("asset.glb", "error_normal.png"):
        shutil.copy2(src / name, folder / name)
    fine_history = [{"step": s, "seconds": 0.1 * s, "loss": 1.0 / s} for s in (1, 10, 20)]
    seq = fit_nested(SdfFit(model=fit_sphere_siren(steps=30), frame=Frame(), history=fine_history), levels=[(8, 0)],
                     steps=20, pool=2000, batch=256, eval_every=10, eval_samples=500, n_estimate=1000,
                     stability_samples=(), certify=False, progress=False)
    seq.save(folder / "nested.safetensors")
    report = {**json.loads((src / "report.json").read_text()), "sdf": "nested.safetensors"}
    (folder / "report.json").write_text(json.dumps(report))
    curves = fit_histories(folder, report)
    assert list(curves) == ["SDF fit (fine level f)", "nested level 0 (8x0)"]
    assert curves["SDF fit (fine level f)"] == fine_history
    level = curves["nested level 0 (8x0)"]
    assert level[-1]["step"] == 20 and all(a["seconds"] <= b["seconds"] for a, b in zip(level, level[1:]))

    index = write_asset_report(folder, ReportConfig(views=2, size=48), log=lambda m: None)
    page = index.read_text()
    captions = re.findall(r"<figcaption>([^<]+)</figcaption>", page)
    assert len(captions) == len(set(captions)), captions  # no two pictures share a caption
    assert (index.parent / "fits.png").is_file()
    # the colour section: source texture through the bake's layout, baked albedo, error over UVs and model
    view = json.loads((index.parent / "view.json").read_text())
    colour = view["colour_error"]
    assert colour["count"] > 1000 and colour["median"] < 3  # analytic albedo against the sample's texture
    for name in ("colour_source.png", "colour_baked.png", "error_colour.png", "heat_colour_0.png", "heat_colour_1.png"):
        assert (index.parent / name).is_file() and name in page
    assert "8-bit levels" in page
