"""Baking with analytic oracles: plane, sphere, bumpy sphere; conventions, fallbacks, misses, streaming."""

import json

import numpy as np
import pytest
import torch
import trimesh

from neural_bake.bake.baker import Baker, bake_texels, bake_vertices, keys_below, sample_keys
from neural_bake.bake.export import export_glb, read_glb
from neural_bake.fields import ColorField, SdfField
from neural_bake.bake.maps import colors_to_normals, decode_tangent_space
from neural_bake.errors import NeuralBakeError
from neural_bake.io.images import read_image
from neural_bake.mesh.decimate import decimate
from neural_bake.mesh.unwrap import unwrap
from neural_bake.types import Mesh

R = 0.7


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


def sphere_mesh(subdivisions=2, radius=R, uv=True):
    ico = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    m = Mesh(vertices=np.asarray(ico.vertices, dtype=np.float64), faces=np.asarray(ico.faces, dtype=np.int64))
    return unwrap(m, resolution=256) if uv else m


def sphere_sdf():
    return SdfField(lambda p: p.norm(dim=1) - R)


def unit_normals(p):
    return p / np.linalg.norm(p, axis=1, keepdims=True)


# bumpy sphere: f(p) = |p| - R - A·b(p/|p|), its zero set is p = (R + A·b(u)) u
A, K = 0.04, 8.0


def bump(u):
    s = torch.sin if isinstance(u, torch.Tensor) else np.sin
    return s(K * u[:, 0]) * s(K * u[:, 1]) * s(K * u[:, 2])


def bumpy_sdf():
    return SdfField(lambda p: p.norm(dim=1) - R - A * bump(p / p.norm(dim=1, keepdim=True)))


def bumpy_normals(p):
    _, n, ok = bumpy_sdf().value_and_normal(torch.as_tensor(p))
    assert ok.all()
    return n.numpy()


def bumpy_mesh(faces=800):
    ico = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    u = np.asarray(ico.vertices)
    v = (R + A * bump(u))[:, None] * u
    fine = Mesh(vertices=v, faces=np.asarray(ico.faces, dtype=np.int64))
    return fine, decimate(fine, faces=faces)


def plane_mesh(n=4):
    xs = np.linspace(-0.5, 0.5, n + 1)
    gx, gy = np.meshgrid(xs, xs)
    v = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    f = []
    for i in range(n):
        for j in range(n):
            a = i * (n + 1) + j
            f += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    f = np.array(f, dtype=np.int64)
    uv = (v[:, :2] + 0.5)[f]
    return Mesh(vertices=v, faces=f, uv=uv, vertex_normals=np.tile([0.0, 0.0, 1.0], (len(v), 1)))


def test_plane_bakes_to_flat_tangent_colour():
    baker = Baker(plane_mesh(), 32, padding=None)
    res = baker.bake(SdfField(lambda p: p[:, 2]))
    assert res.coverage.all()
    assert np.allclose(res.normal_map, (0.5, 0.5, 1.0), atol=1e-6)
    assert res.stats["invalid_gradients"] == 0 and res.stats["texels_covered"] == 32 * 32
    # the baker tuned malloc for its arrays (nets.heap) and says what it did
    from neural_bake.nets import heap

    assert res.stats["heap"] == heap.status() != "not called yet"
    from neural_bake.bake import maps, padding
    from neural_bake.mesh import texels

    assert res.stats["kernels"] == {"rasteriser": texels.kernel_status(), "tangent_encoding": maps.kernel_status(),
                                    "padding": padding.kernel_status()}


