"""Texture fits with the feature-grid network (``network="grid"``): a flat-colour disc keeps its edge, the
orthogonality term applies to it, the model file round-trips, and bad settings are one-line errors.

The disc oracle: a flat square (z = 0, unit frame) whose UVs map it onto a 64² texture holding a flat background
and one disc 20 texels across; its SDF is f(x) = z. The fitted network, read at every texel's centre, is
classified disc or background (nearer one colour than the other along the line between them) and compared with
the analytic disc.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neural_bake.errors import FitError
from neural_bake.fields import TextureField, load_field
from neural_bake.fit.texture import (TextureFitConfig, band_orthogonality, edge_strength, fit_texture,
                                     make_texture_network, texture_targets)
from neural_bake.io.colour import linear_to_srgb
from neural_bake.nets.grid import GridNet
from neural_bake.nets.siren import Siren
from neural_bake.types import Mesh

SIDE = 64  # texels per side of the disc texture
HALF = 0.9  # the square is [-HALF, HALF]² at z = 0
DIAMETER = 20.0  # the disc, in texels
BACKGROUND, DISC = np.array([0.75, 0.62, 0.38]), np.array([0.03, 0.12, 0.6])  # linear RGB
GRID = dict(network="grid", grid_levels=6, grid_features=2, grid_log2_table=14, grid_base_resolution=8,
            grid_max_resolution=128, width=32, depth=1)


def disc_square(n: int = 8) -> Mesh:
    """The flat square as an n×n grid of quads, uv = (x, y) mapped onto [0, 1]², with the disc texture."""
    t = np.linspace(-HALF, HALF, n + 1)
    X, Y = np.meshgrid(t, t, indexing="xy")
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    uv = (V[:, :2] + HALF) / (2 * HALF)
    yy, xx = np.mgrid[0:SIDE, 0:SIDE] + 0.5  # texel centres, row 0 at the top (v = 1)
    inside = np.hypot(xx - SIDE / 2, yy - SIDE / 2) < DIAMETER / 2
    tex = np.where(inside[..., None], DISC, BACKGROUND).astype(np.float32)
    vn = np.tile([0.0, 0.0, 1.0], (len(V), 1))
    return Mesh(vertices=V, faces=F, uv=uv[F], texture=tex, vertex_normals=vn, watertight=False)


def plane_sdf(x: torch.Tensor):
    return x[:, 2], torch.zeros_like(x) + torch.tensor([0.0, 0.0, 1.0], dtype=x.dtype)


def texel_points() -> tuple[np.ndarray, np.ndarray]:
    """The unit-frame points of every texel centre (SIDE², 3) and their distance to the disc's centre in texels."""
    yy, xx = np.mgrid[0:SIDE, 0:SIDE] + 0.5
    u, v = xx / SIDE, 1.0 - yy / SIDE
    pts = np.stack([u * 2 * HALF - HALF, v * 2 * HALF - HALF, np.zeros_like(u)], -1).reshape(-1, 3)
    return pts, np.hypot(xx - SIDE / 2, yy - SIDE / 2).ravel()


@pytest.fixture(scope="module")
def disc_fit():
    torch.set_num_threads(1)
    return fit_texture(disc_square(), plane_sdf, steps=400, minutes=None, batch=2048, pool=40000, lr=1e-2,
                       texel_share=0.0, seed=1, **GRID)


