"""`bench fidelity` on generated meshes (the data folder is never needed): rows, open caps, skipping."""

import json

import numpy as np
import pytest
import trimesh

from neural_bake.bench.fidelity import open_caps, run
from neural_bake.errors import NeuralBakeError
from neural_bake.fit.sdf import load_sdf
from neural_bake.nets.tiles import TiledSdf
from neural_bake.types import Mesh


def open_sphere(radius=0.7, z_cut=0.4, sub=4):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=radius)
    keep = m.triangles_center[:, 2] < z_cut
    sub_m = m.submesh([np.flatnonzero(keep)], append=True)
    return Mesh(vertices=np.asarray(sub_m.vertices), faces=np.asarray(sub_m.faces, dtype=np.int64), watertight=False)


def test_open_caps_split_the_hole_from_the_surface(fit_sphere_siren):
    net = fit_sphere_siren(r=0.7, steps=300)
    mesh = open_sphere()
    caps = open_caps(net, mesh, n=20000, resolution=64)
    # the cap over the hole is the sphere's zone above z = 0.4: (0.7 - 0.4) / 1.4 of its area
    assert caps["cap_share"] == pytest.approx(0.3 / 1.4, abs=0.03)
    assert caps["hausdorff_without_caps"] < 0.05 < 0.5 < caps["cap_max"]  # the pole is ~0.65 from the rim
    closed = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    assert open_caps(net, Mesh(vertices=np.asarray(closed.vertices), faces=np.asarray(closed.faces))) is None


def test_missing_data_is_skipped_saying_so(tmp_path):
    res = run(quick=True, meshes=["nefertiti"], data=tmp_path / "nowhere")
    assert res["rows"] == [] and any("nefertiti: skipped, no data folder" in n for n in res["notes"])
    (tmp_path / "d").mkdir()
    res = run(quick=True, meshes=["fandisk"], data=tmp_path / "d")
    assert res["rows"] == [] and any(n.startswith("fandisk: skipped,") and "not found" in n for n in res["notes"])


@pytest.mark.slow
def test_shrunken_run_on_a_generated_open_mesh(tmp_path):
    path = tmp_path / "cup.obj"
    m = open_sphere(sub=3)
    trimesh.Trimesh(m.vertices, m.faces, process=False).export(path)
    res = run(quick=True, meshes=[str(path)], minutes=0.02, size=48, faces=200, save_dir=tmp_path / "models")
    (row,) = res["rows"]
    saved = load_sdf(tmp_path / "models" / "cup-quick.sdf")  # the fitted field, kept to re-bake or time
    assert saved.steps == row["steps"] and (saved.config.width, saved.config.depth) == (192, 3)
    # the steps expected of the level the row's steps count (the fine one; the coarse level's are apart)
    levels = saved.budget["levels"]
    assert row["expected_steps"] == levels["fine"]["expected_steps"] is not None
    assert saved.budget["expected_steps"] == levels["fine"]["expected_steps"] + levels["coarse"]["expected_steps"]
    # the preset's own construction: a 64-wide coarse level and a 128-wide residual, one 192x3 SIREN
    assert row["mesh"] == "cup" and row["preset"] == "quick" and row["net"] == "64x3+128x3" and row["steps"] >= 1
    assert row["construction"] == "residual" and saved.config.construction == "residual"
    assert row["cap_max"] is not None and row["hausdorff_without_caps"] is not None
    # the classical bake of a mesh onto its own decimation is close; the coarse mesh's own normals are not
    assert row["classical_median_deg"] < 2.0 < row["coarse_median_deg"]
    # a field of a second's training is poor: the hybrid takes the classical normal where it is off
    assert row["hybrid_pct"] > 0 and row["map_median_deg"] <= row["neural_median_deg"]
    # ∇f alone is a bake of its own at every texel; the hybrid bake's own figure only where it evaluated ∇f
    assert row["neural_evaluated_median_deg"] is not None and row["neural_p95_deg"] >= row["neural_median_deg"]
    assert row["map_max_deg"] >= row["map_p95_deg"] and row["classical_max_deg"] >= row["classical_p95_deg"]
    # the source's own faces against its averaged normals: what its exact SDF would read, above 0 on a tessellation
    assert row["faces_p95_deg"] >= row["faces_median_deg"] > 0
    params = lambda w: 3 * w + w + 3 * (w * w + w) + w + 1  # noqa: E731
    assert row["networks_kb"] == pytest.approx((params(64) + params(128)) * 4 / 1024)
    assert row["source_mb"] == pytest.approx(path.stat().st_size / 2**20)
    json.dumps(res)