def test_tilted_field_on_plane_encodes_tangent_coordinates():
    # ∇f = (1, 0, 1)/√2 in object space; the plane's tangent is +x (u), bitangent +y (v): x = 1/√2, z = 1/√2
    baker = Baker(plane_mesh(2), 16, padding=None)
    res = baker.bake(SdfField(lambda p: p[:, 0] + p[:, 2]))
    s = 1 / np.sqrt(2)
    assert np.allclose(res.normal_map, ((s + 1) / 2, 0.5, (s + 1) / 2), atol=1e-6)
    res = Baker(plane_mesh(2), 16, padding=None).bake(SdfField(lambda p: p[:, 1] + p[:, 2]))
    assert np.allclose(res.normal_map, (0.5, (s + 1) / 2, (s + 1) / 2), atol=1e-6)  # +v is green up


def test_directx_flips_green_only():
    mesh = sphere_mesh()
    mesh.vertex_normals = None  # area-weighted normals: the map is not flat
    f = sphere_sdf()
    gl = Baker(mesh, 64).bake(f)
    dx = Baker(mesh, 64, y_convention="directx").bake(f)
    assert np.allclose(dx.normal_map[..., 1], 1.0 - gl.normal_map[..., 1], atol=1e-6)
    assert np.allclose(dx.normal_map[..., [0, 2]], gl.normal_map[..., [0, 2]], atol=1e-6)
    assert np.abs(gl.normal_map[..., 1] - 0.5).max() > 0.01  # the test is not vacuous


def test_object_space_map_is_encoded_normal():
    baker = Baker(sphere_mesh(), 64, normal_space="object", padding=None)
    res = baker.bake(sphere_sdf())
    tx = baker.texels
    got = res.normal_map[tx.pixel[:, 0], tx.pixel[:, 1]]
    # one sample per texel: the texel holds exactly (n + 1) / 2 of its sample (float32 map)
    assert np.allclose(got, (unit_normals(tx.points) + 1) / 2, atol=1e-6)


@pytest.mark.parametrize("supersample", [1, 2])
def test_sphere_normals_within_one_degree(supersample):
    mesh = sphere_mesh(1)  # 80 faces, coarse
    c = torch.tensor([0.05, 0.03, 0.0], dtype=torch.float64)  # the field's sphere is off-centre
    baker = Baker(mesh, 96, supersample=supersample)
    res = baker.bake(SdfField(lambda p: (p - c).norm(dim=1) - R))
    tx = baker.texels
    truth = unit_normals(tx.points - c.numpy())
    assert angle_deg(res.normals, truth).max() < 1e-4
    dec = decode_tangent_space(
        colors_to_normals(res.normal_map[tx.pixel[:, 0], tx.pixel[:, 1]]), tx.tangent, tx.bitangent, tx.normal
    )
    err = angle_deg(dec, truth)
    tol = 1e-3 if supersample == 1 else 1.0  # a supersampled texel averages its samples' normals
    assert err.max() < tol
    # the map is far from flat: the geometric normals are several degrees off
    assert np.median(angle_deg(tx.normal, truth)) > 3.0


def test_bumpy_sphere_decoded_from_exported_glb_matches_gradient(tmp_path):
    fine, coarse = bumpy_mesh(600)
    baker = Baker(coarse, 128)
    assert baker.unwrapped  # decimation dropped UVs: unwrapped automatically
    res = baker.bake(bumpy_sdf())
    path = export_glb(tmp_path / "a.glb", baker.mesh, normal_map=res.normal_map, tangents=baker.tangents)
    gltf, arr, images = read_glb(path)
    (tmp_path / "n.png").write_bytes(images[0])
    nmap = read_image(tmp_path / "n.png", colour="data")  # what the renderer samples (8-bit)
    tx = baker.texels
    # renderer: interpolate the exported NORMAL / TANGENT with the texel's barycentrics
    corners = arr["indices"][tx.face]
    interp = lambda a: np.einsum("mk,mkd->md", tx.bary, a[corners].astype(np.float64))  # noqa: E731
    n = unit_normals(interp(arr["NORMAL"]))
    tan = interp(arr["TANGENT"])
    t = unit_normals(tan[:, :3])
    b = np.where(tan[:, 3:] < 0, -1.0, 1.0) * np.cross(n, t)
    x = colors_to_normals(nmap[tx.pixel[:, 0], tx.pixel[:, 1]])
    dec = decode_tangent_space(x, t, b, n)
    grad = bumpy_normals(tx.points)
    inner = ~tx.border  # texel centres (border texels hold a clamped nearby point)
    err = angle_deg(dec, grad)
    assert np.percentile(err[inner], 99.5) < 1.0 and np.median(err) < 0.5
    # and neural normal mapping matters: the coarse geometry alone is much worse
    assert np.median(angle_deg(tx.normal, grad)) > 3.0


