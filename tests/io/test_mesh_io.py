"""load_mesh / mesh_from_arrays / save_mesh: formats, round trips, frame, validation errors and warnings."""

import json
import warnings

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from neural_bake.bench.common import data_file
from neural_bake.constants import UNIT_FRAME_EXTENT
from neural_bake.errors import ImageError, MeshError, NeuralBakeError, NeuralBakeWarning
from neural_bake.io.colour import sample_texture, srgb_to_linear
from neural_bake.io.images import read_image, write_image
from neural_bake.io.mesh_io import load_mesh, mesh_from_arrays, save_mesh
from neural_bake.types import Frame

SPOT = data_file("spot")

# four quadrants, 8-bit sRGB levels so that 8-bit files store them exactly; row 0 = top of the image
QUAD_COLOURS = {  # (u, v) centre of the quadrant, v up -> sRGB colour
    (0.25, 0.75): (1.0, 0.0, 0.0),  # top-left: red
    (0.75, 0.75): (0.0, 1.0, 0.0),  # top-right: green
    (0.25, 0.25): (0.0, 0.0, 1.0),  # bottom-left: blue
    (0.75, 0.25): (1.0, 1.0, 128 / 255),  # bottom-right: yellow-ish
}


def quadrant_texture(n=8):
    t = np.zeros((n, n, 3), np.float32)
    h = n // 2
    t[:h, :h] = QUAD_COLOURS[(0.25, 0.75)]
    t[:h, h:] = QUAD_COLOURS[(0.75, 0.75)]
    t[h:, :h] = QUAD_COLOURS[(0.25, 0.25)]
    t[h:, h:] = QUAD_COLOURS[(0.75, 0.25)]
    return srgb_to_linear(t)  # linear, as Mesh.texture holds it


def painted_sphere():
    """An icosphere whose faces each sit in one texture quadrant (UVs per corner around the quadrant centre)."""
    s = trimesh.creation.icosphere(subdivisions=1)
    centres = np.array(list(QUAD_COLOURS))
    which = np.arange(len(s.faces)) % 4
    offsets = np.array([[-0.1, -0.1], [0.1, -0.1], [0.0, 0.1]])
    uv = centres[which][:, None, :] + offsets[None]
    return s.vertices * 3.0 + [1.0, -2.0, 0.5], s.faces, uv, which


def check_painted(mesh, which):
    """The colour at each face's UV centroid is the one painted in its quadrant (linear)."""
    centroid = mesh.uv.mean(axis=1)
    got = sample_texture(mesh.texture, centroid, mesh.uv_policy)
    want = srgb_to_linear(np.array([QUAD_COLOURS[tuple(c)] for c in np.array(list(QUAD_COLOURS))[which]], np.float32))
    np.testing.assert_allclose(got[:, :3], want, atol=2e-3)


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"


def quiet(fn, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NeuralBakeWarning)
        return fn(*a, **k)


# --- in-memory meshes, frame, normals ------------------------------------------------------------------------


def test_sphere_unit_frame_and_normals():
    s = trimesh.creation.icosphere(subdivisions=3)
    src = s.vertices * 2.5 + [10.0, -3.0, 7.0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean closed sphere gives no warning
        m = mesh_from_arrays(src, s.faces)
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int64
    lo, hi = m.vertices.min(0), m.vertices.max(0)
    assert np.isclose((hi - lo).max(), UNIT_FRAME_EXTENT)
    np.testing.assert_allclose((hi + lo) / 2, 0, atol=1e-12)
    # to_source(to_unit(x)) == x, and the stored vertices map back to the input exactly (same order)
    np.testing.assert_allclose(m.frame.to_source(m.vertices), src, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m.frame.to_source(m.frame.to_unit(src)), src, rtol=0, atol=1e-12)
    # analytic oracle: a sphere's normals are its unit positions (tolerance of the polyhedral approximation)
    radial = m.vertices / np.linalg.norm(m.vertices, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", m.vertex_normals, radial).min() > 0.999
    np.testing.assert_allclose(np.linalg.norm(m.vertex_normals, axis=1), 1.0)
    assert m.watertight and not m.degenerate.any() and m.warnings == [] and m.uv is None
    assert m.source == "" and m.name == "<generated mesh>"


def test_normalise_false_keeps_source_frame():
    s = trimesh.creation.box(extents=(2, 4, 6))
    m = mesh_from_arrays(s.vertices, s.faces, normalise=False)
    assert m.frame == Frame()
    np.testing.assert_array_equal(m.vertices, s.vertices)


def test_seam_split_vertices_are_welded():
    box = trimesh.creation.box()
    v = box.vertices[box.faces].reshape(-1, 3)  # 36 vertices, every corner its own
    f = np.arange(36).reshape(-1, 3)
    v[5] += 1e-13  # near-duplicate, within MERGE_DISTANCE
    m = mesh_from_arrays(v, f)
    assert m.n_vertices == 8 and m.n_faces == 12 and m.watertight


def test_unreferenced_vertices_dropped():
    v = np.array([[0, 0, 0], [9, 9, 9], [1, 0, 0], [0, 1, 0.0]])
    m = quiet(mesh_from_arrays, v, [[0, 2, 3]], normalise=False)
    np.testing.assert_array_equal(m.vertices, v[[0, 2, 3]])
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])


