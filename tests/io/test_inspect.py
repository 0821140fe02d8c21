"""inspect_mesh / topology / `neural-bake inspect`: counts, genus, winding, JSON, errors and exit codes."""

import json
import warnings

import numpy as np
import pytest
import trimesh

from neural_bake.cli.main import main
from neural_bake.errors import MeshError, NeuralBakeWarning
from neural_bake.io.images import write_image
from neural_bake.io.inspect import format_report, inspect_mesh, topology
from neural_bake.io.mesh_io import mesh_from_arrays, save_mesh


def quiet(fn, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NeuralBakeWarning)
        return fn(*a, **k)


def torus(genus_offset=(0.0, 0.0, 0.0)):
    t = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3, major_sections=24, minor_sections=12)
    return t.vertices + genus_offset, t.faces


def test_topology_sphere_torus_and_two_components():
    s = trimesh.creation.icosphere(subdivisions=1)
    assert topology(s.faces, len(s.vertices)) == {
        "components": 1, "euler": [2], "genus": 0,
        "edges": {"edges": 120, "boundary_edges": 0, "non_manifold_edges": 0, "inconsistent_edges": 0,
                  "watertight": True}}
    v, f = torus()
    t = topology(f, len(v))
    assert t["genus"] == 1 and t["euler"] == [0]
    both_v = np.vstack([v, s.vertices + 5])
    both_f = np.vstack([f, s.faces + len(v)])
    t = topology(both_f, len(both_v))
    assert t["components"] == 2 and sorted(t["euler"]) == [0, 2] and t["genus"] == 1
    assert topology(s.faces[1:], len(s.vertices))["genus"] is None  # open: genus undefined


def test_report_of_generated_textured_mesh():
    s = trimesh.creation.icosphere(subdivisions=2)
    uv = np.random.default_rng(0).random((len(s.faces), 3, 2)) * 0.5 + 0.25
    src = s.vertices * 2.0 + [1.0, 2.0, 3.0]
    m = mesh_from_arrays(src, s.faces, uv=uv, texture=np.zeros((16, 32, 4), np.float32))
    r = inspect_mesh(m)
    assert r["source"] == "<generated mesh>"
    assert (r["vertices"], r["faces"], r["degenerate_faces"]) == (len(s.vertices), len(s.faces), 0)
    assert r["uv"] and r["texture"] == {"width": 32, "height": 16, "channels": 4}
    np.testing.assert_allclose(r["uv_range"]["u"], [uv[..., 0].min(), uv[..., 0].max()])
    assert r["watertight"] and r["genus"] == 0 and r["components"] == 1 and r["winding"] == "outward"
    np.testing.assert_allclose(r["bounding_box"]["min"], src.min(0), atol=1e-9)  # source units
    np.testing.assert_allclose(r["bounding_box"]["size"], src.max(0) - src.min(0), atol=1e-9)
    assert r["warnings"] == [] and not r["own_normals"]
    assert "averaged over the faces at each vertex" in format_report(r)
    json.dumps(r)  # JSON-ready


def test_report_says_a_gltf_gives_its_own_normals(tmp_path):
    box = trimesh.creation.box()
    corners = box.triangles.reshape(-1, 3)  # every face its own corners, its normal theirs: hard edges
    trimesh.Trimesh(corners, np.arange(len(corners)).reshape(-1, 3), process=False,
                    vertex_normals=np.repeat(box.face_normals, 3, axis=0)).export(tmp_path / "box.glb")
    r = inspect_mesh(tmp_path / "box.glb")
    assert r["own_normals"] and "normals       the file's own, per face corner (hard edges kept)" in format_report(r)