def test_bumpy_sphere_baked_normals_match_analytic_on_fine_surface():
    fine, coarse = bumpy_mesh(400)
    baker = Baker(coarse, 64)
    res = baker.bake(bumpy_sdf())
    pts = baker.texels.points
    # the analytic surface normal at the radial projection onto the fine surface
    u = unit_normals(pts)
    on_surface = (R + A * bump(u))[:, None] * u
    truth = bumpy_normals(on_surface)
    assert np.median(angle_deg(res.normals, truth)) < 2.0


def test_zero_gradient_falls_back_to_geometric_normal():
    baker = Baker(sphere_mesh(), 32)
    res = baker.bake(SdfField(lambda p: p[:, 0] * 0.0))
    assert np.isfinite(res.normal_map).all() and not res.valid.any()
    assert res.stats["invalid_gradients"] == res.stats["samples"] > 0
    assert np.allclose(res.normals, baker.texels.normal)
    tx = baker.texels
    assert np.allclose(res.normal_map[tx.pixel[:, 0], tx.pixel[:, 1]], (0.5, 0.5, 1.0), atol=1e-6)


def test_miss_map_flags_texels_outside_the_band():
    baker = Baker(sphere_mesh(), 32)
    shifted = SdfField(lambda p: p.norm(dim=1) - (R - 0.1), delta=0.05)  # |f| ≈ 0.1 on the mesh
    res = baker.bake(shifted)
    assert np.array_equal(res.miss, res.coverage) and res.stats["miss_texels"] == res.stats["texels_covered"]
    res = baker.bake(shifted, delta=0.2)
    assert not res.miss.any() and res.stats["miss_samples"] == 0
    res = baker.bake(sphere_sdf())
    assert not res.miss.any() and res.stats["delta"] is None


def test_streaming_bake_equals_cached_bake():
    mesh = sphere_mesh()
    f = sphere_sdf()
    tex = ColorField(lambda p: torch.stack([p[:, 0] ** 2, p[:, 1] ** 2, p[:, 2] ** 2], dim=1))
    cached = Baker(mesh, 48).bake(f, tex)
    streamed = Baker(mesh, 48, cache_texels=False).bake(f, tex)
    assert streamed.normals is None and cached.normals is not None
    assert np.allclose(cached.normal_map, streamed.normal_map, atol=1e-6)
    assert np.allclose(cached.albedo, streamed.albedo, atol=1e-6)
    assert np.array_equal(cached.coverage, streamed.coverage)


