"""Samples: analytic functions are right (finite differences, distances to fine meshes), the bundled files
are what the generator makes and load with ``load_mesh``, errors name the problem."""

import numpy as np
import pytest

import neural_bake as nb
from neural_bake.errors import NeuralBakeError
from neural_bake.fit.sampling import sample_surface, signed_distance
from neural_bake.io.colour import linear_to_srgb
from neural_bake.io.images import read_image
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.samples import (DATA_DIR, SAMPLES, BumpySphere, Jack, Sphere, Torus, generate, get_sample, sample_path,
                                 unit_frame_normals)
from neural_bake.samples.generate import obj_text

LATLONG_AND_TORUS = ["sphere", "bumpy_sphere", "torus", "dots"]
SHARP = ("torus", "dots")  # sharp-edged textures: bilinear lookups blur their edges


def _surface_points(sample, n=500, seed=0, resolution=4000):
    m = sample.mesh(resolution, 64)
    mesh = mesh_from_arrays(m.vertices, m.faces, m.uv, m.texture, normalise=False)
    p = sample_surface(mesh, n, seed=seed).points.astype(np.float64)
    # project onto the smooth surface with the exact normal (a few Newton steps)
    for _ in range(4):
        p = p - sample.sdf(p)[:, None] * sample.normal(p)
    return p


# ------------------------------------------------------------------------------------------- analytic


@pytest.mark.parametrize("name", list(SAMPLES))
def test_normal_is_the_normalised_sdf_gradient_on_the_surface(name, fd_gradient):
    s = SAMPLES[name]
    p = _surface_points(s, resolution=2000)
    assert np.abs(s.sdf(p)).max() < 1e-9
    n = s.normal(p)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    g = fd_gradient(s.sdf, p)
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    cos = (g * n).sum(1)
    if name == "jack":  # exact except on the creases where a spike meets the ball (the sdf has a kink)
        assert np.mean(cos > 1 - 1e-6) > 0.98
    else:
        assert cos.min() > 1 - 1e-6


def test_bumpy_normal_matches_the_gradient_of_the_implicit_function(fd_gradient):
    s = BumpySphere()
    rng = np.random.default_rng(0)
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    p = d * s.surface_radius(d)[:, None]
    assert np.abs(s.implicit(p)).max() < 1e-12
    g = fd_gradient(s.implicit, p)
    np.testing.assert_allclose(s.normal(p), g / np.linalg.norm(g, axis=1, keepdims=True), atol=1e-6)
    # the normal is the same all along the ray through a surface point (defined at the radial projection)
    np.testing.assert_allclose(s.normal(p * 1.1), s.normal(p), atol=1e-12)
    # star-shaped, no overhangs: the normal never faces away from the centre
    assert (s.normal(p) * d).sum(1).min() > 0.3
    # first-order sdf: exact sign, accurate near the surface
    for t in (0.98, 1.02):
        q = p * t
        assert np.all(np.sign(s.sdf(q)) == np.sign(t - 1))


def test_sphere_and_torus_sdfs_are_exact():
    sph = Sphere()
    p = np.array([[0.0, 0, 0], [2, 0, 0], [0, 0.3, 0.4]])
    np.testing.assert_allclose(sph.sdf(p), [-0.9, 1.1, -0.4])
    np.testing.assert_array_equal(sph.normal(p[:1]), [[0, 0, 0]])  # the centre: zero, never NaN
    tor = Torus()
    p = np.array([[0.0, 0, 0], [0.65, 0, 0], [0.65, 0, 0.5], [1.0, 0, 0], [0, 0, 2]])
    np.testing.assert_allclose(tor.sdf(p), [0.4, -0.25, 0.25, 0.1, np.hypot(0.65, 2) - 0.25])
    n = tor.normal(p)
    assert np.isfinite(n).all() and np.array_equal(n[1], [0, 0, 0])  # on the core circle: zero
    np.testing.assert_allclose(n[2:4], [[0, 0, 1], [1, 0, 0]])


