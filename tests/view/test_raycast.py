"""The mesh renderer: normal-map decoding against hand-made frames and the baker's own decode, silhouettes
and depths against a ray-sphere oracle, and the analytic bumpy-sphere bake against its analytic render."""

import imageio.v3 as iio
import numpy as np
import pytest
import trimesh

from neural_bake.constants import BAKED_RENDER_MIN_PSNR_DB
from neural_bake.render.camera import Camera
from neural_bake.render.shading import Material
from neural_bake.view import (
    ViewError,
    ViewMesh,
    difference_image,
    image_metrics,
    load_view_mesh,
    render_mesh,
    render_turntable,
    shading_normals,
    to_srgb8,
    turntable_cameras,
    view_camera,
    view_mesh_from_glb,
    view_mesh_from_mesh,
    write_gif,
)
from neural_bake.view.analytic import analytic_render_asset
from neural_bake.view.compare import silhouette_iou
from neural_bake.view.neural import neural_renderer


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


def quad(normal_map=None, w=1.0):
    """A unit square in z = 0 facing +Z; u along +X, v along +Y; tangent +X with handedness ``w``."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    uv = v[:, :2][f]
    n = np.tile([0.0, 0.0, 1.0], (4, 1))
    t = np.tile([1.0, 0.0, 0.0, w], (4, 1))
    return ViewMesh(v, f, uv=uv, vertex_normals=n, tangents=t, normal_map=normal_map, source="quad")


@pytest.mark.parametrize("w", [1.0, -1.0])
def test_normal_map_decodes_with_tbn_and_green_up(w):
    vec = np.array([0.3, 0.5, 0.81])
    vec /= np.linalg.norm(vec)
    nmap = np.broadcast_to(((vec + 1) / 2).astype(np.float32), (4, 4, 3)).copy()
    m = quad(nmap, w)
    face = np.array([0, 1, 0])
    bary = np.array([[0.2, 0.3, 0.5], [0.6, 0.2, 0.2], [1 / 3, 1 / 3, 1 / 3]])
    got = shading_normals(m, face, bary)
    # T = +X, B = w·cross(N, T) = w·(+Y), N = +Z: green (y) goes along +Y for w = +1
    want = np.array([vec[0], w * vec[1], vec[2]])
    assert np.allclose(got, want, atol=2e-6)
    assert np.allclose(shading_normals(m, face, bary, use_normal_map=False), [0, 0, 1])
    # the flat map (0.5, 0.5, 1) keeps the geometric normal
    flat = quad(np.broadcast_to(np.float32([0.5, 0.5, 1.0]), (4, 4, 3)).copy(), w)
    assert np.allclose(shading_normals(flat, face, bary), [0, 0, 1], atol=1e-7)


def test_zero_texel_keeps_the_interpolated_normal():
    m = quad(np.full((2, 2, 3), 0.5, dtype=np.float32))  # decodes to the zero vector
    out = shading_normals(m, np.array([0]), np.array([[0.2, 0.3, 0.5]]))
    assert np.isfinite(out).all() and np.allclose(out, [[0, 0, 1]])


def test_glb_normals_match_the_bakers_own_decode(bumpy_bake):
    """At texel centres the renderer's decode of the exported GLB equals the baked normals (8-bit map)."""
    vm = view_mesh_from_glb(bumpy_bake.glb)
    tx = bumpy_bake.baker.texels
    inner = ~tx.border
    got = shading_normals(vm, tx.face[inner], tx.bary[inner])
    err = angle_deg(got, bumpy_bake.result.normals[inner])
    assert np.median(err) < 0.3 and np.percentile(err, 99) < 1.0
    # the exported geometry is the baker's mesh, in the source frame
    frame = bumpy_bake.baker.mesh.frame
    assert np.allclose(vm.positions, frame.to_source(bumpy_bake.baker.mesh.vertices), atol=1e-5)