def test_streaming_in_many_bands_keeps_a_seeded_subsample():
    mesh = sphere_mesh()
    f = sphere_sdf()
    tex = ColorField(lambda p: p.abs())
    baker = Baker(mesh, 48, supersample=2)
    cached = baker.bake(f, tex, delta=1e-3)
    assert cached.sample is None  # every sample kept: no subsample
    streamed = Baker(mesh, 48, supersample=2, cache_texels=False, band_samples=1000).bake(
        f, tex, delta=1e-3, report_samples=700, seed=5)
    assert streamed.normals is None
    assert np.array_equal(cached.normal_map, streamed.normal_map) and np.array_equal(cached.albedo, streamed.albedo)
    assert np.array_equal(cached.coverage, streamed.coverage) and np.array_equal(cached.miss, streamed.miss)
    for key in ("samples", "texels_covered", "miss_samples", "miss_texels", "invalid_gradients"):
        assert cached.stats[key] == streamed.stats[key], key
    smp = streamed.sample
    m = cached.stats["samples"]
    assert smp.total == m and smp.n_samples == 700 and smp.seed == 5
    # the 700 samples with the smallest keys of their global index, in texel order, with their own values
    assert np.array_equal(smp.index, np.sort(np.argsort(sample_keys(np.arange(m), 5))[:700]))
    tx = baker.texels
    for name in ("pixel", "points", "normal", "tangent", "bitangent", "face", "bary", "weight", "texel", "border"):
        assert np.array_equal(getattr(smp.texels, name), getattr(tx, name)[smp.index]), name
    assert np.array_equal(smp.texels.coverage[tx.pixel[smp.index, 0], tx.pixel[smp.index, 1]], np.ones(700, bool))
    assert smp.texels.coverage.sum() <= 700 and smp.texels.size == (48, 48)
    for name in ("normals", "encoded", "values", "colors"):
        assert np.allclose(getattr(smp, name), getattr(cached, name)[smp.index], atol=1e-12), name
    assert np.array_equal(smp.valid, cached.valid[smp.index])
    # the same selection however the layout is banded; fewer samples than the limit: all of them
    one_band = Baker(mesh, 48, supersample=2, cache_texels=False).bake(f, report_samples=700, seed=5).sample
    assert np.array_equal(one_band.index, smp.index)
    everything = Baker(mesh, 48, cache_texels=False, band_samples=500).bake(f, report_samples=10**6).sample
    assert np.array_equal(everything.index, np.arange(everything.total))
    # keep_samples=False on a cached Baker also gives a subsample; report_samples=0 none
    assert baker.bake(f, keep_samples=False, report_samples=50).sample.n_samples == 50
    assert baker.bake(f, keep_samples=False, report_samples=0).sample is None