def test_a_flat_colour_disc_keeps_its_edge_within_a_texel(disc_fit):
    assert isinstance(disc_fit.model, GridNet) and disc_fit.encoding == "srgb"
    pts, r = texel_points()
    with torch.no_grad():
        got = linear_to_srgb(disc_fit.field().color(torch.as_tensor(pts, dtype=torch.float32)).double().numpy())
    bg, disc = linear_to_srgb(BACKGROUND), linear_to_srgb(DISC)
    t = ((got - bg) @ (disc - bg)) / float((disc - bg) @ (disc - bg))
    baked, truth = t > 0.5, r < DIAMETER / 2
    wrong = baked != truth
    assert np.all(np.abs(r[wrong] - DIAMETER / 2) <= 1.0), np.sort(np.abs(r[wrong] - DIAMETER / 2))[-5:]
    assert abs(np.sqrt(baked.sum() / np.pi) - np.sqrt(truth.sum() / np.pi)) <= 0.5
    # flat inside and out: away from the edge, every texel within 0.05 of its colour (sRGB) in each channel
    far = np.abs(r - DIAMETER / 2) > 2.0
    want = np.where(truth[:, None], disc, bg)
    assert np.abs(got - want)[far].max() < 0.05


def test_grid_fit_saves_and_loads_exactly(disc_fit, tmp_path):
    path = disc_fit.save(tmp_path / "g.tex")
    back = load_field(path)
    assert isinstance(back, TextureField) and isinstance(back.model, GridNet)
    assert back.metadata["config"]["network"] == "grid" and back.metadata["config"]["grid_levels"] == 6
    x = torch.rand(500, 3) * 2 - 1
    assert torch.equal(back.color(x), disc_fit.field().color(x))


def test_orthogonality_term_of_a_grid_network():
    """Both methods give Σ_c ⟨∇g_c, n⟩² as finite differences do, and train the table and the MLP."""
    net = make_texture_network(TextureFitConfig(**GRID), torch.Generator().manual_seed(0)).double()
    with torch.no_grad():
        net.table.normal_(generator=torch.Generator().manual_seed(1))
    gen = torch.Generator().manual_seed(2)
    x = torch.rand(64, 3, generator=gen, dtype=torch.float64) * 1.6 - 0.8
    n = torch.nn.functional.normalize(torch.randn(64, 3, generator=gen, dtype=torch.float64), dim=1)
    eps = 1e-7
    fd = (net(x + eps * n) - net(x - eps * n)) / (2 * eps)
    want = (fd ** 2).sum(1)
    for method in ("jacobian", "directional"):
        got = band_orthogonality(net, x, n, method=method)
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6 * want.max().item())
        net.zero_grad()
        got.mean().backward()
        assert net.table.grad.abs().sum() > 0 and net.layers[0].weight.grad.abs().sum() > 0
        assert not band_orthogonality(net, x, n, method=method, differentiable=False).requires_grad


def test_grid_fit_with_the_orthogonality_term_runs():
    torch.set_num_threads(1)
    fit = fit_texture(disc_square(4), plane_sdf, steps=20, minutes=None, batch=256, pool=4000, lam=1e-3, delta=0.05,
                      **GRID)
    assert all(np.isfinite(h["orth"]) for h in fit.history if "orth" in h)


def test_siren_stays_the_default_network():
    assert TextureFitConfig().network == "siren"
    assert isinstance(make_texture_network(TextureFitConfig(width=8, depth=1)), Siren)


@pytest.mark.parametrize("over,message", [
    ({"network": "octree"}, r"^network: must be one of siren, grid, got 'octree'$"),
    ({"grid_levels": 0}, r"^grid_levels: must be an integer in 1\.\.32, got 0$"),
    ({"grid_features": 99}, r"^grid_features: must be an integer in 1\.\.16, got 99$"),
    ({"grid_log2_table": 3}, r"^grid_log2_table: must be an integer in 4\.\.24, got 3$"),
    ({"grid_base_resolution": 2048}, r"^grid_base_resolution: must be an integer in 1\.\.1024, got 2048$"),
    ({"grid_max_resolution": 0}, r"^grid_max_resolution: must be an integer in 1\.\.65536, got 0$"),
    ({"grid_activation": "tanh"}, r"^grid_activation: must be one of relu, sine, got 'tanh'$"),
    ({"normal_inputs": "on", "network": "siren"}, r'^normal_inputs: needs network "grid" \(a SIREN colour network '
                                                  r"reads points only\), got network 'siren'$"),
    ({"normal_inputs": True}, r"^normal_inputs: must be one of off, on, auto, got True$"),
    ({"normal_jitter_deg": 91}, r"^normal_jitter_deg: must be a number of degrees in \[0, 90\], got 91$"),
    ({"normal_jitter_deg": float("nan")}, r"^normal_jitter_deg: must be a number of degrees in \[0, 90\], got nan$"),
])
def test_bad_network_settings_are_one_line_errors(over, message):
    with pytest.raises(FitError, match=message) as err:
        fit_texture(disc_square(2), plane_sdf, steps=1, **over)
    assert err.value.parameter == message.split(":")[0].lstrip("^")


