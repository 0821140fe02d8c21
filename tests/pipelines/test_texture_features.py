"""Small sharp texture features survive a bake: the `dots` sample (flat colour with discs down to 8 texels across
at the map's size) baked onto itself with a briefly trained colour network, with the default hybrid colour rules
(ΔE, and the map's values the classical transfer's wherever the network's differ), with the ΔE rule alone and with the network alone
(both off)."""

import dataclasses

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from neural_bake.io.colour import linear_to_srgb
from neural_bake.io.images import read_image
from neural_bake.io.mesh_io import load_mesh
from neural_bake.samples import Dots
from neural_bake.samples.generate import write_sample

#: Map side of the bake; the dots' sizes are in its texels (the sample's texture is painted at this size).
SIZE = 128
#: SSIM floor of an 8-texel dot's window. The hybrid rule leaves a texel the network's colour only within
#: ΔE 2 of the source's, about 0.02 in sRGB, against a dot-to-background contrast of 0.3–0.7: SSIM stays
#: above 0.98 even if every texel of the window were that far off; a blurred dot (its contrast spread over
#: its neighbours, its peak lowered) loses structure and contrast and scores well below.
SSIM_FLOOR = 0.95


@pytest.fixture(scope="module")
def dots_bakes(tmp_path_factory):
    """The sample written at the map's size, a tiny SDF and a briefly trained 64x1 colour network (it gets the
    flat background within a few ΔE and blurs the dots), baked onto the mesh itself (its own UV layout, so the
    map's texel (i, j) is the source texture's texel (i, j)) with the default hybrid colour tolerance and with
    none; returns (sample, source texture sRGB (H, W, 3), {"hybrid" | "network": (albedo sRGB, report)})."""
    from neural_bake.fit.sdf import fit_sdf
    from neural_bake.fit.texture import fit_texture
    from neural_bake.pipelines.bake_asset import BakeAssetConfig, bake_asset

    tmp = tmp_path_factory.mktemp("dots")
    sample = dataclasses.replace(Dots(), texture_size=SIZE)
    # not named "dots": the bake's truth is then the mesh's texture, not the bundled sample's analytic colours
    obj = write_sample(sample.mesh(2000), tmp, "dots_small")
    mesh = load_mesh(obj)
    fit_sdf(mesh, width=16, depth=1, steps=10, minutes=None, pool_surface=4000, pool_near=4000, pool_uniform=1000,
            batch=512, batch_near=512, batch_uniform=128, polish_evals=0, compile="off", gemm_dtype="float32",
            micro_batches=1, progress=False).save(tmp / "f.sdf")
    fit_texture(mesh, str(tmp / "f.sdf"), width=64, depth=1, steps=600, minutes=None, pool=20000, batch=1024,
                lr=1e-3).save(tmp / "g.tex")
    bakes = {}
    inf = float("inf")
    for label, tol, within in (("hybrid", None, None), ("delta-e", None, inf), ("network", inf, inf)):
        cfg = BakeAssetConfig(coarse="keep", size=SIZE, maps="albedo", baseline=label == "hybrid", force=True,
                              hybrid_color_tol=tol, hybrid_color_within=within)
        rep = bake_asset(str(obj), str(tmp / "f.sdf"), tmp / label, cfg, texture_model=str(tmp / "g.tex"),
                         log=lambda s: None)
        assert rep["kept"]["uv"] == "the asset's"  # the map is in the source texture's layout
        bakes[label] = (read_image(tmp / label / "albedo.png", colour="data")[..., :3], rep)
    source = np.round(np.clip(linear_to_srgb(sample.mesh(2000).texture), 0, 1) * 255) / 255
    np.testing.assert_allclose(read_image(obj.with_suffix(".png"), colour="data")[..., :3], source, atol=1e-6)
    return sample, source, bakes