def test_sample_keys_are_deterministic_and_spread():
    k = sample_keys(np.arange(100_000), 0)
    assert k.dtype == np.uint64 and np.array_equal(k, sample_keys(np.arange(100_000), 0))
    assert len(np.unique(k)) == k.size and not np.array_equal(k, sample_keys(np.arange(100_000), 1))
    # the 10 % smallest keys fall evenly over ten blocks of indices
    counts = np.bincount(np.argsort(k)[:10_000] // 10_000, minlength=10)
    assert np.all(np.abs(counts - 1000) < 4 * np.sqrt(1000 * 0.9))


def test_sample_keys_are_splitmix64_of_index_and_seed():
    # the keys of a few indices against splitmix64 in Python integers; the input array is left alone
    def splitmix(i: int, seed: int) -> int:
        m = 2**64 - 1
        x = (i + seed * 0x9E3779B97F4A7C15 + 0x632BE59BD9B4E019) & m
        x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & m
        x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & m
        return x ^ (x >> 31)

    index = np.array([0, 1, 7, 2**40 + 3, 2**62], dtype=np.uint64)
    for seed in (0, 5):
        keys = sample_keys(index, seed)
        assert [int(k) for k in keys] == [splitmix(int(i), seed) for i in index]
    assert np.array_equal(index, np.array([0, 1, 7, 2**40 + 3, 2**62], dtype=np.uint64))


@pytest.mark.parametrize("fraction", [0.0, 1e-300, 2.0**-10, 256 / 2_400_000, 1 / 3, 0.5, 1 - 1e-12, 1.0, 1.5])
def test_keys_below_is_the_float_comparison(fraction):
    # the integer bound picks exactly the keys whose float64 share is below the fraction, also where float64
    # rounds neighbouring keys together (around 2**54 and next to 2**64)
    edges = np.concatenate([np.array([0, 1, 2**53, 2**63, 2**64 - 1, 2**64 - 1024, 2**64 - 1025], dtype=np.uint64),
                            (2**54 + np.arange(-3000, 3000)).astype(np.uint64)])
    for keys in (sample_keys(np.arange(200_000), 3), edges):
        np.testing.assert_array_equal(keys_below(keys, fraction), keys.astype(np.float64) / 2.0**64 < fraction)


def test_albedo_is_the_colour_field_at_texels():
    baker = Baker(plane_mesh(), 16, padding=None)
    res = baker.bake(SdfField(lambda p: p[:, 2]), ColorField(lambda p: torch.stack([p[:, 0] + 0.5, p[:, 1] + 0.5, 0 * p[:, 0]], 1)))
    tx = baker.texels
    assert res.albedo.shape == (16, 16, 3)
    assert np.allclose(res.albedo[tx.pixel[:, 0], tx.pixel[:, 1], :2], tx.points[:, :2] + 0.5, atol=1e-6)


def radial_colour():
    """A colour field that is not constant along the normal lines: channel 0 is the distance from the centre."""
    return lambda p: torch.stack([p.norm(dim=1), 0.5 + 0.5 * p[:, 0] / p.norm(dim=1), 0 * p[:, 0]], 1)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_texture_is_read_at_the_closest_point_of_the_zero_set(dtype):
    # the coarse surface lies 10 % outside the field's sphere: "surface" reads g on the sphere, "point" at the texel
    mesh = sphere_mesh(radius=1.1 * R)
    sdf = SdfField(lambda p: p.norm(dim=1) - R)
    tex = ColorField(lambda p: radial_colour()(p).to(dtype))
    baker = Baker(mesh, 32, padding=None)
    on = baker.bake(sdf, tex)
    at = baker.bake(sdf, tex, texture_at="point")
    pts = baker.texels.points
    tol = 1e-5 if dtype == torch.float32 else 1e-9
    assert np.allclose(on.colors[:, 0], R, atol=tol)
    assert np.allclose(at.colors[:, 0], np.linalg.norm(pts, axis=1), atol=tol)
    # the direction is kept: the closest point of a sphere lies on the same ray
    assert np.allclose(on.colors[:, 1], at.colors[:, 1], atol=tol)
    assert on.stats["texture_at"] == "surface" and at.stats["texture_at"] == "point"
    assert np.array_equal(on.normal_map, at.normal_map)  # the normals do not depend on where g is read


def test_texture_reach_is_clamped_to_the_colour_fields_band_and_skips_zero_gradients():
    mesh = sphere_mesh(radius=1.1 * R)
    sdf = SdfField(lambda p: p.norm(dim=1) - R)
    res = Baker(mesh, 32, padding=None).bake(sdf, ColorField(radial_colour(), delta=0.01))
    dist = np.linalg.norm(Baker(mesh, 32, padding=None).texels.points, axis=1)
    # a texel farther than δ from the zero set moves by δ only
    assert np.allclose(res.colors[:, 0], dist - np.clip(dist - R, -0.01, 0.01), atol=1e-9)
    flat = Baker(mesh, 32, padding=None).bake(SdfField(lambda p: 0 * p[:, 0] + 0.05), ColorField(radial_colour()))
    assert flat.stats["invalid_gradients"] == len(flat.colors)
    assert np.allclose(flat.colors[:, 0], dist, atol=1e-9)  # no gradient: read where the sample is


def test_bake_vertices_reads_texture_on_the_surface_unless_told():
    mesh = sphere_mesh(radius=1.1 * R, uv=False)
    sdf = SdfField(lambda p: p.norm(dim=1) - R)
    assert np.allclose(bake_vertices(mesh, sdf, ColorField(radial_colour()))["colors"][:, 0], R)
    at = bake_vertices(mesh, sdf, ColorField(radial_colour()), texture_at="point")["colors"][:, 0]
    assert np.allclose(at, np.linalg.norm(mesh.vertices, axis=1))


def sided_colour():
    """A colour field with normal inputs whose colour is the normal it reads: (n + 1) / 2."""
    return ColorField(lambda x: (x[:, 3:] + 1.0) / 2.0, normal_inputs=True, name="sided")


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_colour_field_with_normal_inputs_reads_the_face_normal_at_the_sample_and_grad_f_on_the_surface(dtype):
    mesh = sphere_mesh(radius=1.1 * R)
    sdf = SdfField(lambda p: p.norm(dim=1) - R)
    tex = ColorField(lambda x: ((x[:, 3:] + 1.0) / 2.0).to(dtype), normal_inputs=True)
    baker = Baker(mesh, 32, padding=None)
    on = baker.bake(sdf, tex)
    at = baker.bake(sdf, tex, texture_at="point")
    tx = baker.texels
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    radial = tx.points / np.linalg.norm(tx.points, axis=1, keepdims=True)
    assert np.abs(on.colors - (radial + 1) / 2).max() < tol  # the sphere's ∇f at the sample
    assert np.abs(at.colors - (mesh.face_normals[tx.face] + 1) / 2).max() < tol  # the coarse face's normal
    # an SDF facing the other way (an open mesh's may): the colour of the coarse face's side, not the other's
    inward = baker.bake(SdfField(lambda p: R - p.norm(dim=1)), tex)
    assert np.abs(inward.colors - (mesh.face_normals[tx.face] + 1) / 2).max() < tol
    vertex = bake_vertices(mesh, sdf, tex, texture_at="point")["colors"]
    from neural_bake.geometry import vertex_normals

    assert np.abs(vertex - (vertex_normals(mesh) + 1) / 2).max() < tol


def test_an_adaptive_bake_gives_a_colour_field_with_normal_inputs_the_normal_of_every_evaluation():
    from neural_bake.bake.adaptive import AdaptiveOptions

    baker = Baker(plane_mesh(), 64, padding=None)
    res = baker.bake(SdfField(lambda p: p[:, 2]), sided_colour(), texture_at="point", adaptive=AdaptiveOptions())
    assert res.stats["adaptive"]["interpolated"] > 0 and res.stats["adaptive"]["face_nodes"] > 0  # both passes
    assert np.abs(res.colors - [0.5, 0.5, 1.0]).max() < 1e-12  # the plane's normal, evaluated or interpolated


def test_a_colour_field_with_normal_inputs_needs_normals():
    from neural_bake.bake.baker import _evaluate
    from neural_bake.types import Frame

    with pytest.raises(NeuralBakeError, match=r"^sided: this colour field reads the surface normal at each point; "
                                              r"pass normals of shape \(4, 3\), got none$"):
        sided_colour().color(torch.zeros(4, 3))
    with pytest.raises(NeuralBakeError, match=r"^sided: the colour field reads surface normals, and this bake gave "
                                              r"none"):
        _evaluate(np.zeros((4, 3)), Frame(), None, sided_colour(), 16)
    assert ColorField(radial_colour()).color(torch.ones(2, 3), torch.zeros(2, 3)).shape == (2, 3)  # ignored


def test_bake_texels_wrapper_and_siren_field():
    from neural_bake.nets.siren import Siren

    model = Siren(16, 1, generator=torch.Generator().manual_seed(0))
    res = bake_texels(sphere_mesh(), SdfField.from_model(model), size=32)
    assert res.normal_map.shape == (32, 32, 3) and np.isfinite(res.normal_map).all()
    assert res.normals.dtype == np.float64 and np.allclose(np.linalg.norm(res.normals, axis=1), 1.0)


def test_bake_vertices_sphere():
    mesh = sphere_mesh(uv=False)
    out = bake_vertices(
        mesh, sphere_sdf(), ColorField(lambda p: p.abs()), chunk_size=7
    )
    assert out["valid"].all() and out["invalid"] == 0
    assert angle_deg(out["normals"], unit_normals(mesh.vertices)).max() < 1e-4
    assert np.allclose(out["colors"], np.abs(mesh.vertices))
    assert np.allclose(out["sdf"], 0.0, atol=1e-12)
    out = bake_vertices(mesh, SdfField(lambda p: p[:, 0] * 0))
    assert out["invalid"] == mesh.n_vertices and np.isfinite(out["normals"]).all()


def test_errors():
    mesh = plane_mesh(1)
    with pytest.raises(NeuralBakeError, match="map size must be a positive integer"):
        Baker(mesh, 0)
    with pytest.raises(NeuralBakeError, match="normal_space must be one of"):
        Baker(mesh, 8, normal_space="world")
    with pytest.raises(NeuralBakeError, match="y_convention must be one of"):
        Baker(mesh, 8, y_convention="up")
    with pytest.raises(NeuralBakeError, match="padding must be one of"):
        Baker(mesh, 8, padding="smear")
    with pytest.raises(NeuralBakeError, match="supersample must be a positive integer"):
        Baker(mesh, 8, supersample=0)
    with pytest.raises(NeuralBakeError, match="chunk_size must be a positive integer"):
        Baker(mesh, 8, chunk_size=0)
    with pytest.raises(NeuralBakeError, match="delta must be a positive number"):
        Baker(mesh, 8).bake(SdfField(lambda p: p[:, 2]), delta=-1.0)
    with pytest.raises(NeuralBakeError, match="band_samples must be a positive integer"):
        Baker(mesh, 8, band_samples=0)
    with pytest.raises(NeuralBakeError, match="report_samples must be a non-negative integer"):
        Baker(mesh, 8).bake(SdfField(lambda p: p[:, 2]), report_samples=-1)
    with pytest.raises(NeuralBakeError, match="report_samples must be a non-negative integer"):
        Baker(mesh, 8).bake(SdfField(lambda p: p[:, 2]), report_samples=2.5)
    with pytest.raises(NeuralBakeError, match="seed must be a non-negative integer"):
        Baker(mesh, 8).bake(SdfField(lambda p: p[:, 2]), seed=-3)
    with pytest.raises(NeuralBakeError, match="texture_at must be one of surface, point"):
        Baker(mesh, 8).bake(SdfField(lambda p: p[:, 2]), texture_at="texel")
    with pytest.raises(NeuralBakeError, match="texture_at must be one of surface, point"):
        bake_vertices(mesh, SdfField(lambda p: p[:, 2]), texture_at=None)


def test_non_manifold_coarse_mesh_without_uvs():
    # three triangles sharing one edge (non-manifold), no UVs: unwrapped, baked, finite
    v = np.array([[0, 0, 0], [0, 0, 0.5], [0.5, 0, 0.2], [-0.4, 0.3, 0.2], [0.1, -0.5, 0.2]], dtype=np.float64)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]], dtype=np.int64)
    mesh = Mesh(vertices=v, faces=f, watertight=False)
    baker = Baker(mesh, 32)
    assert baker.unwrapped and baker.mesh.uv is not None
    res = baker.bake(SdfField(lambda p: p.norm(dim=1) - 0.3))
    assert np.isfinite(res.normal_map).all() and res.stats["texels_covered"] > 0
    assert res.stats["singular_frames"] == 0