def test_quads_are_fan_triangulated_with_uvs():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    uv = np.array([[[0, 0], [1, 0], [1, 1], [0, 1.0]]])
    m = quiet(mesh_from_arrays, v, [[0, 1, 2, 3]], uv=uv, normalise=False)
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(m.uv, [[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]])
    np.testing.assert_allclose(m.vertex_normals, [[0, 0, 1]] * 4)


def test_per_vertex_uv_and_uint8_texture():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    tex8 = np.full((2, 2, 3), 128, np.uint8)
    m = quiet(mesh_from_arrays, v, [[0, 1, 2]], uv=v[:, :2], texture=tex8)
    np.testing.assert_array_equal(m.uv[0], v[:, :2])
    assert m.texture.dtype == np.float32
    np.testing.assert_allclose(m.texture, srgb_to_linear(np.float32(128 / 255)), rtol=1e-6)


def test_grey_alpha_texture_becomes_rgba(tmp_path):
    v, f, uv, _ = painted_sphere()
    ga = np.zeros((2, 2, 2), np.float32)
    ga[..., 1] = 0.5
    m = mesh_from_arrays(v, f, uv=uv, texture=ga)
    assert m.texture.shape == (2, 2, 4)
    np.testing.assert_array_equal(m.texture[..., 3], 0.5)


def test_texture_path_for_arrays(tmp_path):
    v, f, uv, which = painted_sphere()
    write_image(tmp_path / "t.png", quadrant_texture())
    m = mesh_from_arrays(v, f, uv=uv, texture=tmp_path / "t.png", source="painted")
    check_painted(m, which)
    assert m.source == "painted"


# --- round trips ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("ext", [".obj", ".ply", ".glb"])
def test_round_trip_textured(tmp_path, ext):
    v, f, uv, which = painted_sphere()
    m = mesh_from_arrays(v, f, uv=uv, texture=quadrant_texture(), source="painted")
    check_painted(m, which)
    out = save_mesh(m, tmp_path / f"m{ext}")
    assert out == tmp_path / f"m{ext}"
    m2 = load_mesh(out)
    assert m2.n_vertices == m.n_vertices and m2.n_faces == m.n_faces
    np.testing.assert_array_equal(m2.faces, m.faces)
    tol = 1e-6 if ext == ".glb" else 1e-12  # GLB stores float32 positions
    np.testing.assert_allclose(m2.frame.to_source(m2.vertices), v, rtol=0, atol=tol * 10)
    np.testing.assert_allclose(m2.uv, m.uv, atol=1e-7)
    np.testing.assert_allclose(m2.texture, m.texture, atol=1e-6)  # 8-bit levels survive exactly
    check_painted(m2, which)  # texel lookup at each face's UV gives the painted colour
    assert m2.watertight and m2.warnings == []
    assert not [q.name for q in tmp_path.iterdir() if q.name.startswith(".")]  # no temporaries


def test_obj_files_written(tmp_path):
    v, f, uv, _ = painted_sphere()
    m = mesh_from_arrays(v, f, uv=uv, texture=quadrant_texture())
    save_mesh(m, tmp_path / "a.obj")
    assert sorted(q.name for q in tmp_path.iterdir()) == ["a.mtl", "a.obj", "a_basecolor.png"]
    assert "map_Kd a_basecolor.png" in (tmp_path / "a.mtl").read_text()
    np.testing.assert_allclose(read_image(tmp_path / "a_basecolor.png"), m.texture, atol=1e-6)


@pytest.mark.parametrize("ext", [".obj", ".ply", ".glb"])
def test_round_trip_plain_and_unit_frame(tmp_path, ext):
    s = trimesh.creation.icosphere(subdivisions=2)
    src = s.vertices * 0.01 + 5.0
    m = mesh_from_arrays(src, s.faces)
    m2 = load_mesh(save_mesh(m, tmp_path / f"a{ext}"))
    assert m2.uv is None and m2.texture is None
    tol = 1e-7 if ext == ".glb" else 1e-14
    np.testing.assert_allclose(m2.frame.to_source(m2.vertices), src, atol=tol * 10)
    np.testing.assert_allclose(m2.vertices, m.vertices, atol=1e-4 if ext == ".glb" else 1e-12)
    m3 = load_mesh(save_mesh(m, tmp_path / f"u{ext}", frame="unit"), normalise=False)
    np.testing.assert_allclose(m3.vertices, m.vertices, atol=1e-6)


