"""An asset's own shading (hard-edge vertex normals) and material maps, read from a generated glTF and kept
by a bake onto the asset itself (`--coarse keep`)."""

import io
import json

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

from neural_bake.bake.export import export_glb, read_glb
from neural_bake.errors import MeshError, NeuralBakeError
from neural_bake.io.asset import read_asset, shading_mesh
from neural_bake.io.mesh_io import load_mesh
from neural_bake.fields import save_model
from neural_bake.nets.siren import Siren

EXTENTS = (1.0, 0.3, 0.6)


def _image(rng, size=8):
    return Image.fromarray((rng.random((size, size, 3)) * 255).astype(np.uint8))


def write_box_glb(path, *, rotate=False):
    """A hard-edged box (every face its own corners, face normals as vertex normals), UVs one triangle per
    grid cell (no overlaps), base colour, normal, metallic-roughness and occlusion maps (8x8 random)."""
    box = trimesh.creation.box(extents=EXTENTS)
    tri = box.triangles.reshape(-1, 3)
    faces = np.arange(len(tri)).reshape(-1, 3)
    normals = np.repeat(box.face_normals, 3, axis=0)
    cell = np.array([[0.05, 0.05], [0.2, 0.05], [0.05, 0.2]])
    uv = np.concatenate([cell + [0.25 * (i % 4), 0.25 * (i // 4)] for i in range(len(faces))])
    rng = np.random.default_rng(1)
    maps = {k: _image(rng) for k in ("base", "normal", "mr", "ao")}
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=maps["base"], normalTexture=maps["normal"],
                                              metallicRoughnessTexture=maps["mr"], occlusionTexture=maps["ao"])
    mesh = trimesh.Trimesh(tri, faces, vertex_normals=normals, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv, material=mat))
    if rotate:  # a node transform: the file's normals must be turned with the positions
        scene = trimesh.Scene()
        scene.add_geometry(mesh, transform=trimesh.transformations.rotation_matrix(0.5, [0, 1, 0]))
        scene.export(path)
    else:
        mesh.export(path)
    return {k: np.asarray(v, dtype=np.float32) / 255 for k, v in maps.items()}


def test_read_asset_normals_and_maps(tmp_path):
    p = tmp_path / "box.glb"
    maps = write_box_glb(p)
    mesh = load_mesh(p)
    assert mesh.n_vertices == 8  # welded: the hard edges are gone from the loaded mesh
    asset = read_asset(p, mesh)
    # each corner's normal is its face's (hard edges), not the welded mesh's averaged normal
    np.testing.assert_allclose(asset.corner_normals, np.repeat(mesh.face_normals[:, None], 3, axis=1), atol=1e-6)
    assert set(asset.maps) == {"normal", "metallic_roughness", "occlusion"}
    np.testing.assert_allclose(asset.maps["normal"], maps["normal"], atol=1e-7)
    np.testing.assert_allclose(asset.maps["metallic_roughness"], maps["mr"], atol=1e-7)
    shaded = shading_mesh(mesh, asset.corner_normals)
    assert shaded.n_vertices == 24 and shaded.n_faces == 12  # 4 corners per side, split along every edge
    np.testing.assert_allclose(shaded.vertex_normals[shaded.faces], asset.corner_normals, atol=1e-6)
    np.testing.assert_array_equal(shaded.uv, mesh.uv)
    np.testing.assert_allclose(shaded.triangles, mesh.triangles)


def test_node_transforms_turn_the_normals(tmp_path):
    p = tmp_path / "turned.glb"
    write_box_glb(p, rotate=True)
    mesh = load_mesh(p)
    asset = read_asset(p, mesh)
    np.testing.assert_allclose(asset.corner_normals, np.repeat(mesh.face_normals[:, None], 3, axis=1), atol=1e-6)


def test_load_mesh_keeps_the_files_corner_normals(tmp_path):
    """The loaded (welded) mesh carries the file's own normals per corner, face-aligned, turned by node
    transforms; an OBJ has none; a mesh file of the batch keeps them."""
    from neural_bake.io.mesh_npz import load_mesh_npz, save_mesh_npz

    for rotate in (False, True):
        p = tmp_path / f"box{int(rotate)}.glb"
        write_box_glb(p, rotate=rotate)
        mesh = load_mesh(p)
        assert mesh.n_vertices == 8 and mesh.corner_normals.shape == (12, 3, 3)
        np.testing.assert_allclose(mesh.corner_normals, np.repeat(mesh.face_normals[:, None], 3, axis=1), atol=1e-6)
        np.testing.assert_array_equal(mesh.corner_normals, read_asset(p, mesh).corner_normals)
    save_mesh_npz(mesh, tmp_path / "m.npz")
    np.testing.assert_array_equal(load_mesh_npz(tmp_path / "m.npz")[0].corner_normals, mesh.corner_normals)
    obj = tmp_path / "box.obj"
    trimesh.creation.box(extents=EXTENTS).export(obj)
    assert load_mesh(obj).corner_normals is None


def test_read_asset_other_formats_and_mismatch(tmp_path):
    obj = tmp_path / "box.obj"
    trimesh.creation.box().export(obj)
    assert read_asset(obj, load_mesh(obj)).corner_normals is None
    p = tmp_path / "box.glb"
    write_box_glb(p)
    with pytest.raises(MeshError, match="the file's faces do not match"):
        read_asset(p, load_mesh(obj))  # 12 faces too, another box
    ico = tmp_path / "ico.obj"
    trimesh.creation.icosphere(1).export(ico)
    with pytest.raises(MeshError, match="12 faces in the file against 80 loaded; not the same mesh"):
        read_asset(p, load_mesh(ico))
    with pytest.raises(MeshError, match="corner normals must be"):
        shading_mesh(load_mesh(p), np.zeros((3, 3, 3)))


def test_export_keeps_material_maps_once(tmp_path):
    p = tmp_path / "box.glb"
    maps = write_box_glb(p)
    mesh = load_mesh(p)
    from neural_bake.mesh.tangents import tangent_frames
    from neural_bake.mesh.unwrap import split_uv_seams

    shaded = split_uv_seams(shading_mesh(mesh, read_asset(p, mesh).corner_normals))[0]

    out = export_glb(tmp_path / "o.glb", shaded, tangents=tangent_frames(shaded),
                     material_maps={"normal": maps["normal"], "metallic_roughness": maps["mr"],
                                    "occlusion": maps["mr"]},
                     same_image=[("metallic_roughness", "occlusion")], material_factors={"metallicFactor": 0.5})
    gltf, arrays, images = read_glb(out)
    mat = gltf["materials"][0]
    assert len(images) == 2  # the packed map once
    assert mat["occlusionTexture"]["index"] == mat["pbrMetallicRoughness"]["metallicRoughnessTexture"]["index"]
    assert mat["pbrMetallicRoughness"]["metallicFactor"] == 0.5 and mat["pbrMetallicRoughness"]["roughnessFactor"] == 1.0
    decoded = np.asarray(Image.open(io.BytesIO(images[mat["normalTexture"]["index"]])), dtype=np.float32) / 255
    np.testing.assert_allclose(decoded, maps["normal"], atol=1e-6)  # written unchanged, as data
    with pytest.raises(NeuralBakeError, match="unknown material map 'height'"):
        export_glb(tmp_path / "x.glb", shaded, material_maps={"height": maps["mr"]})
    with pytest.raises(NeuralBakeError, match="needs tangents"):
        export_glb(tmp_path / "x.glb", shaded, material_maps={"normal": maps["normal"]})


def _models(tmp_path, mesh):
    gen = torch.Generator().manual_seed(0)
    sdf = save_model(Siren(16, 1, generator=gen), tmp_path / "s.sdf", kind="sdf", frame=mesh.frame.to_dict())
    tex = save_model(Siren(16, 1, out_dim=3, generator=gen), tmp_path / "t.tex", kind="texture",
                     frame=mesh.frame.to_dict())
    return str(sdf), str(tex)


def _by_position(arrays):
    """Output vertices keyed by rounded (position, normal): the set a renderer shades."""
    return {tuple(np.round(np.concatenate([p, n]).astype(np.float64), 4))
            for p, n in zip(arrays["POSITION"], arrays["NORMAL"])}


def test_bake_keep_preserves_the_asset(tmp_path):
    from neural_bake.pipelines.bake_asset import BakeAssetConfig, bake_asset

    p = tmp_path / "box.glb"
    maps = write_box_glb(p)
    mesh = load_mesh(p)
    sdf, tex = _models(tmp_path, mesh)
    # the untrained SDF does not describe the box: force past the mesh check, the test is about what is kept
    # the normal map baked: the asset's normals, UVs, base colour and AO/roughness/metal stay
    rep = bake_asset(p, sdf, tmp_path / "a", BakeAssetConfig(coarse="keep", size=32, maps="normal", force=True), log=lambda s: None)
    gltf, arrays, images = read_glb(tmp_path / "a" / "asset.glb")
    src = trimesh.load(p, process=False, force="mesh")
    expected = {tuple(np.round(np.concatenate([v, n]), 4)) for v, n in zip(src.vertices, src.vertex_normals)}
    assert _by_position(arrays) == expected  # every hard-edge split with the file's own normal
    assert len(arrays["POSITION"]) == len(src.vertices) == 36  # no corner merged or lost
    src_uv = {tuple(np.round(np.concatenate([v, [u[0], 1 - u[1]]]), 4)) for v, u in zip(src.vertices, src.visual.uv)}
    assert {tuple(np.round(np.concatenate([v, u]).astype(np.float64), 4))
            for v, u in zip(arrays["POSITION"], arrays["TEXCOORD_0"])} == src_uv
    mat = gltf["materials"][0]
    pbr = mat["pbrMetallicRoughness"]
    assert {"baseColorTexture", "metallicRoughnessTexture"} <= set(pbr) and {"normalTexture", "occlusionTexture"} <= set(mat)
    decode = lambda i: np.asarray(Image.open(io.BytesIO(images[i])), dtype=np.float32) / 255  # noqa: E731
    np.testing.assert_allclose(decode(pbr["metallicRoughnessTexture"]["index"]), maps["mr"], atol=1e-6)
    np.testing.assert_allclose(decode(mat["occlusionTexture"]["index"]), maps["ao"], atol=1e-6)
    np.testing.assert_allclose(decode(pbr["baseColorTexture"]["index"]), maps["base"], atol=1.5 / 255)
    assert decode(mat["normalTexture"]["index"]).shape == (32, 32, 3)  # the baked map replaced the asset's
    assert rep["kept"] == {"vertex_normals": "the asset's", "uv": "the asset's",
                           "maps": ["base_colour", "metallic_roughness", "occlusion"]}
    assert any(w.startswith("--coarse keep:") for w in rep["warnings"])
    # only the albedo baked: the asset's own normal map stays, unchanged
    rep = bake_asset(p, sdf, tmp_path / "b", BakeAssetConfig(coarse="keep", size=32, maps="albedo", force=True),
                     texture_model=tex, log=lambda s: None)
    gltf, arrays, images = read_glb(tmp_path / "b" / "asset.glb")
    mat = gltf["materials"][0]
    np.testing.assert_allclose(decode(mat["normalTexture"]["index"]), maps["normal"], atol=1e-6)
    assert decode(mat["pbrMetallicRoughness"]["baseColorTexture"]["index"]).shape == (32, 32, 3)  # baked
    assert "normal" in rep["kept"]["maps"] and "base_colour" not in rep["kept"]["maps"]
    assert _by_position(arrays) == expected
    json.dumps(rep)