def two_blob_siren(r2=0.06, s=0.0829):
    """A (4, 0) Siren f = g(a1, x + 0.45) + g(a2, y) + g(a2, z) + s·sin(0.5 x)/0.5 - r2 with g(a, t) =
    2 (1 - cos(a t)) / a² ≈ t²: a closed blob around (-0.45, 0, 0) and, one x-period (1.2) further, a speck
    that holds exactly one negative grid point of the 33³ grid (f(0.6875, 0, 0) ≈ -2.5e-4): 8 faces."""
    import math

    from neural_bake.nets.siren import Siren

    net = Siren(4, 0, omega_0=1.0, hidden_omega=1.0)
    a1, a2 = 2 * math.pi / 1.2, 1.5
    with torch.no_grad():
        w, b = net.layers[0].weight, net.layers[0].bias
        w.zero_()
        b.zero_()
        w[0, 0], b[0] = a1, a1 * 0.45 + math.pi / 2  # sin(a t + π/2) = cos(a t)
        w[1, 1], b[1] = a2, math.pi / 2
        w[2, 2], b[2] = a2, math.pi / 2
        w[3, 0] = 0.5
        w2, b2 = net.layers[1].weight, net.layers[1].bias
        w2.zero_()
        w2[0, :4] = torch.tensor([-2 / a1**2, -2 / a2**2, -2 / a2**2, s / 0.5])
        b2.fill_(2 / a1**2 + 4 / a2**2 - r2)
    return net.double()


