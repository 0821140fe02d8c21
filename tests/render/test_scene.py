"""Scene files: TOML with the content of the Scene dataclasses; one-line errors naming the file and key."""

import pytest

from neural_bake.render.camera import CameraError
from neural_bake.render.scene import Scene, SceneError, SceneObject, Transform, load_scene, parse_list
from neural_bake.render.shading import DirectionalLight, PointLight, ShadingError

FULL = """
background = [0.1, 0.2, 0.3]
effects = ["shading", "normal-mapping", "texture", "shadows", "ambient_occlusion"]
channels = ["colour", "depth", "normal", "hit", "iterations"]
normal_level = -1
far = 9.5
skip = false

[camera]
position = [0.0, 0.5, 3.0]
look_at = [0.0, 0.0, 0.0]
fov_deg = 35
width = 64
height = 48

[trace]
mode = "fixed"
iterations = [30, 10]

[ambient_occlusion]
samples = 4
distance = 0.2

[[objects]]
model = "bunny.nested"
texture = "/abs/bunny.tex"
deltas = [0.02, 0.0]
transform = { translate = [0, 1, 0], rotate_deg = [0, 30, 0], scale = 2.0 }

[[lights]]
kind = "directional"
direction = [-0.4, -0.6, -0.7]

[[lights]]
kind = "point"
position = [2.0, 3.0, 3.0]
intensity = 5.0

[material]
kind = "matcap"
"""


def test_a_full_scene_file_reads_into_the_dataclasses(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(FULL)
    s = load_scene(path)
    assert s.background == (0.1, 0.2, 0.3)
    assert s.effects == ("shading", "normal_mapping", "texture", "shadows", "ambient_occlusion")
    assert s.channels == ("color", "depth", "normal", "hit", "iterations")
    assert s.camera.position == (0.0, 0.5, 3.0) and (s.camera.width, s.camera.height) == (64, 48)
    assert s.camera.fov_deg == 35.0
    assert s.trace.mode == "fixed" and s.trace.iterations == (30, 10)
    assert s.ambient_occlusion.samples == 4 and s.ambient_occlusion.distance == 0.2
    assert s.far == 9.5 and s.skip is False
    (obj,) = s.objects
    assert obj.model == str(tmp_path / "bunny.nested") and obj.texture == "/abs/bunny.tex"
    assert obj.deltas == (0.02, 0.0)
    assert obj.transform == Transform((0.0, 1.0, 0.0), (0.0, 30.0, 0.0), 2.0)
    assert s.lights == (DirectionalLight((-0.4, -0.6, -0.7)), PointLight((2.0, 3.0, 3.0), intensity=5.0))
    assert s.material.kind == "matcap"


def test_an_empty_scene_file_is_the_default_scene(tmp_path):
    path = tmp_path / "empty.toml"
    path.write_text("")
    assert load_scene(path) == Scene()


@pytest.mark.parametrize("text, err, match", [
    ("colour_depth = 3", SceneError, r"scene.toml: unknown key 'colour_depth'"),
    ("effects = ['glow']", SceneError, r"scene.toml: effects: unknown effect 'glow'"),
    ("channels = ['color', 'alpha']", SceneError, r"channels: unknown channel 'alpha'"),
    ("channels = []", SceneError, r"at least one channel"),
    ("background = [1, 2]", SceneError, r"background: expected 3 finite numbers"),
    ("far = -1.0", SceneError, r"far: expected a finite number > 0"),
    ("skip = 'yes'", SceneError, r"skip: expected true or false"),
    ("skip_depth = 12", SceneError, r"skip_depth"),
    ("[camera]\nfov_deg = 200", CameraError, r"scene.toml: camera: camera fov_deg"),
    ("[camera]\nlens = 50", SceneError, r"camera: unknown key 'lens'"),
    ("[trace]\nmode = 'quick'", Exception, r"scene.toml: trace: trace mode 'quick'"),
    ("[trace]\niterations = [10, -2]", Exception, r"trace iterations"),
    ("[trace]\nsteps = 3", SceneError, r"trace: unknown key 'steps'"),
    ("[material]\nkind = 'pbr'", ShadingError, r"material: material kind 'pbr'"),
    ("[[lights]]\nkind = 'spot'", SceneError, r"lights\[0\].kind: expected 'directional' or 'point'"),
    ("[[lights]]\ndirection = [0, 0, 0]", ShadingError, r"lights\[0\]: directional light direction"),
    ("lights = 3", SceneError, r"lights: expected an array of tables"),
    ("[[objects]]\nmodel = 3", SceneError, r"objects\[0\].model: expected a file path"),
    ("[[objects]]\nshape = 'x'", SceneError, r"objects\[0\]: unknown key 'shape'"),
    ("[[objects]]\ntransform = { scale = 0 }", SceneError, r"transform scale"),
    ("[[objects]]\ndeltas = [0.1, -1]", SceneError, r"object deltas"),
    ("[ambient_occlusion]\nsamples = 0", SceneError, r"ambient_occlusion samples"),
    ("effects = [", SceneError, r"scene.toml: not valid TOML"),
])
def test_bad_scene_files_give_one_line_errors_naming_file_and_key(tmp_path, text, err, match):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    with pytest.raises(err, match=match) as info:
        load_scene(path)
    assert "\n" not in str(info.value)


def test_a_missing_scene_file_is_named(tmp_path):
    with pytest.raises(SceneError, match="no such scene file"):
        load_scene(tmp_path / "nope.toml")


def test_parse_list_reads_commas_dashes_and_none():
    assert parse_list("shading, normal-mapping,shading", "effects", ("shading", "normal_mapping")) == (
        "shading", "normal_mapping")
    assert parse_list("none", "effects", ("shading",)) == ()
    with pytest.raises(SceneError, match="expected a list"):
        parse_list(3, "effects", ("shading",))


def test_scene_values_are_validated_in_python_too():
    with pytest.raises(SceneError, match="normal_level"):
        Scene(normal_level=1.5)
    with pytest.raises(SceneError, match="lights"):
        Scene(lights=("sun",))
    with pytest.raises(SceneError, match="shadow_bias"):
        Scene(shadow_bias=-1.0)
    assert SceneObject(transform={"scale": 2.0}).transform.scale == 2.0