def test_gltf_source_size_counts_its_buffers(tmp_path):
    from neural_bake.bench.fidelity import _source_bytes

    trimesh.creation.box().export(tmp_path / "box.gltf")  # trimesh writes the buffer beside it
    bins = list(tmp_path.glob("*.bin"))
    assert bins and _source_bytes(tmp_path / "box.gltf") == sum(p.stat().st_size for p in tmp_path.iterdir())


@pytest.mark.slow
def test_sampling_variants_at_equal_steps_get_ratios_against_uniform(tmp_path):
    path = tmp_path / "block.obj"
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    v, f = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=0.2)
    trimesh.Trimesh(v, f, process=False).export(path)
    res = run(quick=True, meshes=[str(path)], steps=[3], sampling=["uniform", "curvature", "error"], size=32,
              constructions=["plain"],
              faces=100)
    rows = res["rows"]
    assert [(r["sampling"], r["step_cap"], r["steps"]) for r in rows] == [
        ("uniform", 3, 3), ("curvature", 3, 3), ("error", 3, 3)]
    base = rows[0]
    assert base["median_ratio"] == 1.0 and base["step_cost_ratio"] == 1.0 and base["hausdorff_ratio"] == 1.0
    assert base["sampling_cost_ratio"] == 1.0
    for r in rows[1:]:
        assert r["median_ratio"] == pytest.approx(r["map_median_deg"] / base["map_median_deg"])
        assert r["step_cost_ratio"] == pytest.approx(r["s_per_step"] / base["s_per_step"])
        assert 0 < r["sampling_share"] < 1
        extra = r["s_per_step"] * r["sampling_share"] - base["s_per_step"] * base["sampling_share"]
        assert r["sampling_cost_ratio"] == pytest.approx(1.0 + extra / base["s_per_step"])
    json.dumps(res)


def test_bad_sampling_and_steps_are_refused(tmp_path, capsys):
    from neural_bake.cli.main import main
    from neural_bake.errors import NeuralBakeError

    with pytest.raises(NeuralBakeError, match="sampling must be among"):
        run(quick=True, meshes=["x.obj"], sampling=["curvy"])
    with pytest.raises(NeuralBakeError, match="steps must be positive"):
        run(quick=True, meshes=["x.obj"], steps=[0])
    (tmp_path / "file").write_text("x")
    with pytest.raises(NeuralBakeError, match=r"file/models: cannot create the models folder"):
        run(quick=True, meshes=["x.obj"], save_dir=tmp_path / "file" / "models")
    assert main(["bench", "fidelity", "--quick", "--mesh", "x.obj", "--save-models", str(tmp_path / "file" / "m")]) == 2
    err = capsys.readouterr().err.strip()
    assert "cannot create the models folder" in err and len(err.splitlines()) == 1, err
    for args, hint in ((["--sampling", "uniform,curvy"], "--sampling"), (["--steps", "10,x"], "--steps"),
                       (["--texture-steps", "0"], "--texture-steps")):
        assert main(["bench", "fidelity", "--quick", *args]) == 2
        assert f"Invalid value for {hint}" in capsys.readouterr().err