def test_quick_and_default_presets_are_grids_and_network_siren_gives_their_sirens():
    from neural_bake.fit.texture import PRESET_SIRENS, _resolve_config

    quick = _resolve_config(None, {"preset": "quick"})
    assert (quick.network, quick.width, quick.depth, quick.lr, quick.edge_share, quick.normal_inputs, quick.pool) == (
        "grid", 64, 1, 1e-2, 0.5, "auto", 4_000_000)
    siren = _resolve_config(None, {"preset": "quick", "network": "siren"})
    assert (siren.network, siren.width, siren.depth, siren.lr, siren.edge_share, siren.normal_inputs) == (
        "siren", 64, 1, 5e-4, 0.0, "off") == ("siren", *PRESET_SIRENS["quick"].values())
    wide = _resolve_config(None, {"preset": "quick", "network": "siren", "width": 128})
    assert (wide.width, wide.lr) == (128, 5e-4)
    default = _resolve_config(None, {"preset": "default"})
    assert (default.network, default.width, default.batch, default.lr, default.edge_share, default.normal_inputs,
            default.pool) == ("grid", 64, 4096, 1e-2, 0.5, "auto", 8_000_000)
    siren = _resolve_config(None, {"preset": "default", "network": "siren"})
    assert (siren.network, siren.width, siren.depth, siren.omega_0, siren.lr, siren.normal_inputs) == (
        "siren", 192, 3, 60.0, 5e-4, "off")
    assert _resolve_config(None, {"preset": "high"}).network == "siren"


def _texel_distance_to_edge(uv: np.ndarray) -> np.ndarray:
    """Distance in texels of UV points (n, 2) of the disc texture from the disc's border circle."""
    xx, yy = uv[:, 0] * SIDE, (1.0 - uv[:, 1]) * SIDE
    return np.abs(np.hypot(xx - SIDE / 2, yy - SIDE / 2) - DIAMETER / 2)


def test_edge_strength_marks_both_sides_of_the_disc_border_only():
    mesh = disc_square()
    strength = edge_strength(mesh.texture)
    yy, xx = np.mgrid[0:SIDE, 0:SIDE] + 0.5
    dist = np.abs(np.hypot(xx - SIDE / 2, yy - SIDE / 2) - DIAMETER / 2)
    step = np.abs(DISC - BACKGROUND).max()
    assert strength[dist < 0.5].min() == pytest.approx(step, rel=1e-6)  # on the border: the full step
    assert (strength[dist > 3.5] == 0).all()  # flat colour away from it: nothing
    assert edge_strength(np.ones((8, 8, 3), np.float32)).max() == 0