def test_glb_file_follows_gltf_uv_convention(tmp_path):
    """Independent of trimesh's reader: in the GLB, raw TEXCOORD_0 (v down from the image's top row) must
    address the texel painted with the face's colour."""
    import struct

    v, f, uv, which = painted_sphere()
    save_mesh(mesh_from_arrays(v, f, uv=uv, texture=quadrant_texture()), tmp_path / "a.glb")
    data = (tmp_path / "a.glb").read_bytes()
    magic, version, _ = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2
    jlen, _ = struct.unpack_from("<II", data, 12)
    doc = json.loads(data[20 : 20 + jlen])
    blen, _ = struct.unpack_from("<II", data, 20 + jlen)
    binary = data[28 + jlen : 28 + jlen + blen]

    def accessor(i):
        acc = doc["accessors"][i]
        view = doc["bufferViews"][acc["bufferView"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        width = {"VEC2": 2, "VEC3": 3, "SCALAR": 1}[acc["type"]]
        dtype = {5126: np.float32, 5125: np.uint32, 5123: np.uint16}[acc["componentType"]]
        return np.frombuffer(binary, dtype, acc["count"] * width, start).reshape(acc["count"], width)

    prim = doc["meshes"][0]["primitives"][0]
    tc = accessor(prim["attributes"]["TEXCOORD_0"])
    idx = accessor(prim["indices"]).reshape(-1, 3)
    img_view = doc["bufferViews"][doc["images"][0]["bufferView"]]
    (tmp_path / "raw.png").write_bytes(binary[img_view.get("byteOffset", 0) : img_view.get("byteOffset", 0) + img_view["byteLength"]])
    img = read_image(tmp_path / "raw.png", colour="data")  # sRGB levels as stored
    h, w, _ = img.shape
    centroid = tc[idx].mean(axis=1)  # raw glTF uv: (0, 0) = top-left of the image
    texel = img[(centroid[:, 1] * h).astype(int), (centroid[:, 0] * w).astype(int)]
    want = np.array([QUAD_COLOURS[tuple(c)] for c in np.array(list(QUAD_COLOURS))[which]])
    np.testing.assert_allclose(texel, want, atol=1 / 255)


def test_gltf_external_texture(tmp_path):
    v, f, uv, which = painted_sphere()
    m = mesh_from_arrays(v, f, uv=uv, texture=quadrant_texture())
    save_mesh(m, tmp_path / "a.glb")
    scene = trimesh.load(tmp_path / "a.glb", process=False)
    files = scene.export(file_type="gltf")
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    m2 = load_mesh(tmp_path / "model.gltf")
    check_painted(m2, which)
    assert m2.n_vertices == m.n_vertices and m2.watertight


def test_gltf_missing_external_image(tmp_path):
    v, f, uv, _ = painted_sphere()
    save_mesh(mesh_from_arrays(v, f, uv=uv, texture=quadrant_texture()), tmp_path / "a.glb")
    files = trimesh.load(tmp_path / "a.glb", process=False).export(file_type="gltf")
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    doc = json.loads((tmp_path / "model.gltf").read_text())
    doc["images"] = [{"uri": "gone%20away.png"}]
    (tmp_path / "model.gltf").write_text(json.dumps(doc))
    with pytest.warns(NeuralBakeWarning, match=r"model\.gltf: texture gone%20away\.png named by the file not found"):
        m = load_mesh(tmp_path / "model.gltf")
    assert m.texture is None and m.uv is not None


def test_glb_base_colour_factor_multiplies_texture(tmp_path):
    from PIL import Image

    s = trimesh.creation.icosphere(subdivisions=1)
    img = Image.new("RGBA", (2, 2), (255, 255, 255, 255))
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=img, baseColorFactor=[0.5, 1.0, 0.25, 0.5])
    s.visual = trimesh.visual.TextureVisuals(uv=np.full((len(s.vertices), 2), 0.5), material=mat)
    s.export(tmp_path / "f.glb")
    m = load_mesh(tmp_path / "f.glb")
    np.testing.assert_allclose(m.texture[0, 0], [128 / 255, 1.0, 64 / 255, 128 / 255], atol=1e-6)


def test_multi_geometry_scene_is_concatenated(tmp_path):
    a = trimesh.creation.box()
    b = trimesh.creation.icosphere(subdivisions=1)
    b.apply_translation([5, 0, 0])
    trimesh.Scene([a, b]).export(tmp_path / "two.glb")
    m = load_mesh(tmp_path / "two.glb", normalise=False)
    assert m.n_faces == len(a.faces) + len(b.faces)
    assert m.n_vertices == len(a.vertices) + len(b.vertices)
    assert m.vertices[:, 0].max() == pytest.approx(6.0) and m.watertight


def test_obj_quads_negative_indices_and_comments(tmp_path):
    corners = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
    quads = [(1, 4, 3, 2), (5, 6, 7, 8), (1, 2, 6, 5), (4, 8, 7, 3), (1, 5, 8, 4), (2, 3, 7, 6)]  # outward
    lines = ["# a unit cube of quads", "o box", "s off", "g g1"] + [f"v {x} {y} {z}" for x, y, z in corners]
    lines += ["f " + " ".join(str(k - 9) for k in q) + "  # quad, negative indices" for q in quads]
    p = write(tmp_path, "box.obj", "\n".join(lines) + "\n")
    m = load_mesh(p, normalise=False)
    assert m.n_faces == 12 and m.watertight and m.warnings == []
    assert trimesh.Trimesh(m.vertices, m.faces).volume == pytest.approx(1.0)
    assert np.einsum("ij,ij->i", m.face_normals, m.triangles.mean(1) - 0.5).min() > 0  # outward


def test_obj_bom_tabs_crlf_and_continuation(tmp_path):
    text = "\ufeffv\t0 0 0\r\nv 1 0 0\r\nv 0\t1 0\r\nf 1 \\\r\n 2 3\r\n"
    (tmp_path / "m.obj").write_bytes(text.encode("utf-8"))
    m = quiet(load_mesh, tmp_path / "m.obj", normalise=False)
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])