def test_targets_are_marked_met_or_not_by_the_map_median():
    from neural_bake.bench.fidelity import target_text

    assert target_text("nefertiti", 10.0, 0.52) == "map ≤ 1.0°: met; halving 1.19°: met, 0.44×"
    assert target_text("nefertiti", 10.0, 0.71) == "map ≤ 1.0°: met; halving 1.19°: NOT met, 0.60×"
    assert target_text("nefertiti", 2.0, 1.5) == "map ≤ 1.4°: NOT met; halving 2.64°: NOT met, 0.57×"
    assert target_text("ogre", 2.0, 1.69) == "halving 4.88°: met, 0.35×"
    assert target_text("nefertiti", 10.0, None) == "map ≤ 1.0°: NOT met; halving 1.19°: NOT met"
    assert target_text("nefertiti", 10.0, float("nan")).startswith("map ≤ 1.0°: NOT met")
    assert target_text("nefertiti", 5.0, 0.52) == "halving 1.25°: met, 0.42×"
    assert target_text("ogre", 5.0, 1.5) == "halving 2.95°: NOT met, 0.51×"
    assert target_text("nefertiti", 8.0, 0.5) is None and target_text("spot", 2.0, 0.5) is None


def test_albedo_scores_of_equal_and_of_offset_images():
    from neural_bake.bench.fidelity_texture import albedo_scores

    rng = np.random.default_rng(0)
    a = rng.random((32, 32, 3))
    covered = np.zeros((32, 32), dtype=bool)
    covered[4:28, 2:30] = True
    same = albedo_scores(a, a, covered)
    assert same["psnr_db"] == float("inf") and same["ssim"] == pytest.approx(1.0)
    b = a.copy()
    b[covered] += 0.01  # a constant offset over the covered texels: MSE 1e-4, 40 dB
    b[~covered] = 0.7  # what lies outside the covered texels does not count
    off = albedo_scores(a, b, covered)
    assert off["psnr_db"] == pytest.approx(40.0, abs=1e-6) and 0.9 < off["ssim"] < 1.0
    assert albedo_scores(a, b, np.zeros((32, 32), dtype=bool)) == {"psnr_db": None, "ssim": None}


def test_shrunken_texture_rows_on_a_generated_textured_mesh(tmp_path):
    """Texture rows alone on a small sphere with a smooth texture: the classical transfer is close to the
    source, the hybrid colour rule is never worse than the network alone, ratios are of the same run."""
    from neural_bake.samples import Sphere
    from neural_bake.samples.generate import write_sample

    path = write_sample(Sphere().mesh(2000, 64), tmp_path, "ball")
    trimesh.creation.box().export(tmp_path / "box.obj")
    res = run(quick=True, meshes=[str(path), str(tmp_path / "box.obj")], only_textures=True, steps=[5], size=48,
              faces=300, texture_steps=20, texture_networks=["siren", "grid"], constructions=["plain"])
    assert res["rows"] == [] and list(res["tables"]) == ["textures"]
    assert any(n == "box: skipped, no texture (texture rows only)" for n in res["notes"])
    row, grid = res["texture_rows"]  # one row per construction, same SDF, coarse mesh and layout
    assert row["mesh"] == "ball" and row["texture_net"] == "64x1" and row["texture_steps"] == 20
    assert row["texture_network"] == "siren" and grid["texture_network"] == "grid"
    assert grid["texture_net"] == "grid 16x2 2^16 16–1024, 64x1 relu" and grid["texture_steps"] == 20
    assert grid["texels"] == row["texels"] and grid["classical_psnr_db"] == row["classical_psnr_db"]
    for r in (row, grid):
        assert r["texture_step_ms"] == pytest.approx(1000 * r["texture_fit_s"] / r["texture_steps"])
        assert r["texture_threads"] >= 1 and "network_feature_ssim_min" not in r
    assert row["texture_kb"] == pytest.approx((3 * 64 + 64 + 64 * 64 + 64 + 64 * 3 + 3) * 4 / 1024)
    assert grid["texture_kb"] > 1000  # the grid's tables
    assert row["sdf_steps"] == 5 and row["size"] == 48 and row["texels"] > 500
    assert row["classical_psnr_db"] > 30 and row["classical_ssim"] > 0.9
    for ref in ("", "_vs_classical"):
        assert row[f"hybrid{ref}_psnr_db"] >= row[f"network{ref}_psnr_db"]
        assert row[f"hybrid{ref}_ssim"] >= row[f"network{ref}_ssim"]
        for who in ("network", "hybrid"):
            assert -1.0 <= row[f"{who}{ref}_ssim"] <= 1.0
    assert 0 < row["hybrid_color_pct"] <= 100  # a 20-step network is far from its texture
    for who in ("hybrid", "classical"):
        assert row[f"{who}_time_ratio"] == pytest.approx(row[f"{who}_bake_s"] / row["network_bake_s"])
    json.dumps(res)
    with pytest.raises(NeuralBakeError, match="texture_steps must be a positive integer"):
        run(quick=True, meshes=[str(path)], only_textures=True, texture_steps=0)