def test_report_inward_and_open_and_degenerate():
    s = trimesh.creation.icosphere(subdivisions=1)
    r = inspect_mesh(quiet(mesh_from_arrays, s.vertices, s.faces[:, ::-1]))
    assert r["winding"] == "inward (fixed)" and r["genus"] == 0 and len(r["warnings"]) == 1
    f = np.vstack([s.faces[1:], [[0, 0, 1]]])
    r = inspect_mesh(quiet(mesh_from_arrays, s.vertices, f))
    assert r["winding"] == "n/a (open mesh)" and r["genus"] is None and not r["watertight"]
    assert r["degenerate_faces"] == 1 and r["boundary_edges"] == 3 and len(r["warnings"]) == 2
    text = format_report(r)
    assert "genus         n/a (open mesh)" in text and "no (3 boundary edges, 0 non-manifold edges)" in text
    assert "warnings      2" in text and "degenerate" in text


def test_report_from_file_does_not_reissue_warnings(tmp_path):
    v, f = torus()
    (tmp_path / "t.obj").write_text(  # a torus wound inward
        "".join(f"v {x} {y} {z}\n" for x, y, z in v) + "".join(f"f {a + 1} {c + 1} {b + 1}\n" for a, b, c in f))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = inspect_mesh(tmp_path / "t.obj")
    assert r["genus"] == 1 and r["winding"] == "inward (fixed)" and r["source"].endswith("t.obj")


# --- CLI -----------------------------------------------------------------------------------------------------


@pytest.fixture
def sphere_obj(tmp_path):
    s = trimesh.creation.icosphere(subdivisions=1)
    uv = np.full((len(s.faces), 3, 2), 0.5)
    m = mesh_from_arrays(s.vertices * 4, s.faces, uv=uv, texture=np.ones((4, 4, 3), np.float32))
    return save_mesh(m, tmp_path / "ball.obj")


def test_cli_human_readable(sphere_obj, capsys):
    assert main(["inspect", str(sphere_obj)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == str(sphere_obj)
    for line in ["vertices      42", "faces         80 (0 degenerate)", "texture       4 x 4, 3 channels",
                 "watertight    yes", "genus         0", "components    1", "winding       outward", "warnings      none"]:
        assert line in out


def test_cli_json_and_texture_option(sphere_obj, tmp_path, capsys):
    write_image(tmp_path / "big.png", np.zeros((8, 16, 3)))
    assert main(["inspect", str(sphere_obj), "--json", "--texture", str(tmp_path / "big.png")]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["texture"] == {"width": 16, "height": 8, "channels": 3} and r["vertices"] == 42
    s = trimesh.creation.icosphere(subdivisions=1)
    assert r["bounding_box"]["size"] == pytest.approx(list(4 * np.ptp(s.vertices, axis=0)), rel=1e-9)


@pytest.mark.parametrize(
    "make,message",
    [
        (lambda d: d / "missing.obj", "missing.obj: no such file"),
        (lambda d: (d / "bad.obj").write_text("v 0 0 0\nf 1 2 3\n") and d / "bad.obj",
         "bad.obj:2: face index 2 out of range (file has 1 vertices)"),
        (lambda d: (d / "m.xyz").write_text("1 2 3") and d / "m.xyz", "m.xyz: unknown mesh format '.xyz'"),
        (lambda d: (d / "c.glb").write_bytes(b"garbage") and d / "c.glb", "c.glb: unreadable GLB file"),
    ],
)
def test_cli_user_errors(tmp_path, capsys, make, message):
    path = make(tmp_path)
    assert main(["inspect", str(path)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"neural-bake: error: {tmp_path}") and message in err[0]
    assert "Traceback" not in captured.err and captured.out == ""


def test_cli_bad_texture(sphere_obj, tmp_path, capsys):
    assert main(["inspect", str(sphere_obj), "--texture", str(tmp_path / "no.png")]) == 2
    assert capsys.readouterr().err.strip() == f"neural-bake: error: {tmp_path / 'no.png'}: no such image file"


def test_library_error_for_missing_file(tmp_path):
    with pytest.raises(MeshError, match=r"nothing\.ply: no such file"):
        inspect_mesh(tmp_path / "nothing.ply")