@pytest.mark.parametrize("face,has_uv", [("f 1 2 3", False), ("f 1//1 2//1 3//1", False),
                                         ("f 1/2/1 2/1/1 3/3/1", True), ("f 1/2 2/1 3/3", True)])
def test_obj_face_formats(tmp_path, face, has_uv):
    p = write(tmp_path, "m.obj", TRI + "vt 0.1 0.2\nvt 0.3 0.4\nvt 0.5 0.6\nvn 0 0 1\n" + face + "\n")
    m = quiet(load_mesh, p)
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])
    assert (m.uv is not None) == has_uv
    if has_uv:
        np.testing.assert_array_equal(m.uv[0], [[0.3, 0.4], [0.1, 0.2], [0.5, 0.6]])


SIMPLE_OBJS = {
    "plain": TRI + "v 1 1 0\nf 1 2 3\nf 2 4 3\n",
    "comments, groups, normals": "####\n# c # d\no a\ng b\ns 1\n" + TRI + "vn 0 0 1\nf 1//1 2//1 3//1\n",
    "uv": TRI + "vt 0.1 0.2\nvt 0.3 0.4\nvt 0.5 0.6\nf 1/2 2/1 3/3\n",
    "uv and normals, crlf": (TRI + "vt 0.1 0.2\nvt 0.3 0.4\nvt 0.5 0.6\nvn 0 0 1\nf 1/2/1 2/1/1 3/3/1\n")
    .replace("\n", "\r\n"),
    "material": "mtllib m.mtl\nusemtl a\n" + TRI + "vt 0.75 0.25\nf 1/1 2/1 3/1\n",
    # not plain: the line parser reads these
    "quad": TRI + "v 1 1 0\nf 1 2 4 3\n",
    "negative": TRI + "f -3 -2 -1\n",
    "inline comment": TRI + "f 1 2 3 # c\n",
    "mixed corners": TRI + "vt 0 0\nf 1/1 2 3\n",
    "vertex colours": "v 0 0 0 1 0 0\nv 1 0 0 1 0 0\nv 0 1 0 1 0 0\nf 1 2 3\n",
    "tabs": "v\t0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "two materials": "usemtl a\n" + TRI + "f 1 2 3\nusemtl b\nf 1 3 2\n",
}


@pytest.mark.parametrize("name", list(SIMPLE_OBJS))
def test_plain_obj_reader_agrees_with_the_line_parser(tmp_path, name):
    from neural_bake.io.mesh_io import _read_obj, _read_simple_obj

    text = SIMPLE_OBJS[name]
    write(tmp_path, "m.mtl", "newmtl a\nmap_Kd t.png\n")
    write_image(tmp_path / "t.png", quadrant_texture())
    p = tmp_path / "m.obj"
    p.write_bytes(text.encode())
    plain = name in ("plain", "comments, groups, normals", "uv", "uv and normals, crlf", "material")
    assert (_read_simple_obj(text.replace("\r\n", "\n")) is not None) == plain
    fast, slow = _read_obj(p, "m.obj", []), _read_obj(p, "m.obj", [], simple=False)
    for a, b in zip(fast[:3], slow[:3]):
        if a is None or b is None:
            assert a is None and b is None
        else:
            np.testing.assert_array_equal(a, b)
    assert fast[4] == slow[4]  # the same texture file


@pytest.mark.parametrize("rel", ["scans/ogre.obj", "bunny/bunny_closed.obj", "spot/spot_triangulated.obj",
                                 "cad/fandisk.obj"])
def test_plain_obj_reader_on_the_data_folder(rel):
    from neural_bake.io.mesh_io import _read_obj, _read_simple_obj

    p = data_file(rel)
    if not p.is_file():
        pytest.skip("shared data absent")
    assert _read_simple_obj(p.read_text()) is not None  # each is plain: no line loop
    fast, slow = _read_obj(p, p.name, []), _read_obj(p, p.name, [], simple=False)
    for a, b in zip(fast[:3], slow[:3]):
        if a is None or b is None:
            assert a is None and b is None
        else:
            np.testing.assert_array_equal(a, b)


def test_obj_texture_convention(tmp_path):
    """Hand-written OBJ: a face whose UVs sit in the top-left quadrant (v up) reads the top-left texels."""
    write_image(tmp_path / "tex.png", quadrant_texture())
    write(tmp_path, "m.mtl", "newmtl mat\nKd 1 1 1\nmap_Kd -s 1 1 1 -o 0 0 tex.png\n")
    p = write(tmp_path, "m.obj", "mtllib m.mtl\nusemtl mat\n" + TRI + "vt 0.2 0.7\nvt 0.3 0.7\nvt 0.25 0.8\nf 1/1 2/2 3/3\n")
    m = quiet(load_mesh, p)
    np.testing.assert_allclose(sample_texture(m.texture, m.uv.mean(axis=1)), srgb_to_linear(np.float32([[1, 0, 0]])))