@pytest.mark.parametrize("name", ["torus", "jack"])
def test_sdf_equals_the_distance_to_a_fine_mesh(name, rng):
    s = SAMPLES[name]
    if name == "jack":  # the bundled mesh (making it takes ~15 s)
        mesh = nb.load_mesh(sample_path(name), normalise=False)
    else:
        m = s.mesh(20000, 32)
        mesh = mesh_from_arrays(m.vertices, m.faces, normalise=False)
    p = rng.uniform(-1.0, 1.0, (1500, 3))
    d_mesh = signed_distance(mesh, p)
    d = s.sdf(p)
    if name == "torus":
        np.testing.assert_allclose(d, d_mesh, atol=2e-3)  # the tessellation gap of the 20k-face torus
    else:  # exact outside; a bound inside (|sdf| <= true distance); marching-cubes mesh within ~half a cell
        out = d > 0.01
        np.testing.assert_allclose(d[out], d_mesh[out], atol=4e-3)
        assert np.all(np.sign(d[np.abs(d) > 0.01]) == np.sign(d_mesh[np.abs(d) > 0.01]))
        inside = d < -0.01
        assert np.all(-d[inside] <= -d_mesh[inside] + 4e-3)


def test_bumps_are_lost_on_a_coarse_mesh_and_held_on_the_fine_one():
    s = BumpySphere()

    def normal_error(resolution):
        m = s.mesh(resolution, 32)
        mesh = mesh_from_arrays(m.vertices, m.faces, normalise=False)
        smp = sample_surface(mesh, 4000, seed=1, normals="vertex")
        cos = np.clip((smp.normals * s.normal(smp.points.astype(np.float64))).sum(1), -1, 1)
        return np.degrees(np.arccos(cos)).mean()

    fine, coarse = normal_error(None), normal_error(2000)
    assert fine < 2.0
    assert coarse > 3 * fine


@pytest.mark.parametrize("name", list(SAMPLES))
def test_meshes_are_closed_outward_and_on_the_surface(name):
    s = SAMPLES[name]
    m = s.mesh(1000 if name != "jack" else 3000, 32)
    assert m.faces.dtype == np.int64 and m.uv.shape == (len(m.faces), 3, 2) and m.texture.dtype == np.float32
    assert m.texture.shape == ((16, 32, 3) if name not in ("jack", "dots") else (32, 32, 3))
    assert np.abs(s.sdf(m.vertices)).max() < 1e-9
    mesh = mesh_from_arrays(m.vertices, m.faces, m.uv, m.texture, normalise=False)
    assert mesh.watertight and not mesh.warnings
    tri = mesh.triangles
    cos = (mesh.face_normals * s.normal(tri.mean(1))).sum(1)
    assert np.mean(cos > 0.5) > 0.99 and cos.min() > -0.5


@pytest.mark.parametrize("name", LATLONG_AND_TORUS)
def test_texture_is_the_albedo_at_the_texels(name):
    s = SAMPLES[name]
    size = 512 if name in SHARP else 64
    m = s.mesh(500, size)
    mesh = mesh_from_arrays(m.vertices, m.faces, m.uv, m.texture, normalise=False)
    smp = sample_surface(mesh, 3000, seed=2)
    err = np.abs(smp.colors - s.albedo_uv(smp.uv, size)).max(1)
    if name == "dots":  # exact but within a texel and a half of a disc's edge (bilinear lookups)
        x, y = smp.uv[:, 0] * s.texture_size, (1.0 - smp.uv[:, 1]) * s.texture_size
        cell = np.floor(np.stack([x, y], 1) / s.spacing)
        r = np.hypot(*(np.stack([x, y], 1) - (cell + 0.5) * s.spacing).T)
        diameter = np.asarray(s.dot_texels)[cell[:, 1].astype(int) % len(s.dot_texels)]
        near_edge = np.abs(r - diameter / 2) * size / s.texture_size < 1.5
        assert err[~near_edge].max() < 1e-6 and near_edge.mean() < 0.5
    elif name in SHARP:  # sharp edges: bilinear blur within one texel of an edge only
        assert np.mean(err < 1e-6) > 0.9
    else:
        assert err.max() < 0.01


