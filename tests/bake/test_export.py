"""GLB export: round trip through trimesh and through the raw glTF accessors; source frame; errors."""

import json
import os

import numpy as np
import pytest
import trimesh

from neural_bake.bake.export import export_glb, export_vertex_ply, read_glb
from neural_bake.errors import MeshError, NeuralBakeError
from neural_bake.io.colour import linear_to_srgb
from neural_bake.mesh.tangents import tangent_frames, vertex_normals, vertex_uv
from neural_bake.mesh.unwrap import unwrap
from neural_bake.types import Frame, Mesh


@pytest.fixture
def asset(rng):
    ico = trimesh.creation.icosphere(subdivisions=1, radius=0.6)
    m = Mesh(vertices=np.asarray(ico.vertices), faces=np.asarray(ico.faces, dtype=np.int64),
             frame=Frame((10.0, -2.0, 3.0), 0.25))
    m = unwrap(m, resolution=64)
    normal_map = rng.uniform(0, 1, size=(16, 24, 3)).astype(np.float32)
    albedo = rng.uniform(0, 1, size=(20, 12, 3)).astype(np.float32)
    return m, tangent_frames(m), normal_map, albedo


def test_round_trip_in_trimesh(tmp_path, asset):
    m, tangents, normal_map, albedo = asset
    path = export_glb(tmp_path / "a.glb", m, normal_map=normal_map, albedo=albedo, tangents=tangents)
    scene = trimesh.load(path, process=False)
    (geom,) = scene.geometry.values()
    # positions in the source frame, same order and faces
    assert np.allclose(geom.vertices, m.frame.to_source(m.vertices), atol=1e-4)
    assert np.array_equal(geom.faces, m.faces)
    assert np.allclose(geom.vertex_normals, vertex_normals(m), atol=1e-6)
    assert np.allclose(geom.visual.uv, vertex_uv(m), atol=1e-6)  # trimesh flips glTF's v back
    mat = geom.visual.material
    base = np.asarray(mat.baseColorTexture.convert("RGB"), dtype=np.float64) / 255
    assert base.shape == (20, 12, 3)
    assert np.abs(base - linear_to_srgb(albedo)).max() <= 0.5 / 255 + 1e-6  # sRGB-encoded 8-bit
    nrm = np.asarray(mat.normalTexture.convert("RGB"), dtype=np.float64) / 255
    assert np.abs(nrm - normal_map).max() <= 0.5 / 255 + 1e-6  # linear data, not sRGB


def test_raw_accessors_hold_tangents_and_glTF_uv(tmp_path, asset):
    m, tangents, normal_map, _ = asset
    path = export_glb(tmp_path / "a.glb", m, normal_map=normal_map, tangents=tangents)
    gltf, arr, images = read_glb(path)
    assert np.allclose(arr["TANGENT"], tangents, atol=1e-6)
    assert set(np.unique(arr["TANGENT"][:, 3])) <= {-1.0, 1.0}
    uv = vertex_uv(m)
    assert np.allclose(arr["TEXCOORD_0"], np.stack([uv[:, 0], 1 - uv[:, 1]], axis=1), atol=1e-6)
    pos = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    assert np.allclose(pos["min"], arr["POSITION"].min(axis=0)) and np.allclose(pos["max"], arr["POSITION"].max(axis=0))
    mat = gltf["materials"][0]
    assert "normalTexture" in mat and "baseColorTexture" not in mat["pbrMetallicRoughness"]
    assert len(images) == 1 and images[0][:8] == b"\x89PNG\r\n\x1a\n"
    # the file is a valid GLB: declared length, 4-byte aligned chunks
    data = path.read_bytes()
    assert int.from_bytes(data[8:12], "little") == len(data) and len(data) % 4 == 0


def test_vertex_colours_and_normals_without_uv(tmp_path):
    ico = trimesh.creation.icosphere(subdivisions=1)
    m = Mesh(vertices=np.asarray(ico.vertices), faces=np.asarray(ico.faces, dtype=np.int64))
    cols = np.abs(m.vertices)
    normals = -m.vertices / np.linalg.norm(m.vertices, axis=1, keepdims=True)
    path = export_glb(tmp_path / "v.glb", m, vertex_colors=cols, normals=normals)
    _, arr, images = read_glb(path)
    assert images == [] and "TEXCOORD_0" not in arr
    assert np.allclose(arr["COLOR_0"], np.clip(cols, 0, 1), atol=1e-6)
    assert np.allclose(arr["NORMAL"], normals, atol=1e-6)
    (geom,) = trimesh.load(path, process=False).geometry.values()
    assert np.allclose(geom.visual.vertex_colors[:, :3] / 255, np.clip(cols, 0, 1), atol=1 / 255)


def test_failed_export_keeps_the_good_file(tmp_path, asset):
    m, tangents, normal_map, _ = asset
    path = export_glb(tmp_path / "a.glb", m, normal_map=normal_map, tangents=tangents)
    good = path.read_bytes()
    bad = normal_map.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(NeuralBakeError, match="normal_map holds NaN"):
        export_glb(path, m, normal_map=bad, tangents=tangents)
    assert path.read_bytes() == good and sorted(p.name for p in tmp_path.iterdir()) == ["a.glb"]