def test_explicit_texture_overrides(tmp_path):
    write_image(tmp_path / "t.png", quadrant_texture())
    write(tmp_path, "m.mtl", "newmtl a\nmap_Kd gone.png\n")
    p = write(tmp_path, "m.obj", "mtllib m.mtl\nusemtl a\n" + TRI + "vt 0.75 0.25\nf 1/1 2/1 3/1\n")
    m = quiet(load_mesh, p, texture=tmp_path / "t.png")
    assert m.texture.shape == (8, 8, 3)
    assert not [w for w in m.warnings if "gone.png" in w]  # the file's own (missing) texture is not looked at


@pytest.mark.skipif(not (SPOT / "spot_triangulated.obj").exists(), reason="shared data absent")
def test_spot():
    with pytest.warns(NeuralBakeWarning, match=r"12 face corners have UVs outside \[0, 1\].*policy 'clamp'"):
        m = load_mesh(SPOT / "spot_triangulated.obj", SPOT / "spot_texture.png", uv_policy="clamp")
    assert (m.n_vertices, m.n_faces) == (2930, 5856)
    assert m.watertight and m.texture.shape == (1024, 1024, 3) and m.uv.shape == (5856, 3, 2)
    assert m.uv_policy == "clamp" and len(m.warnings) == 1
    assert m.uv[..., 1].max() > 1.0 and m.uv[..., 0].min() == pytest.approx(-0.05224, abs=1e-5)


# --- errors --------------------------------------------------------------------------------------------------


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(MeshError, match=r"nope\.obj: no such file"):
        load_mesh(tmp_path / "nope.obj")
    with pytest.raises(MeshError, match=r"d\.obj: not a file"):
        (tmp_path / "d.obj").mkdir()
        load_mesh(tmp_path / "d.obj")


def test_unknown_format(tmp_path):
    p = write(tmp_path, "m.stl2", "solid")
    with pytest.raises(MeshError, match=r"m\.stl2: unknown mesh format '\.stl2' \(expected one of \.obj, \.ply"):
        load_mesh(p)