def test_sphere_silhouette_and_depth_match_ray_sphere_oracle():
    r = 0.7
    ico = trimesh.creation.icosphere(subdivisions=5, radius=r)
    m = ViewMesh(np.asarray(ico.vertices), np.asarray(ico.faces), vertex_normals=np.asarray(ico.vertex_normals))
    cam = Camera(position=(0.3, 0.2, 3.0), look_at=(0, 0, 0), width=96, height=80)
    out = render_mesh(m, cam, background=(0.0, 0.0, 1.0))
    d = cam.pixel_directions().reshape(-1, 3)
    o = np.asarray(cam.position)
    b = d @ o
    disc = b * b - (o @ o - r * r)
    truth = (disc > 0).reshape(80, 96)
    t_true = (-b - np.sqrt(np.clip(disc, 0, None))).reshape(80, 96)
    assert silhouette_iou(out.mask, truth) > 0.97
    both = out.mask & truth
    # faceting: the flat faces lie inside the sphere by at most r·(1 − cos(edge angle / 2))
    assert np.abs(out.depth[both] - t_true[both]).max() < 0.01 * r / 0.7 * 2
    assert np.allclose(out.rgb[~out.mask], (0, 0, 1))
    # the shading normal is the sphere's: the hit point's direction, within the vertex-normal interpolation
    pts = o + d.reshape(80, 96, 3)[both] * out.depth[both][:, None]
    assert np.median(angle_deg(out.normals[both].astype(np.float64), pts / np.linalg.norm(pts, axis=1)[:, None])) < 0.5


def test_bumpy_sphere_bake_renders_like_the_analytic_surface(bumpy_bake, tmp_path):
    """The stated error: interior PSNR ≥ BAKED_RENDER_MIN_PSNR_DB against the analytic render; a map with its
    green channel flipped and the coarse mesh without maps stay below it."""
    sample = bumpy_bake.sample
    src = view_mesh_from_mesh(bumpy_bake.fine, "source")
    baked = view_mesh_from_glb(bumpy_bake.glb)
    cam = view_camera(src, width=160, height=160)
    ref = render_mesh(src, cam, normals_fn=sample.normal, albedo_fn=sample.albedo)
    good = render_mesh(baked, cam)
    flipped_map = baked.normal_map.copy()
    flipped_map[..., 1] = 1.0 - flipped_map[..., 1]
    flipped = render_mesh(baked.with_normal_map(flipped_map), cam)
    bare = render_mesh(baked.without_maps(), cam)

    def interior(r):
        return image_metrics(ref.rgb, r.rgb, ref.mask, r.mask, region="interior")["psnr_db"]

    assert interior(good) >= BAKED_RENDER_MIN_PSNR_DB
    assert interior(flipped) < BAKED_RENDER_MIN_PSNR_DB - 3
    assert interior(bare) < BAKED_RENDER_MIN_PSNR_DB - 20
    # the union of the masks counts the coarse outline: lower, but the bake still beats the flipped map
    union = {k: image_metrics(ref.rgb, r.rgb, ref.mask, r.mask)["mse"] for k, r in
             (("good", good), ("flipped", flipped))}
    assert union["good"] < union["flipped"]
    assert silhouette_iou(ref.mask, good.mask) > 0.97
    diff = difference_image(ref.rgb, flipped.rgb)
    assert diff.shape == (160, 160, 3) and diff[~ref.mask & ~flipped.mask].max() == 0 and diff.max() > 0.2


def test_bake_render_matches_the_neural_preview_of_its_fields(bumpy_bake):
    """The check: the neural preview (sphere tracing, GEMM-free analytic normals and colours of the
    same fields the bake holds) and the render of the baked GLB agree within BAKED_RENDER_MIN_PSNR_DB; the
    flipped green channel and the bare coarse mesh do not."""
    preview = neural_renderer(analytic_render_asset(bumpy_bake))
    baked = view_mesh_from_glb(bumpy_bake.glb)
    cam = view_camera(baked, width=96, height=96)
    ref = preview(cam)
    assert ref.mask.mean() > 0.3 and np.isfinite(ref.rgb).all()
    flipped_map = baked.normal_map.copy()
    flipped_map[..., 1] = 1.0 - flipped_map[..., 1]

    def interior(mesh):
        r = render_mesh(mesh, cam)
        return image_metrics(ref.rgb, r.rgb, ref.mask, r.mask, region="interior")["psnr_db"]

    assert interior(baked) >= BAKED_RENDER_MIN_PSNR_DB
    assert interior(baked.with_normal_map(flipped_map)) < BAKED_RENDER_MIN_PSNR_DB - 3
    assert interior(baked.without_maps()) < BAKED_RENDER_MIN_PSNR_DB - 20


