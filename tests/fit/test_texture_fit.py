"""Gradient-orthogonal texture fitting: loss terms against autograd, analytic metrics, quality floors, errors.

Meshes are generated here: a lat-long UV sphere of radius 0.9 (unit frame) with a seam at u = 0 / 1 (vertices
duplicated there) and a smooth texture periodic in u, and its analytic SDF f(x) = |x| − 0.9 (exact ∇f).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from neural_bake.errors import FitError, ImageError, MeshError, ModelFileError, NeuralBakeWarning
from neural_bake.fit.texture import (
    DEFAULT_DELTA,
    PRESETS,
    TextureFitConfig,
    band_orthogonality,
    fit_texture,
    pool_size,
    texel_face_weights,
    texture_metrics,
    texture_targets,
)
from neural_bake.fit.presets import REFERENCE_STEPS
from neural_bake.io.colour import linear_to_srgb
from neural_bake.fields import load_field, save_model
from neural_bake.nets.model_io import load_model
from neural_bake.nets.siren import Siren
from neural_bake.types import Frame, Mesh

R = 0.9
TINY = dict(width=32, depth=1, omega_0=5.0, steps=250, batch=1024, lr=1e-3, pool=20000, log_every=50)


def uv_sphere(n_lat=24, n_lon=48, tex_hw=(64, 128), radius=R):
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    V = radius * np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    UV = np.stack([P / (2 * np.pi), 1 - T / np.pi], -1).reshape(-1, 2)
    idx = np.arange((n_lat + 1) * (n_lon + 1)).reshape(n_lat + 1, n_lon + 1)
    faces = []
    for i in range(n_lat):
        for j in range(n_lon):
            a, b, c, d = idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]
            if i > 0:
                faces.append([a, b, d])
            if i < n_lat - 1:
                faces.append([b, c, d])
    F = np.array(faces, dtype=np.int64)
    h, w = tex_hw
    U, Vv = np.meshgrid((np.arange(w) + 0.5) / w, 1 - (np.arange(h) + 0.5) / h)
    tex = np.stack([0.5 + 0.35 * np.sin(2 * np.pi * U),
                    0.5 + 0.35 * np.cos(np.pi * Vv),
                    0.5 + 0.25 * np.sin(2 * np.pi * U) * np.sin(np.pi * Vv)], -1).astype(np.float32)
    vn = V / np.linalg.norm(V, axis=1, keepdims=True)
    return Mesh(vertices=V, faces=F, uv=UV[F], texture=tex, vertex_normals=vn, watertight=False)


def sphere_sdf(x: torch.Tensor):
    n = x.norm(dim=1, keepdim=True)
    return n[:, 0] - R, x / n.clamp_min(1e-12)


@pytest.fixture(scope="module")
def sphere():
    return uv_sphere()


@pytest.fixture(scope="module")
def fits(sphere):
    """λ = 0 and λ > 0 on the same seed and steps (shared by several tests)."""
    torch.set_num_threads(1)
    out = {}
    for lam in (0.0, 0.1):
        out[lam] = fit_texture(sphere, sphere_sdf, lam=lam, delta=0.03, seed=3, **TINY)
    return out


def constant_net(rgb, dtype=torch.float32) -> Siren:
    net = Siren(8, 0, 3, 3).to(dtype)
    with torch.no_grad():
        net.layers[-1].weight.zero_()
        net.layers[-1].bias.copy_(torch.tensor(rgb, dtype=dtype))
    return net


# ------------------------------------------------------------------------------------------- loss terms


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-10), (torch.float32, 1e-4)])
def test_band_orthogonality_matches_autograd_values_and_weight_gradients(dtype, tol):
    gen = torch.Generator().manual_seed(0)
    net = Siren(16, 2, 3, 3, omega_0=10.0, generator=gen).to(dtype)
    x = (torch.rand(64, 3, generator=gen, dtype=torch.float64) * 2 - 1).to(dtype)
    n = torch.nn.functional.normalize(torch.randn(64, 3, generator=gen, dtype=torch.float64), dim=1).to(dtype)

    got = band_orthogonality(net, x, n)
    # reference: ∂g_c/∂x by autograd (create_graph for the weight gradient), ⟨·, n⟩², summed over c
    xr = x.clone().requires_grad_(True)
    y = net(xr)
    rows = [torch.autograd.grad(y[:, c].sum(), xr, create_graph=True)[0] for c in range(3)]
    ref = sum(((r * n).sum(dim=1)) ** 2 for r in rows)
    scale = float(ref.detach().abs().max())
    assert torch.allclose(got, ref, atol=tol * scale, rtol=tol)

    w = net.layers[1].weight
    (g_got,) = torch.autograd.grad(got.mean(), w, retain_graph=True)
    (g_ref,) = torch.autograd.grad(ref.mean(), w)
    assert torch.allclose(g_got, g_ref, atol=tol * float(g_ref.abs().max()) * 10, rtol=tol * 10)


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-11), (torch.float32, 1e-5)])
def test_directional_method_matches_the_jacobian(dtype, tol):
    gen = torch.Generator().manual_seed(5)
    net = Siren(24, 2, 3, 3, generator=gen).to(dtype)
    x = (torch.rand(80, 3, generator=gen, dtype=torch.float64) * 2 - 1).to(dtype)
    n = torch.nn.functional.normalize(torch.randn(80, 3, generator=gen, dtype=torch.float64), dim=1).to(dtype)
    a = band_orthogonality(net, x, n, method="jacobian")
    b = band_orthogonality(net, x, n, method="directional")
    scale = float(a.detach().abs().max())
    assert torch.allclose(a, b, atol=tol * scale, rtol=tol * 10)
    ga = torch.autograd.grad(a.mean(), net.layers[0].weight)[0]
    gb = torch.autograd.grad(b.mean(), net.layers[0].weight)[0]
    assert torch.allclose(ga, gb, atol=tol * 10 * float(ga.abs().max()), rtol=tol * 10)
    with torch.no_grad():
        assert torch.allclose(band_orthogonality(net, x, n, method="directional", differentiable=False),
                              b.detach(), atol=tol * scale)
    with pytest.raises(FitError, match="orth_method: must be 'jacobian' or 'directional'"):
        band_orthogonality(net, x, n, method="autograd")


def test_band_orthogonality_is_zero_for_a_field_constant_along_the_normal():
    # a net that only depends on x_0, read along normals (0, ±1, 0) / (0, 0, 1): exactly orthogonal
    net = Siren(16, 1, 3, 3, omega_0=10.0, generator=torch.Generator().manual_seed(1)).double()
    with torch.no_grad():
        net.layers[0].weight[:, 1:] = 0
    x = torch.rand(50, 3, dtype=torch.float64)
    n = torch.tensor([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0]], dtype=torch.float64).repeat(25, 1)
    assert float(band_orthogonality(net, x, n).detach().abs().max()) < 1e-20
    along = band_orthogonality(net, x, torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64).repeat(50, 1)).detach()
    assert float(along.mean()) > 1e-3


# ------------------------------------------------------------------------------------------- metrics


def test_metrics_of_a_constant_net_are_exact(sphere):
    mesh = replace(sphere, texture=np.full((8, 8, 3), 0.25, np.float32))
    net = constant_net([0.25, 0.5, 0.75])
    m = texture_metrics(net, mesh, sphere_sdf, delta=0.05, n=2000, n_views=3, resolution=32)
    expected = (0.0 + 0.25**2 + 0.5**2) / 3
    assert m["surface_mse"] == pytest.approx(expected, rel=1e-5)
    assert m["surface_psnr"] == pytest.approx(10 * math.log10(1 / expected), rel=1e-5)
    assert m["texel_mse"] == pytest.approx(expected, rel=1e-5)
    enc = linear_to_srgb(np.array([0.25, 0.5, 0.75]))
    srgb_mse = float(np.mean((enc - enc[0]) ** 2))
    assert m["texel_psnr_srgb"] == pytest.approx(10 * math.log10(1 / srgb_mse), rel=1e-5)
    assert m["band_change"] == 0.0 and m["band_change_at_delta"] == 0.0 and m["band_change_read"] == 0.0
    assert m["render_mse"] == pytest.approx(expected, rel=1e-5)
    assert m["render_mse_band"] == pytest.approx(expected, rel=1e-5)
    assert len(m["render_mse_views"]) == 3 and m["delta"] == 0.05


def test_band_change_of_the_identity_colour_is_analytic(sphere):
    # g(x) = x on a sphere with radial ∇f: g(p ± t n) − g(p) = ±t n, mean |.| over channels = t·mean|n_i|,
    # and E|n_i| = 1/2 for directions uniform on the sphere.
    delta = 0.04
    m = texture_metrics(lambda x: x, sphere, sphere_sdf, delta=delta, n=20000, n_views=2, resolution=16)
    assert m["band_change_at_delta"] == pytest.approx(delta / 2, rel=0.02)
    assert m["band_change"] == pytest.approx(np.mean([0.25, 0.5, 0.75, 1.0]) * delta / 2, rel=0.02)
    # read as a bake reads it, at the closest point of f = 0 (on the sphere: p's own direction at radius R),
    # the band adds nothing: what is left is the distance of the mesh's flat facets from the sphere, in 7 of the
    # 8 reads (the 8th, δ inside a facet point already inside the sphere, is clamped to δ: back to the point)
    p = texture_targets(sphere, 20000)["points"].astype(np.float64)
    facets = np.abs(R * p / np.linalg.norm(p, axis=1, keepdims=True) - p).mean()
    assert m["band_change_read"] == pytest.approx(7 / 8 * facets, rel=0.02) and facets < 0.1 * m["band_change"]


# ------------------------------------------------------------------------------------------- fitting


def test_smooth_sphere_texture_reaches_a_quality_floor(sphere, fits):
    fit = fits[0.1]
    assert fit.steps == TINY["steps"] and fit.delta == 0.03 and fit.lam == 0.1
    assert fit.history[-1]["colour"] < fit.history[0]["colour"] / 5
    assert "orth" in fit.history[-1]
    m = texture_metrics(fit.field(), sphere, sphere_sdf, delta=0.03, n=5000, n_views=3, resolution=48)
    assert m["surface_psnr"] > 28.0
    assert m["render_mse"] < 2e-3


def test_orthogonality_term_reduces_colour_change_across_the_band(sphere, fits):
    m = {lam: texture_metrics(f.field(), sphere, sphere_sdf, delta=0.03, n=5000, n_views=2, resolution=32)
         for lam, f in fits.items()}
    assert "orth" not in fits[0.0].history[-1]
    assert m[0.1]["band_change"] < 0.5 * m[0.0]["band_change"]
    assert m[0.1]["band_change_at_delta"] < 0.5 * m[0.0]["band_change_at_delta"]
    # at a comparable surface quality (within 3 dB)
    assert m[0.1]["surface_psnr"] > m[0.0]["surface_psnr"] - 3.0


def test_colour_is_continuous_across_the_uv_seam(sphere, fits):
    # the texture is periodic in u, so the colour is continuous across the seam u = 0 / 1 in 3-D; so is g
    net = fits[0.1].model
    theta = np.linspace(0.3, np.pi - 0.3, 50)
    eps = 1e-3

    def at(phi):
        p = R * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
        with torch.no_grad():
            return net(torch.as_tensor(p, dtype=torch.float32)).numpy()

    seam = np.abs(at(eps) - at(-eps)).max()
    elsewhere = np.abs(at(np.pi + eps) - at(np.pi - eps)).max()
    assert seam < 0.01
    assert seam < 3 * elsewhere + 2e-3
    # and the training targets agree across the seam: nearest 3-D neighbours on the other side, same colour
    from scipy.spatial import cKDTree

    s = texture_targets(sphere, 40000, seed=0)
    u = s["uv"][:, 0]
    lo, hi = u < 0.01, u > 0.99
    dist, j = cKDTree(s["points"][hi]).query(s["points"][lo])
    close = dist < 0.01
    assert close.sum() > 20
    assert np.abs(s["colors"][lo][close] - s["colors"][hi][j[close]]).max() < 0.03


def test_same_seed_same_run_and_save_load_roundtrip(sphere, fits, tmp_path):
    again = fit_texture(sphere, sphere_sdf, lam=0.1, delta=0.03, seed=3, **TINY)
    x = torch.rand(100, 3) * 2 - 1
    with torch.no_grad():
        assert torch.equal(again.model(x), fits[0.1].model(x))
    path = fits[0.1].save(tmp_path / "tex.safetensors")
    model, meta = load_model(path)
    assert meta["kind"] == "texture" and meta["delta"] == 0.03 and meta["lam"] == 0.1
    assert Frame.from_dict(meta["frame"]) == sphere.frame
    assert meta["config"]["width"] == 32 and meta["steps"] == TINY["steps"]
    # the loss curve travels with the model, for the report's accuracy-against-time plot
    assert meta["training"]["steps"] == TINY["steps"] and meta["training"]["history"] == fits[0.1].history[-200:]
    assert meta["training"]["history"] and all("loss" in h and "seconds" in h for h in meta["training"]["history"])
    with torch.no_grad():
        assert torch.equal(model(x), fits[0.1].model(x))


def test_checkpoint_resume_continues_the_same_run(sphere, tmp_path):
    small = dict(TINY, steps=40, pool=4000, batch=256, lam=0.1, delta=0.03, lr_schedule="constant")
    full = fit_texture(sphere, sphere_sdf, **small)
    ck = tmp_path / "run.ckpt"
    fit_texture(sphere, sphere_sdf, **dict(small, steps=20), checkpoint=str(ck), checkpoint_every=10)
    resumed = fit_texture(sphere, sphere_sdf, **small, checkpoint=str(ck), resume=True)
    assert resumed.steps == 40
    x = torch.rand(100, 3) * 2 - 1
    with torch.no_grad():
        assert torch.allclose(resumed.model(x), full.model(x), atol=1e-5)


def test_sdf_model_file_gives_delta_and_frame(sphere, tmp_path):
    # a tiny Siren SDF of the sphere, fitted quickly; stored with kind "sdf", its frame and δ
    torch.manual_seed(0)
    sdf = Siren(32, 1, 3, 1, omega_0=5.0)
    opt = torch.optim.Adam(sdf.parameters(), lr=3e-3)
    for _ in range(150):
        x = torch.rand(1024, 3) * 2 - 1
        loss = ((sdf(x)[:, 0] - (x.norm(dim=1) - R)) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    path = save_model(sdf, tmp_path / "sphere.sdf", kind="sdf", frame=sphere.frame.to_dict(), delta=0.04)
    fit = fit_texture(sphere, str(path), **dict(TINY, steps=30, pool=4000, batch=256, lam=1e-3))
    assert fit.delta == 0.04 and fit.history[-1]["orth"] >= 0
    # without δ in the file: the stated default
    path2 = save_model(sdf, tmp_path / "nodelta.sdf", kind="sdf", frame=sphere.frame.to_dict())
    assert fit_texture(sphere, str(path2), **dict(TINY, steps=2, pool=2000, batch=64)).delta == DEFAULT_DELTA
    # another frame: refused
    other = save_model(sdf, tmp_path / "other.sdf", kind="sdf", frame={"center": [0, 0, 0], "scale": 2.0})
    with pytest.raises(FitError, match="another frame"):
        fit_texture(sphere, str(other), **dict(TINY, steps=2))
    # a texture file where an SDF is expected
    tex = save_model(Siren(8, 0, 3, 3), tmp_path / "t.tex", kind="texture")
    with pytest.raises(ModelFileError, match="expected an SDF model file"):
        fit_texture(sphere, str(tex), **dict(TINY, steps=2))
    with pytest.raises(FitError, match="scalar field"):
        fit_texture(sphere, Siren(8, 0, 3, 3), **dict(TINY, steps=2))


def test_presets_are_valid_and_applied(sphere):
    for name, values in PRESETS.items():
        assert values["minutes"] > 0
        replace(TextureFitConfig(), **values)
    fit = fit_texture(sphere, sphere_sdf, preset="fast", steps=3, pool=2000, batch=64, minutes=None)
    assert (fit.model.width, fit.model.depth) == (PRESETS["quick"]["width"], PRESETS["quick"]["depth"])
    assert fit.steps == 3 and fit.budget is None  # no time budget, no account
    # the shared names, and the earlier ones as aliases
    assert set(PRESETS) == {"quick", "default", "high"}
    for old, new in (("medium", "default"), ("fine", "high")):
        a = fit_texture(sphere, sphere_sdf, preset=old, steps=1, pool=2000, batch=64, minutes=None)
        assert (a.model.width, a.model.depth) == (PRESETS[new]["width"], PRESETS[new]["depth"])
    with pytest.raises(FitError, match="unknown preset 'huge'.*fast, medium, fine are aliases"):
        fit_texture(sphere, sphere_sdf, preset="huge", steps=1)
    # the orthogonality term is off by default (bakes read g at the closest point of f = 0), on when asked
    assert TextureFitConfig().lam == 0 and fit.lam == 0 and "orth" not in fit.history[-1]
    on = fit_texture(sphere, sphere_sdf, preset="quick", lam=1e-3, steps=1, pool=2000, batch=64, minutes=None)
    assert on.lam == 1e-3 and "orth" in on.history[-1]


# ------------------------------------------------------------------------------------------- texture policies


def test_alpha_is_ignored_with_a_warning(sphere):
    rgba = np.concatenate([sphere.texture, np.full(sphere.texture.shape[:2] + (1,), 0.5, np.float32)], axis=2)
    with pytest.warns(NeuralBakeWarning, match="alpha below 1; fitting RGB only"):
        s = texture_targets(replace(sphere, texture=rgba), 500, seed=1)
    ref = texture_targets(sphere, 500, seed=1)
    assert np.array_equal(s["colors"], ref["colors"])


def test_16_bit_textures_are_decoded_from_srgb_and_float_textures_kept(sphere):
    u16 = np.round(linear_to_srgb(sphere.texture) * 65535).astype(np.uint16)
    a = texture_targets(sphere, 1000, seed=2, texture=u16)["colors"]
    b = texture_targets(sphere, 1000, seed=2)["colors"]
    assert np.abs(a - b).max() < 1e-4
    hdr = sphere.texture * 4.0  # float: linear data, values above 1 kept
    c = texture_targets(sphere, 1000, seed=2, texture=hdr)["colors"]
    assert np.allclose(c, 4 * b, rtol=1e-5) and c.max() > 1.0


def test_the_network_holds_srgb_colours_and_its_field_reads_linear(sphere, fits, tmp_path):
    # the default ("auto") fits an 8-bit-range texture sRGB-encoded; the field, the file and the metrics
    # decode it, so every reader sees linear RGB
    fit = fits[0.0]
    assert fit.encoding == "srgb" and fit.metadata()["encoding"] == "srgb"
    s = texture_targets(sphere, 2000, seed=5)
    x = torch.as_tensor(s["points"])
    with torch.no_grad():
        raw = fit.model(x).numpy()
    lin = fit.field().color(x).numpy()
    assert np.abs(raw - linear_to_srgb(s["colors"])).mean() < 0.02  # the network: sRGB
    assert np.abs(lin - s["colors"]).mean() < 0.02  # its field: linear
    back = load_field(fit.save(tmp_path / "g.tex"))
    assert back.encoding == "srgb" and torch.allclose(back.color(x), fit.field().color(x))
    m = texture_metrics(fit.field(), sphere, sphere_sdf, delta=0.03, n=3000, n_views=2, resolution=32)
    t = texture_targets(sphere, 3000, seed=0)  # the metrics' samples
    mse = np.mean((fit.field().color(torch.as_tensor(t["points"])).double().numpy() - t["colors"]) ** 2)
    assert m["surface_mse"] == pytest.approx(float(mse), rel=1e-4)


def test_hdr_textures_and_an_explicit_linear_encoding_fit_linear_colours(sphere):
    hdr = fit_texture(sphere, sphere_sdf, texture=sphere.texture * 4.0, **dict(TINY, steps=2))
    assert hdr.encoding == "linear"
    lin = fit_texture(sphere, sphere_sdf, encoding="linear", **dict(TINY, steps=2))
    x = torch.rand(50, 3) * 2 - 1
    with torch.no_grad():
        assert lin.encoding == "linear" and torch.equal(lin.field().color(x), lin.model(x))


def test_texel_share_draws_samples_as_densely_as_the_texels_lie(sphere):
    # the UV sphere's texels are uniform in (φ, θ): drawn by UV area, θ is about uniform and E|z| ≈ R·2/π;
    # drawn by surface area, z is about uniform and E|z| ≈ R/2. Exactly, on the faceted mesh (no face crosses
    # z = 0, so a face's mean |z| is its centroid's): Σ_f w_f |z_f| with w the area or the UV-area shares
    z = {share: np.abs(texture_targets(sphere, 60000, seed=4, texel_share=share)["points"][:, 2]).mean()
         for share in (0.0, 0.5, 1.0)}
    zc = np.abs(sphere.vertices[sphere.faces][:, :, 2].mean(axis=1))
    d1, d2 = sphere.uv[:, 1] - sphere.uv[:, 0], sphere.uv[:, 2] - sphere.uv[:, 0]
    by_area = sphere.face_areas / sphere.face_areas.sum()
    by_uv = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    by_uv = by_uv / by_uv.sum()
    for share, w in ((0.0, by_area), (1.0, by_uv), (0.5, (by_area + by_uv) / 2)):
        assert z[share] == pytest.approx(float((w * zc).sum()), rel=0.01)
    assert z[0.0] == pytest.approx(R / 2, rel=0.05) and z[1.0] == pytest.approx(R * 2 / math.pi, rel=0.05)
    # no UVs, or UVs of no area: by surface area alone
    assert texel_face_weights(replace(sphere, uv=None), 0.5) is None
    assert texel_face_weights(replace(sphere, uv=np.zeros_like(sphere.uv)), 1.0) is None
    w = texel_face_weights(sphere, 0.5)
    assert w.shape == (sphere.n_faces,) and w.sum() == pytest.approx(1.0) and (w > 0).all()


def test_uvs_outside_unit_square_follow_the_mesh_policy(sphere):
    shifted = replace(sphere, uv=sphere.uv + np.array([1.0, -2.0]))
    a = texture_targets(shifted, 1000, seed=4)["colors"]
    b = texture_targets(sphere, 1000, seed=4)["colors"]
    assert np.allclose(a, b, atol=1e-5)  # wrap: UV + integers reads the same texel
    clamped = texture_targets(replace(shifted, uv_policy="clamp"), 1000, seed=4)["colors"]
    assert not np.allclose(clamped, b, atol=1e-3)


@pytest.mark.parametrize("name,bits,tol", [("t16.png", 16, 1e-4), ("t8.png", 8, 6e-3), ("t.exr", 32, 1e-6),
                                           ("rgba.png", 16, 1e-4)])
def test_texture_files_of_any_depth_give_the_same_targets(tmp_path, name, bits, tol):
    # the bundled sphere read with its own texture replaced by 8/16-bit sRGB PNG, float EXR, or RGBA copies
    from neural_bake.io.images import write_image
    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.samples import sample_path

    mesh = load_mesh(sample_path("sphere"))
    img = mesh.texture[..., :3]
    if name.startswith("rgba"):
        img = np.concatenate([img, np.full(img.shape[:2] + (1,), 0.25, np.float32)], axis=2)
    path = write_image(tmp_path / name, img, bits=bits)
    other = load_mesh(sample_path("sphere"), path)
    if name.startswith("rgba"):
        with pytest.warns(NeuralBakeWarning, match="alpha below 1"):
            got = texture_targets(other, 2000, seed=7)["colors"]
    else:
        got = texture_targets(other, 2000, seed=7)["colors"]
    ref = texture_targets(mesh, 2000, seed=7)["colors"]
    assert np.abs(got - ref).max() < tol


# ------------------------------------------------------------------------------------------- errors


def test_mesh_without_uvs_or_texture_is_a_clear_error(sphere):
    with pytest.raises(MeshError, match="no UV coordinates"):
        fit_texture(replace(sphere, uv=None), sphere_sdf, **TINY)
    with pytest.raises(MeshError, match="no texture image"):
        fit_texture(replace(sphere, texture=None), sphere_sdf, **TINY)
    with pytest.raises(MeshError, match="no UV coordinates"):
        texture_metrics(constant_net([0, 0, 0]), replace(sphere, uv=None), sphere_sdf)


def test_bad_textures_are_clear_errors(sphere):
    bad = sphere.texture.copy()
    bad[3, 4, 1] = np.nan
    with pytest.raises(ImageError, match="1 texels with NaN"):
        fit_texture(sphere, sphere_sdf, texture=bad, **TINY)
    with pytest.raises(ImageError, match=r"must be \(H, W, C\)"):
        fit_texture(sphere, sphere_sdf, texture=np.zeros((4, 4, 5), np.float32), **TINY)


@pytest.mark.parametrize("override,message", [
    ({"lam": -1.0}, "lam: must be a finite number >= 0"),
    ({"delta": 0.0}, r"delta: must be in \(0, 1\]"),
    ({"width": 0}, "width: must be a positive integer"),
    ({"depth": -1}, "depth: must be a non-negative integer"),
    ({"lr": float("nan")}, "lr: must be a positive number"),
    ({"minutes": -2.0}, "minutes: must be a positive number"),
    ({"band_uniform_fraction": 1.5}, r"band_uniform_fraction: must be in \[0, 1\]"),
    ({"dtype": "float16"}, "dtype: must be 'float32' or 'float64'"),
    ({"lr_schedule": "step"}, "lr_schedule: must be 'constant' or 'cosine'"),
    ({"orth_method": "autograd"}, "orth_method: must be 'jacobian' or 'directional'"),
    ({"encoding": "gamma"}, "encoding: must be 'auto', 'srgb' or 'linear'"),
    ({"texel_share": 1.5}, r"texel_share: must be in \[0, 1\]"),
    ({"preset": "huge"}, "unknown preset 'huge'"),
    ({"colour_weight": 2}, "unknown option 'colour_weight'"),
])
def test_bad_config_is_a_fit_error(sphere, override, message):
    with pytest.raises(FitError, match=message):
        fit_texture(sphere, sphere_sdf, **dict(TINY, **override))


def test_wrong_sdf_argument_and_empty_band_are_fit_errors(sphere):
    with pytest.raises(FitError, match="expected a Siren, a field, a model file path or a callable"):
        fit_texture(sphere, 3.5, **TINY)

    def far(x):  # an SDF whose zero set is nowhere near the mesh and whose gradient vanishes
        return torch.full((x.shape[0],), 5.0, dtype=x.dtype), torch.zeros_like(x)

    with pytest.raises(FitError, match="no band samples"):
        fit_texture(sphere, far, **TINY, lam=0.1)
    # without the orthogonality term the band is not drawn: nothing to refuse here (the bake checks the SDF)
    assert fit_texture(sphere, far, **dict(TINY, steps=2)).steps == 2


# ------------------------------------------------------------------------------------------- CLI


@pytest.fixture(scope="module")
def sphere_files(tmp_path_factory):
    """The bundled sphere sample and a tiny Siren SDF of it (kind "sdf", its frame, δ = 0.04)."""
    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.samples import sample_path

    path = sample_path("sphere")
    mesh = load_mesh(path)
    torch.manual_seed(0)
    sdf = Siren(32, 1, 3, 1, omega_0=5.0)
    opt = torch.optim.Adam(sdf.parameters(), lr=3e-3)
    radius = float(np.linalg.norm(mesh.vertices, axis=1).max())
    for _ in range(150):
        x = torch.rand(1024, 3) * 2 - 1
        loss = ((sdf(x)[:, 0] - (x.norm(dim=1) - radius)) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    folder = tmp_path_factory.mktemp("cli")
    sdf_path = save_model(sdf, folder / "sphere.sdf", kind="sdf", frame=mesh.frame.to_dict(), delta=0.04)
    return path, sdf_path, folder


def test_cli_fit_texture_writes_a_texture_model(sphere_files, capsys):
    from neural_bake.cli.main import main

    mesh_path, sdf_path, folder = sphere_files
    out = folder / "sphere.tex"
    code = main(["fit", "texture", str(mesh_path), "--sdf", str(sdf_path), "-o", str(out), "--width", "32",
                 "--depth", "1", "--steps", "40", "--batch", "256", "--lam", "0.05", "--no-progress"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "fitted (32, 1) texture" in text and "40 steps" in text and "δ = 0.04" in text
    assert "surface PSNR" in text and "render MSE" in text and f"wrote {out}" in text
    model, meta = load_model(out)
    assert meta["kind"] == "texture" and meta["lam"] == 0.05 and meta["delta"] == 0.04
    assert (model.in_dim, model.out_dim, model.width) == (3, 3, 32)


def test_cli_fit_texture_user_errors_are_one_line(sphere_files, tmp_path, capsys):
    from neural_bake.cli.main import main

    mesh_path, sdf_path, _ = sphere_files
    out = tmp_path / "x.tex"
    code = main(["fit", "texture", str(mesh_path), "--sdf", str(sdf_path), "-o", str(out), "--lam", "-1",
                 "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "neural-bake: error: lam: must be a finite number >= 0" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()
    code = main(["fit", "texture", str(mesh_path), "--sdf", str(tmp_path / "missing.sdf"), "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "missing.sdf" in err and not out.exists()
    # a mesh without UVs
    import trimesh

    plain = tmp_path / "plain.ply"
    trimesh.creation.icosphere(2).export(plain)
    code = main(["fit", "texture", str(plain), "--sdf", str(sdf_path), "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "no UV coordinates" in err and "plain.ply" in err


# ------------------------------------------------------------------------------------------- benchmark parts


def test_bench_mesh_sdf_is_the_exact_distance_of_the_sphere():
    from neural_bake.bench.texture import latlong_sphere, mesh_sdf

    mesh = latlong_sphere(48, 96, (16, 32))
    f = mesh_sdf(mesh)
    x = torch.as_tensor(np.random.default_rng(0).uniform(-1, 1, (500, 3)))
    x = x[(x.norm(dim=1) - R).abs() > 0.02]
    v, g = f(x)
    r = x.norm(dim=1)
    # the polyhedron is inscribed: its distance is within the chord sag (R (1 − cos(π/48)) ≈ 0.0019) of |x| − R
    assert torch.allclose(v, r - R, atol=2.5e-3)
    assert float((g * (x / r[:, None])).sum(dim=1).min()) > 0.99
    assert x.dtype == v.dtype == g.dtype


def test_bench_run_with_tiny_settings_reports_the_lam0_baselines():
    from neural_bake.bench.texture import run

    tiny = {"label": "tiny", "width": 16, "depth": 0, "steps": 30, "batch": 128, "pool": 3000, "lam": 0.05,
            "lr": 1e-3}
    res = run(quick=True, cases=["sphere", "checker8"],
              settings=[tiny, dict(tiny, label="t2", equal_time=False, only=["checker8"])])
    rows = res["tables"]["accuracy"]
    eq = ("", "λ=0 equal steps", "λ=0 equal time")
    assert [(r["case"], r["setting"], r["baseline"]) for r in rows] == (
        [("sphere", "tiny", b) for b in eq] + [("checker8", "tiny", b) for b in eq]
        + [("checker8", "t2", b) for b in eq[:2]])
    for main_row, base in [(rows[0], rows[1]), (rows[3], rows[4]), (rows[6], rows[7])]:
        assert main_row["steps"] == base["steps"] == 30 and base["lam"] == 0.0
        assert main_row["band_ratio"] == pytest.approx(base["band_change"] / main_row["band_change"])
    assert res["name"] == "texture" and res["machine"]["cores"] and res["tables"]["orthogonality term cost per step"]
    from neural_bake.nets import grid

    (g,) = res["tables"]["feature grid: C kernel against torch's encoding"]
    assert g["kernel"] == grid.kernel_status() and g["adam"] == "fused" and g["eval_points"] == 8192
    assert g["eval_s"] > 0 and g["step_s"] > 0 and g["eval_torch/kernel"] == pytest.approx(g["eval_torch_s"] / g["eval_s"])


def test_bench_default_settings_by_preset():
    from neural_bake.bench.texture import default_settings

    full = default_settings(False)
    assert [s["label"] for s in full] == ["quick", "default", "high"] and full[2]["only"] == ["sphere", "spot"]
    picked = default_settings(False, ["default", "fine"], lam=0.5)  # an earlier name is an alias
    assert [(s["label"], s["preset"], s["lam"]) for s in picked] == [("default", "default", 0.5), ("high", "high", 0.5)]
    assert all("only" not in s for s in picked)  # a preset asked for runs on every case
    assert len(default_settings(True)) == 1


def test_bench_unknown_case_is_a_one_line_cli_error(capsys):
    from neural_bake.cli.main import main

    assert main(["bench", "texture", "--quick", "--case", "cube"]) == 2
    assert "neural-bake: error: --case: unknown case 'cube'" in capsys.readouterr().err
    assert main(["bench", "texture", "--quick", "--case", "checkerx"]) == 2
    assert "'checkerx' needs a positive cell count" in capsys.readouterr().err
    assert main(["bench", "texture", "--quick", "--preset", "huge"]) == 2
    assert "neural-bake: error: --preset: unknown preset 'huge' (choose quick, default, high)" in capsys.readouterr().err


def test_a_large_pool_offsets_a_seeded_subset_of_it_into_the_band(sphere, monkeypatch):
    """The band pool (λ > 0) takes at most BAND_POOL of the surface samples and as many uniform candidates:
    each costs f and ∇f, while the colour loss reads the whole pool."""
    import neural_bake.fit.texture as texture

    calls = []
    real = texture._band_pool

    def spy(points, normals, sdf, delta, n_uniform, gen):
        calls.append((points.shape[0], points.dtype, n_uniform))
        out = real(points, normals, sdf, delta, n_uniform, gen)
        # each offset point is within δ of a sample on the tessellated sphere (its faces lie a little inside)
        assert (out[0].norm(dim=1) - R).abs().max() <= 0.03 + 0.005
        return out

    monkeypatch.setattr(texture, "_band_pool", spy)
    monkeypatch.setattr(texture, "BAND_POOL", 1500)
    small = dict(TINY, steps=100, batch=64, lam=1e-3, delta=0.03, minutes=None)
    fit_texture(sphere, sphere_sdf, **dict(small, pool=6000))
    fit_texture(sphere, sphere_sdf, **dict(small, pool=1000))
    assert calls == [(1500, torch.float64, 1500), (1000, torch.float64, 1000)]
    # a pool is never larger than the samples the steps read
    assert pool_size(TextureFitConfig(steps=10, batch=64, pool=6000)) == 640
    assert pool_size(TextureFitConfig(steps=1000, batch=64, pool=6000)) == 6000
    # a time-budgeted preset fit: the steps its minutes make on the reference machine
    quick = TextureFitConfig(**PRESETS["quick"])
    assert pool_size(quick, "quick") == PRESETS["quick"]["pool"]
    short = replace(quick, minutes=PRESETS["quick"]["minutes"] / 100)
    assert pool_size(short, "quick") == math.ceil(REFERENCE_STEPS["texture:quick"] / 100) * quick.batch
    assert pool_size(short) == quick.pool  # no preset: no step count to go by but the cap