def test_edge_share_draws_that_part_of_the_samples_at_the_texture_edges():
    """The disc oracle: the band within 3.5 texels of the border circle (the edge strength's support: the
    texels on both sides of the border, spread by one, read bilinearly) holds about 11 % of the square; with
    edge_share 0.3, 0.3 + 0.7 × that of the samples lie there, and their colours are the texture's."""
    mesh = disc_square()
    n = 40000
    plain = texture_targets(mesh, n, seed=3)
    edged = texture_targets(mesh, n, seed=3, edge_share=0.3)
    assert len(edged["points"]) == n and edged["points"].dtype == np.float32
    near_plain = (_texel_distance_to_edge(plain["uv"]) < 3.5).mean()
    near_edged = (_texel_distance_to_edge(edged["uv"]) < 3.5).mean()
    assert 0.08 < near_plain < 0.14
    assert near_edged == pytest.approx(0.3 + 0.7 * near_plain, abs=0.02)
    # fresh places, not repeats of the pool's samples
    assert len(np.unique(edged["points"], axis=0)) > 0.95 * n
    # every sample's colour is the texture's at its UV, and its point is the square's at that UV
    np.testing.assert_allclose(edged["points"][:, :2], edged["uv"] * 2 * HALF - HALF, atol=1e-5)
    inside = _texel_distance_to_edge(edged["uv"]) > 2.0  # past the pixelated border and its bilinear blend
    disc = np.hypot(edged["uv"][:, 0] * SIDE - SIDE / 2, (1 - edged["uv"][:, 1]) * SIDE - SIDE / 2) < DIAMETER / 2
    want = np.where(disc[:, None], DISC, BACKGROUND)
    np.testing.assert_allclose(edged["colors"][inside], want[inside], atol=1e-6)
    # edge_share 0 draws exactly what it drew before; a texture without edges draws its edge part uniformly
    np.testing.assert_array_equal(texture_targets(mesh, n, seed=3, edge_share=0.0)["points"], plain["points"])
    flat = Mesh(vertices=mesh.vertices, faces=mesh.faces, uv=mesh.uv, texture=np.ones((8, 8, 3), np.float32),
                vertex_normals=mesh.vertex_normals, watertight=False)
    assert len(texture_targets(flat, 1000, seed=3, edge_share=0.5)["points"]) == 1000


@pytest.mark.parametrize("value", [-0.1, 1.5, True, "a"])
def test_edge_share_out_of_range_is_a_one_line_error(value):
    with pytest.raises(FitError, match=r"edge_share: must be in \[0, 1\]"):
        fit_texture(disc_square(), plane_sdf, steps=1, minutes=None, edge_share=value, **GRID)


# ------------------------------------------------------------------------------------------ normal inputs
# The two-sided oracle: a board 1e-4 thick (unit frame), its top face mapped onto the red half of the texture and
# its bottom face onto the blue half. The grid's finest cell (1/8) is far wider than the board: read by the point
# alone, both faces get one colour; with the normal beside it each keeps its own.
THICK = 1e-4
RED, BLUE = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
SMALL_GRID = dict(network="grid", grid_levels=4, grid_features=2, grid_log2_table=12, grid_base_resolution=2,
                  grid_max_resolution=16, width=16, depth=1)


def two_sided_board() -> Mesh:
    h = THICK / 2
    V = np.array([[x, y, z] for z in (-h, h) for y in (-0.5, 0.5) for x in (-0.5, 0.5)], dtype=np.float64)
    quads = [(4, 5, 7, 6), (0, 2, 3, 1), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]  # top, bottom, sides
    F = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)

    def uv(p, face):  # top: u in [0.05, 0.45] (red); bottom and sides: u in [0.55, 0.95] (blue) or a red strip
        u0 = 0.05 if face < 2 else (0.55 if face < 4 else 0.1)
        return [u0 + 0.4 * (p[0] + 0.5), 0.05 + 0.9 * (p[1] + 0.5)]

    uvs = np.array([[uv(V[i], f) for i in tri] for f, tri in enumerate(F)])
    tex = np.zeros((32, 32, 3), dtype=np.float32)
    tex[:, :16], tex[:, 16:] = RED, BLUE
    mesh = Mesh(vertices=V, faces=F, uv=uvs, texture=tex, watertight=True)
    top = mesh.face_normals[0]
    assert top[2] > 0.99 and mesh.face_normals[2][2] < -0.99  # outward: the top faces up, the bottom down
    return mesh