def test_coarse_mesh_march_is_cleaned_and_reports_it():
    from neural_bake.mesh.coarse import coarse_mesh
    from neural_bake.mesh.cleanup import clean_mesh
    from neural_bake.mesh.marching import march
    from neural_bake.types import Frame

    net = two_blob_siren()
    raw, _ = march(net, 32)
    frame = Frame((1.0, 2.0, 3.0), 2.0)
    sdf = SdfField.from_model(net, frame=frame)
    out, info = coarse_mesh(sphere_mesh(1, uv=False), "march:32", sdf)
    rep = info["cleanup"]
    # the speck (8 faces, under 1% of the blob's) is dropped; what remains is the blob, closed
    assert rep["components"] == 2 and rep["components_removed"] == 1 and rep["small_component_faces_removed"] == 8
    assert out.n_faces == raw.n_faces - 8 and info["faces"] == out.n_faces == rep["faces_out"]
    assert out.vertices[:, 0].max() < 0 and out.watertight and rep["non_manifold_edges"] == 0
    assert rep["degenerate_faces_removed"] == 0 and out.frame == frame
    expected, _ = clean_mesh(raw)
    np.testing.assert_array_equal(out.faces, expected.faces)
    np.testing.assert_array_equal(out.vertices, expected.vertices)
    assert info["march"]["mode"] == "auto" and info["march"]["faces"] == raw.n_faces
    json.dumps(info)  # reaches report.json as is