def test_torus_uv_of_matches_the_mesh_uv():
    s = Torus()
    m = s.mesh(8000, 64)
    mesh = mesh_from_arrays(m.vertices, m.faces, m.uv, m.texture, normalise=False)
    smp = sample_surface(mesh, 2000, seed=3)
    uv = s.uv_of(smp.points.astype(np.float64))
    ok = (smp.uv.min(1) > 0.01) & (smp.uv.max(1) < 0.99)  # away from the seams (0 ≡ 1)
    np.testing.assert_allclose(uv[ok], smp.uv[ok], atol=0.01)


# ------------------------------------------------------------------------------------------- files


@pytest.mark.parametrize("name", LATLONG_AND_TORUS)
def test_bundled_files_are_what_the_generator_makes(name):
    s = SAMPLES[name]
    m = s.mesh()
    path = sample_path(name)
    assert path.read_text() == obj_text(m, f"{name}.mtl")
    png = read_image(path.with_suffix(".png"), colour="data")
    expect = np.round(np.clip(linear_to_srgb(m.texture), 0, 1) * 255) / 255
    np.testing.assert_allclose(png, expect, atol=1e-6)
    assert f"map_Kd {name}.png" in path.with_suffix(".mtl").read_text()


@pytest.mark.parametrize("name", list(SAMPLES))
def test_bundled_files_load_and_match_the_analytic_functions(name):
    s = SAMPLES[name]
    path = sample_path(name)
    assert all((DATA_DIR / f"{name}.{e}").stat().st_size < 1_000_000 for e in ("obj", "mtl", "png"))
    mesh = nb.load_mesh(path)
    assert mesh.watertight and mesh.texture is not None and mesh.uv is not None and not mesh.warnings
    src = mesh.frame.to_source(mesh.vertices)
    assert np.abs(s.sdf(src)).max() < 2e-6  # 6 decimals in the file
    smp = sample_surface(mesh, 3000, seed=4)
    err = np.abs(smp.colors - s.albedo(mesh.frame.to_source(smp.points))).max(1)
    if name in SHARP:
        assert np.mean(err < 0.01) > 0.9
    else:  # 8-bit sRGB quantisation + bilinear + tessellation
        assert np.quantile(err, 0.99) < 0.01 and err.max() < 0.05


def test_generate_writes_atomically_named_files(tmp_path):
    out = generate(tmp_path / "a", ["sphere"], resolution=64, texture_size=16)
    assert out == {"sphere": tmp_path / "a" / "sphere.obj"}
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["sphere.mtl", "sphere.obj", "sphere.png"]


def test_errors(tmp_path):
    with pytest.raises(NeuralBakeError, match=r"unknown sample 'cube' \(known: sphere, bumpy_sphere, torus, jack, dots\)"):
        get_sample("cube")
    with pytest.raises(NeuralBakeError, match="unknown sample 'cube'"):
        sample_path("cube")
    f = tmp_path / "f"
    f.write_text("")
    with pytest.raises(NeuralBakeError, match="f: not a folder"):
        generate(f, ["sphere"])
    with pytest.raises(NeuralBakeError, match="resolution must be an approximate face count >= 32, got 5"):
        generate(tmp_path, ["sphere"], resolution=5)
    with pytest.raises(NeuralBakeError, match="texture size must be at least 8 texels"):
        generate(tmp_path, ["sphere"], texture_size=4)
    with pytest.raises(ValueError, match=r"resolution must be an approximate face count >= 32, got 10"):
        Sphere().mesh(10)
    with pytest.raises(ValueError, match=r"points must be \(N, 3\), got shape \(3,\)"):
        Jack().sdf(np.zeros(3))


@pytest.mark.slow
def test_bundled_jack_is_what_the_generator_makes():
    # marching cubes + xatlas (~15 s): deterministic, so the committed file is reproducible
    assert sample_path("jack").read_text() == obj_text(SAMPLES["jack"].mesh(), "jack.mtl")


def test_unit_frame_normals_of_the_bundled_sphere_point_away_from_its_centre():
    mesh = nb.load_mesh(sample_path("sphere"))
    normals = unit_frame_normals(get_sample("sphere"), mesh.frame)
    centre = mesh.frame.to_unit(np.zeros((1, 3)))  # the source sphere is centred on the origin
    radial = mesh.vertices - centre
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    got = normals(mesh.vertices)
    assert got.shape == mesh.vertices.shape
    np.testing.assert_allclose(got, radial, atol=1e-9)