def test_source_mesh_keeps_its_texture_and_normals(bumpy_bake, tmp_path):
    """A source OBJ through load_view_mesh renders as the in-memory mesh does."""
    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.samples.generate import sample_path

    obj = sample_path("sphere")
    a = load_view_mesh(obj)
    assert a.texture is not None and a.uv is not None and a.normal_map is None
    b = view_mesh_from_mesh(load_mesh(obj))
    cam = view_camera(a, width=48, height=48)
    ra, rb = render_mesh(a, cam), render_mesh(b, cam)
    assert np.array_equal(ra.rgb, rb.rgb)
    # without the texture the material's albedo shows: a grey sphere
    grey = render_mesh(a, cam, use_albedo=False, material=Material(albedo=(0.5, 0.5, 0.5), specular=0.0))
    px = grey.rgb[grey.mask]
    assert np.allclose(px[:, 0], px[:, 1]) and np.allclose(px[:, 1], px[:, 2])


def test_turntable_orbits_and_writes_a_gif(bumpy_bake, tmp_path):
    vm = view_mesh_from_glb(bumpy_bake.glb)
    cam = view_camera(vm, width=40, height=32)
    cams = turntable_cameras(cam, 4)
    centre = np.asarray(cam.look_at)
    dist = [np.linalg.norm(np.asarray(c.position) - centre) for c in cams]
    assert np.allclose(dist, dist[0])
    # half a turn about +Y mirrors x and z about the centre and keeps y
    p0, p2 = np.asarray(cam.position) - centre, np.asarray(cams[2].position) - centre
    assert np.allclose(p2, [-p0[0], p0[1], -p0[2]], atol=1e-9)
    frames = render_turntable(vm, cam, 4)
    assert len(frames) == 4 and np.array_equal(frames[0].rgb, render_mesh(vm, cam).rgb)
    assert not np.array_equal(frames[0].rgb, frames[1].rgb)
    gif = write_gif(tmp_path / "t.gif", [to_srgb8(f.rgb) for f in frames])
    back = iio.imread(gif, index=None)
    assert back.shape[:3] == (4, 32, 40)
    assert np.abs(back[0][..., :3].astype(int) - to_srgb8(frames[0].rgb)).mean() < 6  # GIF palette


def test_errors_are_one_line(tmp_path):
    v = np.zeros((3, 3))
    f = np.array([[0, 1, 2]])
    with pytest.raises(ViewError, match="out of range"):
        ViewMesh(v, np.array([[0, 1, 3]]), vertex_normals=v)
    with pytest.raises(ViewError, match="normals must have shape"):
        ViewMesh(v, f, vertex_normals=np.zeros((2, 3)))
    with pytest.raises(ViewError, match="needs UVs"):
        ViewMesh(v, f, vertex_normals=v, texture=np.zeros((2, 2, 3)))
    with pytest.raises(ViewError, match="needs tangents"):
        ViewMesh(v, f, uv=np.zeros((1, 3, 2)), vertex_normals=v, normal_map=np.zeros((2, 2, 3)))
    with pytest.raises(ViewError, match="no such GLB"):
        view_mesh_from_glb(tmp_path / "missing.glb")
    (tmp_path / "bad.glb").write_bytes(b"not a glb at all, not at all")
    with pytest.raises(Exception, match="not a GLB"):
        view_mesh_from_glb(tmp_path / "bad.glb")
    cam = Camera(width=4, height=4)
    with pytest.raises(ViewError, match="whole number"):
        turntable_cameras(cam, 0)
    with pytest.raises(ViewError, match="one size"):
        image_metrics(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    with pytest.raises(ViewError, match="region"):
        image_metrics(np.zeros((4, 4, 3)), np.zeros((4, 4, 3)), np.ones((4, 4)), None, region="edges")
    with pytest.raises(ViewError, match="at least one frame"):
        write_gif(tmp_path / "e.gif", [])