def test_normal_and_texture_rows_of_one_run(tmp_path):
    """A textured mesh without --no-texture: its normal row carries the texture network's PSNR beside the
    classical transfer's, and its texture row is of the same SDF."""
    from neural_bake.samples import Sphere
    from neural_bake.samples.generate import write_sample

    path = write_sample(Sphere().mesh(1000, 32), tmp_path, "ball")
    res = run(quick=True, meshes=[str(path)], steps=[3], size=32, faces=200, texture=True, texture_steps=5,
              texture_networks=["siren"], constructions=["plain"])
    (row,), (tex,) = res["rows"], res["texture_rows"]
    assert row["mesh"] == tex["mesh"] == "ball" and row["sdf_settings"] is None and tex["texture_steps"] == 5
    assert row["texture_psnr_db"] is not None and row["classical_texture_psnr_db"] is not None
    json.dumps(res)


def test_texture_network_constructions():
    from neural_bake.bench.fidelity import GRID_TEXTURE, own_texture_network, texture_network_settings

    assert texture_network_settings("siren", "quick") == {"network": "siren"}
    assert texture_network_settings("siren-wide", "quick") == {"network": "siren", "width": 128, "depth": 2}
    assert texture_network_settings("siren-wide", "default") == {"network": "siren", "width": 384, "depth": 4}
    assert texture_network_settings("grid", "high")["network"] == "grid"
    assert texture_network_settings("grid-auto", "quick") == {}  # the quick preset's own network
    assert texture_network_settings("grid-auto", "default") == {}  # the default preset's own, with its 64x2 MLP
    assert texture_network_settings("grid", "default") == {"network": "grid", "width": 64, "depth": 2, "lr": 1e-2,
                                                           "edge_share": 0.5, "normal_inputs": "off"}
    assert texture_network_settings("grid", "quick") == {**GRID_TEXTURE, "normal_inputs": "off"}
    assert own_texture_network("default") == "grid-auto" and own_texture_network("high") == "siren"
    assert texture_network_settings("grid-uniform", "quick") == {"network": "grid", "width": 64, "depth": 1, "lr": 1e-2,
                                                                 "edge_share": 0.0, "normal_inputs": "off"}
    assert texture_network_settings("grid-uniform", "high")["edge_share"] == 0.0
    assert texture_network_settings("grid-normals", "high") == {"network": "grid", "width": 64, "depth": 1,
                                                                "lr": 1e-2, "edge_share": 0.5, "normal_inputs": "on"}
    with pytest.raises(NeuralBakeError, match=r"texture_networks must be distinct names among siren, siren-wide, "
                                              r"grid, grid-uniform, grid-normals, grid-auto, got siren, siren"):
        run(quick=True, meshes=["x.obj"], texture_networks=["siren", "siren"])
    with pytest.raises(NeuralBakeError, match=r"texture_minutes must be a positive number, got 0"):
        run(quick=True, meshes=["x.obj"], texture_minutes=0)
    with pytest.raises(NeuralBakeError, match=r"give texture_steps or texture_minutes, not both"):
        run(quick=True, meshes=["x.obj"], texture_minutes=1.0, texture_steps=5)