def test_maps_are_encoded_beside_the_glb_where_the_next_run_removes_a_killed_runs_leftover(tmp_path, asset,
                                                                                          monkeypatch):
    """The PNG files OpenImageIO needs for the GLB's textures go in a temporary folder beside the GLB, named as
    one of its atomic temporary files (never in the system's temporary folder): a run killed meanwhile leaves
    it where the next run for the output removes it."""
    import re
    import tempfile

    import neural_bake.io.images as images
    from neural_bake.io.outdir import OutputLock

    m, tangents, normal_map, albedo = asset
    monkeypatch.setenv("TMPDIR", str(tmp_path / "system-tmp"))
    (tmp_path / "system-tmp").mkdir()
    seen, real = [], images.write_image
    monkeypatch.setattr(images, "write_image", lambda p, *a, **k: seen.append(p) or real(p, *a, **k))
    monkeypatch.setattr(tempfile, "tempdir", None)  # re-read TMPDIR
    export_glb(tmp_path / "a.glb", m, normal_map=normal_map, albedo=albedo, tangents=tangents)
    assert len(seen) == 2 and all(p.parent.parent == tmp_path for p in seen)
    assert all(re.fullmatch(r"\.a\.glb\.\d+\.[^.]+\.tmp", p.parent.name) for p in seen), seen
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.glb", "system-tmp"]
    assert list((tmp_path / "system-tmp").iterdir()) == []
    left = tmp_path / seen[0].parent.name.replace(f".{os.getpid()}.", ".4194305.")  # as a killed run leaves it
    left.mkdir()
    (left / "map.png").write_bytes(b"x")
    with OutputLock(tmp_path / "a.glb"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.glb", "system-tmp"]


def test_errors(tmp_path, asset):
    m, tangents, normal_map, albedo = asset
    with pytest.raises(NeuralBakeError, match="normal_map needs tangents"):
        export_glb(tmp_path / "x.glb", m, normal_map=normal_map)
    with pytest.raises(NeuralBakeError, match=r"tangents must have shape \(\d+, 4\)"):
        export_glb(tmp_path / "x.glb", m, normal_map=normal_map, tangents=tangents[:, :3])
    with pytest.raises(NeuralBakeError, match="albedo must be"):
        export_glb(tmp_path / "x.glb", m, albedo=albedo[:, :, 0])
    with pytest.raises(NeuralBakeError, match="vertex_colors must have shape"):
        export_glb(tmp_path / "x.glb", m, vertex_colors=np.zeros((3, 3)))
    no_uv = Mesh(vertices=m.vertices, faces=m.faces)
    with pytest.raises(MeshError, match="texture maps need a mesh with UVs"):
        export_glb(tmp_path / "x.glb", no_uv, albedo=albedo)
    with pytest.raises(NeuralBakeError, match="folder .* does not exist"):
        export_glb(tmp_path / "nope" / "x.glb", m)
    (tmp_path / "t.txt").write_text("hello")
    with pytest.raises(NeuralBakeError, match="not a GLB file"):
        read_glb(tmp_path / "t.txt")
    assert not (tmp_path / "x.glb").exists()
    json.dumps(read_glb(export_glb(tmp_path / "ok.glb", m))[0])  # the JSON chunk is plain JSON


def test_vertex_ply_round_trip(tmp_path):
    ico = trimesh.creation.icosphere(subdivisions=1)
    m = Mesh(vertices=np.asarray(ico.vertices), faces=np.asarray(ico.faces, dtype=np.int64),
             frame=Frame((1.0, 2.0, 3.0), 0.5))
    cols = np.abs(m.vertices)
    normals = -m.vertices / np.linalg.norm(m.vertices, axis=1, keepdims=True)
    path = export_vertex_ply(tmp_path / "v.ply", m, normals=normals, vertex_colors=cols)
    got = trimesh.load(path, process=False)
    assert np.allclose(got.vertices, m.frame.to_source(m.vertices), atol=1e-5)
    assert np.array_equal(got.faces, m.faces)
    srgb = np.round(linear_to_srgb(np.clip(cols, 0, 1)) * 255)
    assert np.array_equal(got.visual.vertex_colors[:, :3], srgb)
    assert np.allclose(got.vertex_normals, normals, atol=1e-5)
    with pytest.raises(NeuralBakeError, match="normals must have shape"):
        export_vertex_ply(tmp_path / "w.ply", m, normals=normals[:3])


def test_png_files_written_beside_are_embedded_as_the_same_bytes(tmp_path, asset):
    from neural_bake.io.images import write_image

    m, tangents, normal_map, albedo = asset
    nfile = write_image(tmp_path / "normal.png", normal_map, colour="data", bits=8)
    afile = write_image(tmp_path / "albedo.png", albedo, colour="srgb", bits=8)
    encoded = export_glb(tmp_path / "a.glb", m, normal_map=normal_map, albedo=albedo, tangents=tangents)
    reused = export_glb(tmp_path / "b.glb", m, normal_map=normal_map, albedo=albedo, tangents=tangents,
                        png_files={"normal_map": nfile, "albedo": afile})
    gltf, _, images = read_glb(reused)
    mat = gltf["materials"][0]
    by_slot = {"albedo": images[gltf["textures"][mat["pbrMetallicRoughness"]["baseColorTexture"]["index"]]["source"]],
               "normal_map": images[gltf["textures"][mat["normalTexture"]["index"]]["source"]]}
    assert by_slot["normal_map"] == nfile.read_bytes() and by_slot["albedo"] == afile.read_bytes()
    # the files hold exactly what the GLB encodes itself: both GLBs are the same bytes
    assert reused.read_bytes() == encoded.read_bytes()
