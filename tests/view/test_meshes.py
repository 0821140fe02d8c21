"""ViewMesh is a Mesh: a loaded mesh's view keeps its vertices and frame; to_mesh in the identity frame and in a
mesh's own frame; what the viewer reads of a GLB."""

import numpy as np
import trimesh

from neural_bake.bake.export import export_glb
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.types import Frame, Mesh
from neural_bake.view.meshes import load_view_mesh, view_mesh_from_glb, view_mesh_from_mesh


def _textured(rng):
    s = trimesh.creation.icosphere(subdivisions=1)
    uv = rng.uniform(0, 1, size=(len(s.faces), 3, 2))
    tex = rng.uniform(0, 1, size=(8, 8, 3)).astype(np.float32)
    return mesh_from_arrays(np.asarray(s.vertices) * 3 + 7, s.faces, uv=uv, texture=tex, source="ico.obj")


def test_to_mesh_gives_the_arrays_back_in_any_frame(rng):
    mesh = _textured(rng)
    view = view_mesh_from_mesh(mesh)
    assert isinstance(view, Mesh) and view.frame == mesh.frame and view.n_faces == mesh.n_faces
    np.testing.assert_array_equal(view.vertices, mesh.vertices)  # the mesh itself, in its own frame
    np.testing.assert_array_equal(view.positions, mesh.frame.to_source(mesh.vertices))  # the source frame
    same = view.to_mesh()
    assert same.frame == Frame() and same.source == view.name == "ico.obj"
    np.testing.assert_array_equal(same.vertices, view.positions)  # the identity frame: exactly the positions
    np.testing.assert_array_equal(same.faces, mesh.faces)
    np.testing.assert_array_equal(same.vertex_normals, view.vertex_normals)
    np.testing.assert_array_equal(same.uv, mesh.uv)
    np.testing.assert_array_equal(same.texture, mesh.texture)
    back = view.to_mesh(mesh.frame, source="again")
    assert back.frame == mesh.frame and back.source == "again"
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-12)
    assert view.without_maps().to_mesh().texture is None


def test_our_glb_is_read_as_exported_and_a_foreign_one_through_load_mesh(tmp_path, rng):
    from neural_bake.mesh.unwrap import split_uv_seams

    mesh = split_uv_seams(_textured(rng))[0]
    ours = export_glb(tmp_path / "ours.glb", mesh, albedo=mesh.texture, name="x")
    trimesh.Trimesh(np.asarray(mesh.vertices), mesh.faces).export(tmp_path / "theirs.glb")
    read = load_view_mesh(ours)
    np.testing.assert_array_equal(read.positions, view_mesh_from_glb(ours).positions)
    np.testing.assert_allclose(read.positions, mesh.frame.to_source(mesh.vertices), atol=1e-5)
    assert read.texture is not None and read.name == "ours.glb"
    foreign = load_view_mesh(tmp_path / "theirs.glb")
    assert foreign.texture is None and foreign.faces.shape == (mesh.n_faces, 3)  # load_mesh welds the seams