def test_cli_refuses_bad_texture_networks(capsys):
    from neural_bake.cli.main import main

    for args, hint in ((["--texture-network", "siren,octree"], "--texture-network"),
                       (["--texture-minutes", "-1"], "--texture-minutes")):
        assert main(["bench", "fidelity", "--quick", *args]) == 2
        assert f"Invalid value for {hint}" in capsys.readouterr().err


def test_dot_windows_and_their_scores():
    """The 8-texel discs of the dots sample (every fourth row of its 32 × 32 cells): windows twice their diameter,
    centred on them, at the sample's size and scaled with the map; an exact map keeps SSIM 1 in each, a blurred
    one falls below the floor."""
    from scipy.ndimage import uniform_filter

    from neural_bake.bench.fidelity_texture import FEATURE_SSIM_FLOOR, dot_windows, feature_ssim
    from neural_bake.io.colour import linear_to_srgb
    from neural_bake.samples import Dots

    windows = dot_windows(1024)
    assert len(windows) == 8 * 32 and all(r.stop - r.start == 16 == c.stop - c.start for r, c in windows)
    assert windows[0] == (slice(8, 24), slice(8, 24))  # the first cell (32 texels) holds an 8-texel disc at (16, 16)
    assert [(r.start, c.start) for r, c in dot_windows(512)] == [(r.start // 2, c.start // 2) for r, c in windows]
    tex = np.round(linear_to_srgb(Dots().mesh(200).texture) * 255) / 255
    assert feature_ssim(tex, tex, windows) == [1.0] * len(windows)
    blurred = uniform_filter(tex, size=(5, 5, 1))
    assert max(feature_ssim(blurred, tex, windows)) < FEATURE_SSIM_FLOOR
    assert feature_ssim(tex, tex, dot_windows(256)) is None  # 4-texel windows: too small for 7x7 SSIM


@pytest.mark.slow
def test_sdf_constructions_side_by_side_get_ratios_against_plain(tmp_path):
    path = tmp_path / "block.obj"
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    v, f = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=0.2)
    trimesh.Trimesh(v, f, process=False).export(path)
    res = run(quick=True, meshes=[str(path)], steps=[8], constructions=["plain", "residual", "tiles"], size=32,
              faces=100, save_dir=tmp_path / "models", sampling=["audit"])
    plain, residual, tiles = res["rows"]
    # the band audit between the residual construction's levels (a plain fit has none)
    assert plain["audit_kept"] is None and plain["audit_s"] is None
    assert residual["audit_kept"] >= 0 and residual["audit_s"] >= 0
    assert (plain["construction"], plain["net"], plain["steps"], plain["coarse_steps"]) == ("plain", "192x3", 8, None)
    # the same 8 steps split: a quarter to the 64-wide coarse level, the rest to the residual
    assert (residual["construction"], residual["net"], residual["steps"], residual["coarse_steps"]) == (
        "residual", "64x3+128x3", 6, 2)
    assert residual["band"] > 0 and plain["band"] is None
    assert plain["plain_median_ratio"] == 1.0 and plain["plain_p95_ratio"] == 1.0
    assert residual["plain_median_ratio"] == pytest.approx(residual["map_median_deg"] / plain["map_median_deg"])
    assert residual["plain_hausdorff_ratio"] == pytest.approx(residual["hausdorff"] / plain["hausdorff"])
    # the two networks' parameters, not the zero blocks of their sum as one network
    params = lambda w: 3 * w + w + 3 * (w * w + w) + w + 1  # noqa: E731
    assert residual["networks_kb"] == pytest.approx((params(64) + params(128)) * 4 / 1024)
    saved = load_sdf(tmp_path / "models" / "block-quick-8-audit-residual.sdf")  # the sum, an ordinary SDF file
    assert saved.model.width == 192 and saved.steps == 6
    # the tiles construction: the same coarse level, then its tiles; scored and baked like the others
    assert (tiles["construction"], tiles["steps"], tiles["coarse_steps"]) == ("tiles", 6, 2)
    assert tiles["net"].startswith("64x3+") and tiles["net"].endswith("x(64x2)") and tiles["band"] > 0
    assert tiles["map_median_deg"] > 0 and tiles["plain_median_ratio"] == pytest.approx(
        tiles["map_median_deg"] / plain["map_median_deg"])
    assert isinstance(load_sdf(tmp_path / "models" / "block-quick-8-audit-tiles.sdf").model, TiledSdf)
    json.dumps(res)


def test_unknown_sdf_construction_is_refused_in_one_line(capsys):
    from neural_bake.cli.main import main

    with pytest.raises(NeuralBakeError, match="constructions must be distinct names among plain, residual"):
        run(quick=True, meshes=["x.obj"], constructions=["plain", "nested"])
    with pytest.raises(NeuralBakeError, match="only_textures fits the plain SDF"):
        run(quick=True, only_textures=True, constructions=["residual"])
    for value in ("plain,nested", "residual,residual", ","):
        assert main(["bench", "fidelity", "--quick", "--sdf-construction", value]) == 2
        err = capsys.readouterr().err.strip()
        assert "Invalid value for --sdf-construction" in err and len(err.splitlines()) == 1, err


def test_sdf_settings_are_set_on_every_fit_and_named(tmp_path):
    path = tmp_path / "block.obj"
    trimesh.creation.box(extents=(1.0, 0.6, 0.4)).export(path)
    res = run(quick=True, meshes=[str(path)], steps=[8], size=32, faces=100, save_dir=tmp_path / "models",
              sdf_settings={"coarse_share": "0.5"})
    (row,) = res["rows"]
    # the quick preset's residual construction, its 8 steps split in half instead of a quarter
    assert (row["steps"], row["coarse_steps"]) == (4, 4)
    assert row["sdf_settings"] == {"coarse_share": 0.5}
    assert load_sdf(tmp_path / "models" / "block-quick-8-coarse_share=0.5.sdf").steps == 4
    json.dumps(res)


def test_bad_sdf_settings_are_refused_in_one_line(capsys):
    from neural_bake.cli.main import main

    for settings, match in (({"coarse_shar": 0.1}, "unknown SDF fit setting 'coarse_shar'"),
                            ({"coarse_share": "a lot"}, r"coarse_share='a lot': expected float"),
                            ({"minutes": 3}, "cannot set 'minutes'")):
        with pytest.raises(NeuralBakeError, match=match):
            run(quick=True, meshes=["x.obj"], sdf_settings=settings)
    assert main(["bench", "fidelity", "--quick", "--sdf-set", "coarse_share"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Invalid value for --sdf-set" in err and len(err.splitlines()) == 1, err
    assert main(["bench", "fidelity", "--quick", "--sdf-set", "stpes=3"]) != 0
    err = capsys.readouterr().err.strip()
    assert "unknown SDF fit setting 'stpes'" in err and len(err.splitlines()) == 1, err


def test_expected_steps_are_the_counted_levels():
    from types import SimpleNamespace

    from neural_bake.bench.fidelity import _fine_account

    levels = {"coarse": {"expected_steps": 300}, "fine": {"expected_steps": 700}}
    assert _fine_account(SimpleNamespace(budget={"expected_steps": 1000, "levels": levels}))["expected_steps"] == 700
    assert _fine_account(SimpleNamespace(budget={"expected_steps": 1000}))["expected_steps"] == 1000  # plain
    assert _fine_account(SimpleNamespace(budget=None)) == {}