@pytest.mark.parametrize(
    "text,match",
    [
        ("", r"empty mesh \(no vertices or faces\)"),
        (TRI, r"empty mesh \(3 vertices but no faces\)"),
        (TRI + "f 1 2\n", r"m\.obj:4: face with 2 vertices \(a face needs at least 3\)"),
        (TRI + "f 1 2 5\n", r"m\.obj:4: face index 5 out of range \(file has 3 vertices\)"),
        (TRI + "f 1 2 0\n", r"m\.obj:4: face index 0 out of range"),
        (TRI + "f -1 -2 -4\n", r"m\.obj:4: face index -?\d+ out of range"),
        (TRI + "vt 0 0\nf 1/1 2/1 3/2\n", r"m\.obj:5: texture coordinate index 2 out of range \(file has 1 texture"),
        ("v 0 0 0\nv 0 0 nan\nv 0 1 0\nf 1 2 3\n", r"m\.obj:2: vertex 2 has a non-finite coordinate \(0\.0, 0\.0, nan\)"),
        ("v 0 0 inf\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"m\.obj:1: vertex 1 has a non-finite coordinate"),
        ("v 0 0 0\nv 1e300 0 0\nv 0 1e300 0\nf 1 2 3\n", r"m\.obj: vertex 1 has a coordinate of magnitude 1e\+300"),
        ("v 0 zero 0\n", r"m\.obj:1: cannot parse vertex 'v 0 zero 0'"),
        ("v 0 0\n", r"m\.obj:1: cannot parse vertex"),
        (TRI + "f 1 2 x\n", r"m\.obj:4: cannot parse face 'f 1 2 x'"),
        (TRI + "vt a b\n", r"m\.obj:4: cannot parse texture coordinate"),
        (TRI + "f 1 1 2\n", r"m\.obj: all 1 faces are degenerate"),
        ("v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\n", r"all 1 faces are degenerate"),
    ],
)
def test_obj_errors(tmp_path, text, match):
    p = write(tmp_path, "m.obj", text)
    with pytest.raises(MeshError, match=match):
        load_mesh(p)


def test_binary_junk_obj(tmp_path):
    (tmp_path / "m.obj").write_bytes(b"\x00\x01\x02garbage")
    with pytest.raises(MeshError, match=r"m\.obj: unreadable OBJ file \(binary data"):
        load_mesh(tmp_path / "m.obj")


@pytest.mark.parametrize("ext", [".ply", ".glb", ".gltf"])
def test_corrupt_binary_formats(tmp_path, ext):
    (tmp_path / f"m{ext}").write_bytes(b"\x00\x01 definitely not a mesh")
    with pytest.raises(MeshError, match=rf"m\{ext}: unreadable {ext[1:].upper()} file \(.+\)"):
        load_mesh(tmp_path / f"m{ext}")


def test_empty_ply(tmp_path):
    p = tmp_path / "e.ply"
    p.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                 "element face 0\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(MeshError, match=r"e\.ply: empty mesh \(no faces\)"):
        load_mesh(p)


def test_ply_index_out_of_range(tmp_path):
    p = tmp_path / "e.ply"
    p.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                 "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    with pytest.raises(MeshError, match=r"e\.ply: face 0: vertex index 7 out of range \(mesh has 3 vertices\)"):
        load_mesh(p)


PLY_HEAD = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n")


def test_ply_quad_is_triangulated(tmp_path):
    p = tmp_path / "q.ply"
    p.write_text(PLY_HEAD + "0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    m = quiet(load_mesh, p)
    assert m.n_faces == 2 and np.isclose(m.face_areas.sum(), 0.5 * 1.8**2 * 2)


def test_truncated_ply(tmp_path):
    p = tmp_path / "t.ply"
    p.write_text(PLY_HEAD + "0 0 0\n1 0 0\n")
    with pytest.raises(MeshError, match=r"t\.ply: unreadable PLY file"):
        load_mesh(p)


def test_texture_for_mesh_without_uvs(tmp_path):
    write_image(tmp_path / "t.png", np.zeros((2, 2, 3)))
    p = write(tmp_path, "m.obj", TRI + "f 1 2 3\n")
    with pytest.raises(MeshError, match=r"m\.obj: texture .*t\.png given but the mesh has no UV coordinates"):
        quiet(load_mesh, p, texture=tmp_path / "t.png")
    v = np.eye(3)
    with pytest.raises(MeshError, match=r"<generated mesh>: texture .*t\.png given but the mesh has no UV"):
        mesh_from_arrays(v, [[0, 1, 2]], texture=tmp_path / "t.png")
    with pytest.raises(MeshError, match=r"cow: a texture was given but the mesh has no UV coordinates"):
        mesh_from_arrays(v, [[0, 1, 2]], texture=np.zeros((2, 2, 3)), source="cow")


def test_unreadable_texture_is_image_error(tmp_path):
    (tmp_path / "t.png").write_bytes(b"not a png")
    p = write(tmp_path, "m.obj", TRI + "vt 0 0\nf 1/1 2/1 3/1\n")
    with pytest.raises(ImageError, match=r"t\.png: unreadable image"):
        quiet(load_mesh, p, texture=tmp_path / "t.png")
    write(tmp_path, "m.mtl", "newmtl a\nmap_Kd t.png\n")
    p = write(tmp_path, "n.obj", "mtllib m.mtl\nusemtl a\n" + TRI + "vt 0 0\nf 1/1 2/1 3/1\n")
    with pytest.raises(ImageError, match=r"t\.png: unreadable image"):
        quiet(load_mesh, p)


@pytest.mark.parametrize(
    "vertices,faces,kw,match",
    [
        (np.zeros((3, 2)), [[0, 1, 2]], {}, r"vertices must be a numeric \(V, 3\) array, got shape \(3, 2\)"),
        (np.eye(3), np.zeros((0, 3), int), {}, r"empty mesh \(no faces\)"),
        (np.eye(3), [[0, 1]], {}, r"faces have 2 corners \(a face needs at least 3\)"),
        (np.eye(3), [[0, 1, 3]], {}, r"face 0: vertex index 3 out of range \(mesh has 3 vertices\)"),
        (np.eye(3), [[0, -1, 2]], {}, r"face 0: vertex index -1 out of range"),
        (np.eye(3), [[0.5, 1, 2]], {}, r"faces must hold integer vertex indices"),
        (np.eye(3), [[0, 1, 2]], {"uv": np.zeros((2, 2))}, r"uv must be \(F, 3, 2\) per corner or \(V, 2\) per vertex"),
        (np.eye(3), [[0, 1, 2]], {"uv": np.full((1, 3, 2), np.nan)}, r"face 0 has a non-finite texture coordinate"),
        (np.eye(3), [[0, 1, 2]], {"uv": np.zeros((3, 2)), "texture": np.zeros((2, 2, 5))}, r"texture must be a \(H, W, C\)"),
        (np.array([[0, 0, 0], [1, np.nan, 0], [0, 1, 0]]), [[0, 1, 2]], {}, r"vertex 1 has a non-finite coordinate"),
        (np.eye(3) * 1e300, [[0, 1, 2]], {}, r"vertex 0 has a coordinate of magnitude 1e\+300, beyond 1e\+100"),
        (np.eye(3), [[0, 1, 2]], {"uv_policy": "mirror"}, r"uv_policy must be one of \('wrap', 'clamp'\), got 'mirror'"),
    ],
)
def test_array_errors(vertices, faces, kw, match):
    with pytest.raises(NeuralBakeError, match=match):
        quiet(mesh_from_arrays, vertices, faces, source="", **kw)


def test_save_errors(tmp_path):
    m = quiet(mesh_from_arrays, np.eye(3), [[0, 1, 2]])
    with pytest.raises(MeshError, match=r"a\.stl: cannot write mesh format '\.stl'"):
        save_mesh(m, tmp_path / "a.stl")
    with pytest.raises(MeshError, match=r"folder .*nowhere does not exist"):
        save_mesh(m, tmp_path / "nowhere" / "a.obj")
    with pytest.raises(ValueError, match="frame must be 'source' or 'unit'"):
        save_mesh(m, tmp_path / "a.obj", frame="world")
    assert not list(tmp_path.iterdir())


# --- warnings ------------------------------------------------------------------------------------------------


def test_degenerate_faces_flagged_and_kept():
    s = trimesh.creation.icosphere(subdivisions=1)
    f = np.vstack([s.faces, [[0, 0, 1]], [[2, 3, 3]]])  # two zero-area faces, closed mesh otherwise
    with pytest.warns(NeuralBakeWarning, match=r"<generated mesh>: 2 degenerate faces \(area < 1e-12 in the unit frame\)"):
        m = mesh_from_arrays(s.vertices, f)
    assert m.n_faces == len(f) and m.degenerate.sum() == 2 and m.degenerate[-2:].all()
    assert np.isfinite(m.vertex_normals).all() and m.watertight
    assert any("degenerate" in w for w in m.warnings)


def test_open_mesh_warns():
    s = trimesh.creation.icosphere(subdivisions=1)
    with pytest.warns(NeuralBakeWarning, match=r"mesh is not watertight \(3 boundary edges\)"):
        m = mesh_from_arrays(s.vertices, s.faces[1:])
    assert not m.watertight and len(m.warnings) == 1


def test_inconsistent_winding_is_not_watertight():
    s = trimesh.creation.icosphere(subdivisions=1)
    f = s.faces.copy()
    f[0] = f[0, ::-1]
    with pytest.warns(NeuralBakeWarning, match=r"3 edges with inconsistent winding"):
        m = mesh_from_arrays(s.vertices, f)
    assert not m.watertight


def test_inward_winding_is_flipped():
    s = trimesh.creation.icosphere(subdivisions=2)
    uv = np.random.default_rng(0).random((len(s.faces), 3, 2))
    with pytest.warns(NeuralBakeWarning, match=r"faces were wound inward \(negative volume\); flipped all faces"):
        m = mesh_from_arrays(s.vertices, s.faces[:, ::-1], uv=uv)
    np.testing.assert_array_equal(m.faces, s.faces)
    np.testing.assert_array_equal(m.uv, uv[:, ::-1])  # corners follow their vertices
    radial = m.vertices / np.linalg.norm(m.vertices, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", m.vertex_normals, radial).min() > 0.99
    assert np.einsum("ij,ij->i", m.face_normals, m.triangles.mean(1)).min() > 0


def test_uv_outside_range_and_policy():
    v, f, uv, _ = painted_sphere()
    uv = uv.copy()
    uv[0, 0] = [1.25, -0.5]
    with pytest.warns(NeuralBakeWarning, match=r"1 face corners have UVs outside \[0, 1\] \(u in \[.*, 1\.25\], v in \[-0\.5, .*policy 'wrap'"):
        m = mesh_from_arrays(v, f, uv=uv)
    assert m.uv_policy == "wrap"
    m = quiet(mesh_from_arrays, v, f, uv=uv, uv_policy="clamp")
    assert m.uv_policy == "clamp"


def test_missing_texture_named_by_mtl(tmp_path):
    write(tmp_path, "m.mtl", "newmtl a\nKd 1 1 1\nmap_Kd gone.png\n")
    p = write(tmp_path, "m.obj", "mtllib m.mtl\nusemtl a\n" + TRI + "vt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    with pytest.warns(NeuralBakeWarning, match=r"m\.obj: texture gone\.png named by m\.mtl not found; loading without texture"):
        m = load_mesh(p)
    assert m.texture is None and m.uv is not None


def test_two_material_libraries_on_one_line(tmp_path):
    write_image(tmp_path / "t.png", quadrant_texture())
    write(tmp_path, "b.mtl", "newmtl second\nmap_Kd t.png\n")
    p = write(tmp_path, "m.obj", "mtllib a.mtl b.mtl\nusemtl second\n" + TRI + "vt 0.25 0.75\nf 1/1 2/1 3/1\n")
    with pytest.warns(NeuralBakeWarning, match=r"m\.obj: material library a\.mtl not found"):
        m = load_mesh(p)
    assert m.texture.shape == (8, 8, 3)


def test_warnings_point_at_the_caller(tmp_path):
    p = write(tmp_path, "m.obj", "mtllib nothere.mtl\n" + TRI + "f 1 2 3\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_mesh(p)
    assert len(caught) == 2 and all(w.filename == __file__ for w in caught)


def test_missing_mtl(tmp_path):
    p = write(tmp_path, "m.obj", "mtllib nothere.mtl\n" + TRI + "f 1 2 3\n")
    with pytest.warns(NeuralBakeWarning, match=r"m\.obj: material library nothere\.mtl not found"):
        m = load_mesh(p)
    assert m.texture is None


def test_missing_texture_named_by_ply(tmp_path):
    v, f, uv, _ = painted_sphere()
    save_mesh(mesh_from_arrays(v, f, uv=uv, texture=quadrant_texture()), tmp_path / "a.ply")
    (tmp_path / "a_basecolor.png").unlink()
    with pytest.warns(NeuralBakeWarning, match=r"a\.ply: texture a_basecolor\.png named by the file not found"):
        m = load_mesh(tmp_path / "a.ply")
    assert m.texture is None and m.uv is not None


def test_faces_without_uvs_in_a_uv_mesh(tmp_path):
    p = write(tmp_path, "m.obj", TRI + "v 1 1 0\nvt 0.5 0.5\nf 1/1 2/1 3/1\nf 2 4 3\n")
    with pytest.warns(NeuralBakeWarning, match=r"m\.obj: 1 faces have no texture coordinates; they get uv \(0, 0\)"):
        m = load_mesh(p)
    np.testing.assert_array_equal(m.uv[1], 0.0)
    np.testing.assert_array_equal(m.uv[0], 0.5)


def test_named_texture_without_uvs(tmp_path):
    write_image(tmp_path / "t.png", np.zeros((2, 2, 3)))
    write(tmp_path, "m.mtl", "newmtl a\nmap_Kd t.png\n")
    p = write(tmp_path, "m.obj", "mtllib m.mtl\nusemtl a\n" + TRI + "f 1 2 3\n")
    with pytest.warns(NeuralBakeWarning, match=r"m\.obj: the file names a texture but has no UV coordinates; texture ignored"):
        m = load_mesh(p)
    assert m.texture is None


# --- welding against a slow reference ------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 40))
def test_first_of_equal_rows_matches_reference(seed, n):
    from neural_bake.io.mesh_io import _first_of_equal_rows

    rng = np.random.default_rng(seed)
    a = rng.integers(0, 3, (n, 3)).astype(np.float64)  # many repeats
    want = [next(j for j in range(n) if (a[j] == a[i]).all()) for i in range(n)]
    np.testing.assert_array_equal(_first_of_equal_rows(a), want)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 60), scale=st.sampled_from([1e-9, 1e-3, 1.0, 1e4]))
def test_close_pair_check_never_misses_a_pair_within_the_tolerance(seed, n, scale):
    # the grid check against brute force: whenever two distinct points lie within tol it says so; points on a
    # lattice of a few tol, and a pair placed just within tol across a cell border of the first grid
    from neural_bake.io.mesh_io import _may_have_close_pairs

    rng = np.random.default_rng(seed)
    tol = 1e-9 * scale
    pts = rng.integers(0, 6, (n, 3)) * (tol * rng.uniform(0.5, 3.0)) + rng.uniform(-1, 1) * scale
    pts = np.unique(pts, axis=0)
    if len(pts) > 1:
        close = pts.copy()
        close[-1] = close[0] + rng.uniform(-1, 1, 3) * tol / np.sqrt(3) * 0.999
        for p in (pts, np.unique(close, axis=0)):
            d = np.sqrt(((p[:, None] - p[None]) ** 2).sum(-1))
            d[np.arange(len(p)), np.arange(len(p))] = np.inf
            if d.min() <= tol:
                assert _may_have_close_pairs(p, tol)
    far = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3) * 5.0 * tol
    assert not _may_have_close_pairs(far + scale, tol)  # 5 tol apart: no cell of any grid holds two


def test_truncated_glb(tmp_path):
    v, f, uv, _ = painted_sphere()
    save_mesh(mesh_from_arrays(v, f, uv=uv, texture=quadrant_texture()), tmp_path / "a.glb")
    data = (tmp_path / "a.glb").read_bytes()
    (tmp_path / "t.glb").write_bytes(data[: len(data) * 9 // 10])
    with pytest.raises(MeshError, match=r"t\.glb: unreadable GLB file \(.+\)"):
        load_mesh(tmp_path / "t.glb")


def _textured_box(colour, offset):
    from PIL import Image

    b = trimesh.creation.box()
    b.apply_translation([offset, 0, 0])
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.new("RGB", (4, 4), colour))
    b.visual = trimesh.visual.TextureVisuals(uv=np.full((len(b.vertices), 2), 0.5), material=mat)
    return b


def test_geometries_sharing_one_texture_load_without_a_warning(tmp_path):
    # a reader copies the image per geometry: the copies are one texture, not several
    trimesh.Scene([_textured_box((200, 10, 10), 0), _textured_box((200, 10, 10), 3)]).export(tmp_path / "same.glb")
    m = load_mesh(tmp_path / "same.glb")
    assert m.texture is not None and not any("textures" in w for w in m.warnings)


def test_geometries_with_different_textures_warn_that_only_the_first_is_used(tmp_path):
    trimesh.Scene([_textured_box((200, 10, 10), 0), _textured_box((10, 10, 200), 3)]).export(tmp_path / "two.glb")
    with pytest.warns(NeuralBakeWarning, match=r"two\.glb: geometries use 2 different base-colour textures; only the first"):
        m = load_mesh(tmp_path / "two.glb")
    assert m.texture is not None