def test_a_grid_colour_field_bakes_through_the_grid_kernel_as_through_torch(monkeypatch):
    """A feature-grid colour network bakes the same albedo through the grid's C kernel (where it runs) as through
    torch's encoding, and the bake's stats say which encoding ran."""
    from neural_bake.fields import TextureField
    from neural_bake.nets import grid
    from neural_bake.nets.native import Kernel

    net = grid.GridNet(4, 2, 9, 3, 40, 8, 1, generator=torch.Generator().manual_seed(1)).double()
    with torch.no_grad():
        net.table.normal_(generator=torch.Generator().manual_seed(2))
    tex = TextureField.from_model(net)
    baker = Baker(plane_mesh(), 32, padding=None)
    res = baker.bake(SdfField(lambda p: p[:, 2]), tex)
    assert res.stats["kernels"]["grid_encoding"] == grid.kernel_status()
    monkeypatch.setenv(grid.ENV_SWITCH, "0")
    monkeypatch.setattr(grid, "KERNEL", Kernel(grid.KERNEL.source, switch=grid.ENV_SWITCH, declare=grid._declare))
    off = Baker(plane_mesh(), 32, padding=None).bake(SdfField(lambda p: p[:, 2]), tex)
    assert off.stats["kernels"]["grid_encoding"].startswith("torch (off")
    assert np.abs(res.albedo).max() > 0.05
    np.testing.assert_allclose(res.albedo, off.albedo, rtol=0, atol=1e-6)