def board_sdf(x: torch.Tensor):
    return x[:, 2].abs() - THICK / 2, torch.stack([0 * x[:, 0], 0 * x[:, 0], torch.sign(x[:, 2])], dim=1)


@pytest.mark.parametrize("setting,sided", [("off", False), ("on", True), ("auto", False)])
def test_normal_inputs_keep_the_two_sides_of_a_thin_board_apart(tmp_path, setting, sided):
    # "auto" reads normals on an open mesh only: the board is closed
    torch.set_num_threads(1)
    fit = fit_texture(two_sided_board(), board_sdf, steps=300, minutes=None, batch=1024, pool=20000, lr=1e-2,
                      seed=2, normal_inputs=setting, **SMALL_GRID)
    field = load_field(fit.save(tmp_path / "t.safetensors"))
    assert field.normal_inputs == sided == fit.model.normal_inputs
    xy = np.random.default_rng(3).uniform(-0.4, 0.4, (200, 2))
    errors = []
    for z, n, want in ((THICK / 2, 1.0, RED), (-THICK / 2, -1.0, BLUE)):
        pts = torch.as_tensor(np.column_stack([xy, np.full(200, z)]), dtype=torch.float32)
        normals = torch.tensor([[0.0, 0.0, n]]).expand(200, 3)
        got = field.color(pts, normals).double().numpy()
        errors.append(np.abs(got - want).max())
    if sided:
        assert max(errors) < 0.05  # each face its own colour
        from neural_bake.fit.texture import texture_metrics

        metrics = texture_metrics(field, two_sided_board(), board_sdf, n=2000, n_views=2, resolution=32)
        assert metrics["texel_psnr"] > 20 and metrics["render_mse"] is not None
    else:
        assert min(errors) > 0.3  # one colour for both: each face is far from its own


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_tilted_normals_stay_unit_within_the_angle_and_spread_over_it(dtype):
    from neural_bake.fit.texture import tilt_normals

    n = torch.nn.functional.normalize(torch.randn(4000, 3, generator=torch.Generator().manual_seed(0)), dim=1)
    n = torch.cat([n, torch.zeros(1, 3)]).to(dtype)
    out = tilt_normals(n, np.radians(15.0), torch.Generator().manual_seed(1))
    assert out.dtype == dtype and torch.equal(out[-1], torch.zeros(3, dtype=dtype))  # a zero row stays zero
    angle = torch.rad2deg(torch.acos((out[:-1] * n[:-1]).sum(dim=1).clamp(-1, 1))).double()
    tol = 1e-3 if dtype == torch.float32 else 1e-9
    assert torch.allclose(out[:-1].norm(dim=1).double(), torch.ones(4000, dtype=torch.float64), atol=tol)
    assert angle.max() <= 15.0 + 0.05 and 6.5 < angle.mean() < 8.5  # uniform in [0, 15]: mean 7.5
    assert tilt_normals(n, 0.0) is n


def test_auto_normal_inputs_follow_whether_the_mesh_is_open():
    from neural_bake.fit.texture import reads_normals

    for setting, closed, opened in (("off", 3, 3), ("on", 6, 6), ("auto", 3, 6)):
        config = TextureFitConfig(**GRID, normal_inputs=setting)
        assert make_texture_network(config, open_mesh=False).in_dim == closed
        assert make_texture_network(config, open_mesh=True).in_dim == opened
        assert reads_normals(config, True) == (opened == 6)
    fit = fit_texture(disc_square(2), plane_sdf, steps=2, minutes=None, batch=64, pool=500, normal_inputs="auto",
                      **GRID)
    assert fit.model.normal_inputs  # the disc's square is open
    siren = TextureFitConfig(width=8, depth=1, normal_inputs="auto")  # "auto" leaves a SIREN reading points
    assert not reads_normals(siren, True) and make_texture_network(siren, open_mesh=True).in_dim == 3