def dot_window(dot, half):
    """Rows and columns of the (2·half)² texels centred on a dot."""
    x, y = dot["centre"]
    r0, c0 = int(round(y - half)), int(round(x - half))
    return slice(r0, r0 + 2 * half), slice(c0, c0 + 2 * half)


def window_ssim(a, b, dot):
    """SSIM of two sRGB images over the 16² texels around an 8-texel dot (7² windows, colour channels)."""
    rows, cols = dot_window(dot, 8)
    return structural_similarity(a[rows, cols], b[rows, cols], channel_axis=2, data_range=1.0)


@pytest.mark.parametrize("label", ["hybrid", "delta-e"])
def test_eight_texel_dots_survive_the_hybrid_bake_and_not_the_network_alone(dots_bakes, label):
    sample, source, bakes = dots_bakes
    small = [d for d in sample.dots() if d["diameter"] == 8]
    assert len(small) == 4
    hybrid = [window_ssim(bakes[label][0], source, d) for d in small]
    network = [window_ssim(bakes["network"][0], source, d) for d in small]
    assert min(hybrid) > SSIM_FLOOR, hybrid
    assert max(network) < SSIM_FLOOR and max(network) < min(hybrid) - 0.05, network
    rep = bakes[label][1]
    assert rep["hybrid"]["color_tol"] == 2.0 and rep["color_psnr_db"] > rep["neural_color_psnr_db"] + 10
    assert bakes["network"][1].get("hybrid", {}).get("hybrid_color_fraction") is None


def test_the_delta_e_rule_alone_replaces_the_dots_not_the_background(dots_bakes):
    rep = dots_bakes[2]["delta-e"][1]
    assert 0.05 < rep["hybrid"]["hybrid_color_fraction"] < 0.95 and rep["hybrid"]["color_within"] is None


def test_the_default_hybrid_colours_stay_within_half_a_db_of_the_classical_transfer(dots_bakes):
    """The report's colour PSNR against the source texture, the hybrid map's and the classical transfer's of the
    same texels (the bake's baseline, quantised as its map would be): the default hybrid stays within 0.5 dB,
    while the ΔE rule alone falls further behind."""
    rep = dots_bakes[2]["hybrid"][1]
    classical = rep["baseline"]["color_psnr_db"]
    assert rep["hybrid"]["color_within"] == 0.0
    assert rep["color_psnr_db"] >= classical - 0.5, (rep["color_psnr_db"], classical)
    assert dots_bakes[2]["delta-e"][1]["color_psnr_db"] < classical - 0.5


def test_disc_edges_stay_within_a_texel_of_the_analytic_discs(dots_bakes):
    """Every disc of the hybrid bake, classified texel by texel (nearer the disc's colour than the background's
    along the line between them, in sRGB), against the analytic disc: texels on the wrong side lie within one
    texel of the circle, and the disc's area gives its radius to within half a texel."""
    sample, _, bakes = dots_bakes
    albedo = bakes["hybrid"][0]
    bg = linear_to_srgb(np.asarray(sample.background, dtype=np.float64))
    yy, xx = np.mgrid[0:SIZE, 0:SIZE] + 0.5  # texel centres, texel units of the map
    for dot in sample.dots():
        rows, cols = dot_window(dot, sample.spacing // 2)
        c = linear_to_srgb(np.asarray(dot["color"], dtype=np.float64))
        t = ((albedo[rows, cols] - bg) @ (c - bg)) / float((c - bg) @ (c - bg))
        baked = t > 0.5
        r = np.hypot(xx[rows, cols] - dot["centre"][0], yy[rows, cols] - dot["centre"][1])
        radius = dot["diameter"] / 2
        wrong = baked != (r < radius)
        assert np.all(np.abs(r[wrong] - radius) <= 1.0), (dot, r[wrong])
        analytic_area = float((r < radius).sum())
        assert abs(np.sqrt(baked.sum() / np.pi) - np.sqrt(analytic_area / np.pi)) <= 0.5, dot
