"""The GLB writer and reader (neural_bake.io.gltf): round trip of arrays, images and material; what wrote a file;
errors; the Khronos glTF validator on a baked asset and a saved mesh."""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from neural_bake.errors import NeuralBakeError
from neural_bake.io.gltf import GENERATOR, glb_bytes, glb_generator, read_glb

PNG = b"\x89PNG\r\n\x1a\n" + bytes(13)  # bytes only: the writer embeds them as they are
VALIDATOR = Path(__file__).resolve().parents[2] / ".cache" / "gltf-validator" / "node_modules" / "gltf-validator"


def _quad():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    return v, f


def test_round_trip_of_arrays_images_and_material(tmp_path):
    v, f = _quad()
    n = np.tile([0.0, 0, 1], (4, 1))
    t = np.array([[0.0, 0], [1, 0], [1, 1], [0, 1]])
    material = {"pbrMetallicRoughness": {"baseColorTexture": {"index": 1}}, "normalTexture": {"index": 0}}
    data = glb_bytes([("POSITION", v), ("NORMAL", n), ("TEXCOORD_0", t)], f, images=[PNG, PNG + b"x"],
                     material=material, name="quad")
    assert len(data) % 4 == 0 and int.from_bytes(data[8:12], "little") == len(data)
    (tmp_path / "q.glb").write_bytes(data)
    gltf, arr, images = read_glb(tmp_path / "q.glb")
    assert gltf["asset"] == {"version": "2.0", "generator": GENERATOR}
    assert list(arr) == ["POSITION", "NORMAL", "TEXCOORD_0", "indices"]
    np.testing.assert_array_equal(arr["POSITION"], v.astype(np.float32))
    np.testing.assert_array_equal(arr["TEXCOORD_0"], t.astype(np.float32))
    np.testing.assert_array_equal(arr["indices"], f)
    assert arr["POSITION"].dtype == np.float32 and arr["indices"].dtype == np.uint32
    assert images == [PNG, PNG + b"x"]
    assert gltf["materials"] == [{"name": "quad", **material}]
    assert gltf["textures"] == [{"source": 0, "sampler": 0}, {"source": 1, "sampler": 0}]
    pos = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    assert pos["min"] == [0.0, 0.0, 0.0] and pos["max"] == [1.0, 1.0, 0.0]
    # trimesh reads it too
    (geom,) = trimesh.load(tmp_path / "q.glb", process=False).geometry.values()
    np.testing.assert_allclose(geom.vertices, v)


def test_no_material_and_no_images_is_the_default_material(tmp_path):
    v, f = _quad()
    (tmp_path / "q.glb").write_bytes(glb_bytes([("POSITION", v)], f))
    gltf, arr, images = read_glb(tmp_path / "q.glb")
    assert images == [] and "materials" not in gltf and "material" not in gltf["meshes"][0]["primitives"][0]
    assert not {"samplers", "images", "textures"} & set(gltf)


def test_generator_names_who_wrote_the_file(tmp_path):
    v, f = _quad()
    (tmp_path / "ours.glb").write_bytes(glb_bytes([("POSITION", v)], f))
    trimesh.Trimesh(v, f).export(tmp_path / "theirs.glb")
    (tmp_path / "junk.glb").write_bytes(b"glTF" + bytes(30))
    (tmp_path / "short.glb").write_bytes(b"gl")
    assert glb_generator(tmp_path / "ours.glb") == GENERATOR
    assert glb_generator(tmp_path / "theirs.glb") not in (None, GENERATOR)
    assert glb_generator(tmp_path / "junk.glb") is None and glb_generator(tmp_path / "short.glb") is None


def test_read_errors_name_the_file(tmp_path):
    (tmp_path / "t.glb").write_bytes(b"not a glb at all, really")
    with pytest.raises(NeuralBakeError, match=r"t\.glb: not a GLB file"):
        read_glb(tmp_path / "t.glb")
    (tmp_path / "j.glb").write_bytes(b"glTF" + (2).to_bytes(4, "little") + (40).to_bytes(4, "little")
                                     + (8).to_bytes(4, "little") + b"BIN\x00" + bytes(8))
    with pytest.raises(NeuralBakeError, match=r"j\.glb: GLB without a JSON chunk"):
        read_glb(tmp_path / "j.glb")
    (tmp_path / "p.glb").write_bytes(b"glTF" + (2).to_bytes(4, "little") + (28).to_bytes(4, "little")
                                     + (8).to_bytes(4, "little") + b"JSON" + b"{bad    ")
    with pytest.raises(NeuralBakeError, match=r"p\.glb: GLB whose JSON chunk does not parse"):
        read_glb(tmp_path / "p.glb")


_VALIDATE_JS = """
const fs = require("fs");
const validator = require(process.argv[1]);
const data = new Uint8Array(fs.readFileSync(process.argv[2]));
validator.validateBytes(data, {maxIssues: 100}).then(
  (report) => process.stdout.write(JSON.stringify(report.issues)),
  (error) => { process.stderr.write(String(error)); process.exit(1); });
"""


def _validate(path: Path) -> dict:
    if shutil.which("node") is None:
        pytest.skip("node is not installed: the Khronos glTF validator runs on it")
    if not (VALIDATOR / "package.json").is_file():
        pytest.skip(f"the Khronos glTF validator is not in {VALIDATOR} (scripts/setup.sh fetches it with npm)")
    res = subprocess.run(["node", "-e", _VALIDATE_JS, str(VALIDATOR), str(path)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def test_khronos_validator_accepts_a_baked_asset_and_a_saved_mesh(tmp_path):
    from neural_bake.io.mesh_io import mesh_from_arrays, save_mesh
    from neural_bake.samples.shapes import get_sample
    from neural_bake.view.analytic import analytic_bake

    bake = analytic_bake(tmp_path, faces=300, size=64)
    arrays = get_sample("sphere").mesh(resolution=400, texture_size=32)
    saved = save_mesh(mesh_from_arrays(arrays.vertices, arrays.faces, arrays.uv, arrays.texture),
                      tmp_path / "saved.glb")
    for path in (bake.glb, saved):
        issues = _validate(path)
        problems = [m for m in issues["messages"] if m["severity"] <= 1]  # 0 error, 1 warning
        assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, (path.name, problems)
