"""Only what the scene calls for: evaluation counters per network and effect, shading, textures, shadows, AO."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from neural_bake.render.asset import RenderAsset, RenderError, analytic_texture, as_render_asset
from neural_bake.render.camera import Camera
from neural_bake.render.renderer import render
from neural_bake.render.scene import Scene, Transform, SceneObject
from neural_bake.render.shading import DirectionalLight, Material, PointLight
from neural_bake.render.trace import TraceSettings

from render_cases import exact_sphere_hits, nested_sphere_asset, sphere_level

CAM = Camera(position=(0.2, 0.3, 2.4), fov_deg=40, width=40, height=32)
RED = analytic_texture(lambda p: torch.stack([0.9 + 0 * p[:, 0], 0.1 + 0 * p[:, 0], 0.1 + 0 * p[:, 0]], 1),
                       name="tex")


def _asset():
    return nested_sphere_asset().with_texture(RED)


def _counts(result) -> dict:
    return {(net, eff): n for net, effects in result.counter.points.items() for eff, n in effects.items() if n}


def test_a_scene_without_effects_only_traces_and_misses_evaluate_nothing_after_the_miss():
    r = render(_asset(), Scene(effects=(), channels=("color", "hit")), camera=CAM)
    assert r.counter.effects() <= {"trace", "skip_octree"}
    assert r.counter.total(network="tex") == 0
    np.testing.assert_allclose(r["color"][r["hit"]], np.full((int(r["hit"].sum()), 3), 0.8), atol=1e-6)
    np.testing.assert_allclose(r["color"][~r["hit"]], 1.0)


def test_each_effect_adds_only_its_own_evaluations():
    base_scene = Scene(effects=("shading",), channels=("color",))
    base = _counts(render(_asset(), base_scene, camera=CAM))
    hits = int(render(_asset(), base_scene, camera=CAM)["hit"].sum())
    assert base[("f", "normals")] == hits  # GEMM normals at the hits only
    for effect in ("texture", "shadows", "ambient_occlusion"):
        counts = _counts(render(_asset(), base_scene.with_(effects=("shading", effect)), camera=CAM))
        added = {k: v for k, v in counts.items() if k not in base}
        assert added and all(eff == effect for _, eff in added), (effect, added)
        assert {k: counts[k] for k in base} == base, effect
    # normal mapping replaces the traced level's normals by the chosen level's, at the same pixels
    nm = _counts(render(_asset(), base_scene.with_(effects=("shading", "normal_mapping"), normal_level=0), camera=CAM))
    assert nm[("h1", "normal_mapping")] == hits and ("f", "normals") not in nm
    assert {k: v for k, v in nm.items() if k[1] != "normal_mapping"} == {
        k: v for k, v in base.items() if k[1] != "normals"}


def test_per_effect_counts_are_bounded_by_the_hits():
    scene = Scene(effects=("shading", "texture", "shadows", "ambient_occlusion"), channels=("color",),
                  lights=(DirectionalLight(), PointLight(position=(2.0, 2.0, 2.0))))
    r = render(_asset(), scene, camera=CAM)
    hits = int(r["hit"].sum())
    assert r.counter.points["tex"]["texture"] == hits
    assert r.counter.total("ambient_occlusion") == hits * scene.ambient_occlusion.samples
    assert r.counter.total("normals") == hits
    its = scene.trace.iterations_for(2)
    assert 0 < r.counter.total("shadows") <= hits * 2 * sum(its)


def test_without_normal_mapping_the_fine_level_is_never_evaluated():
    scene = Scene(effects=("shading", "texture", "ambient_occlusion"), channels=("color",),
                  trace=TraceSettings(mode="fixed", iterations=(40, 0)))
    r = render(_asset(), scene, camera=CAM)
    assert r.counter.total(network="f") == 0
    r = render(_asset(), scene.with_(effects=("shading", "normal_mapping")), camera=CAM)
    assert r.counter.total(network="f") == r.counter.total("normal_mapping") == int(r["hit"].sum())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_normal_mapping_reads_the_texture_at_the_mapped_levels_closest_point(dtype):
    # channel 0 is the distance from the centre: traced on h1 (radius 0.52), mapped onto f (radius 0.5)
    radial = analytic_texture(lambda p: torch.stack([p.norm(dim=1), 0 * p[:, 0], 0 * p[:, 0]], 1))
    asset = nested_sphere_asset().with_texture(radial)
    scene = Scene(effects=("texture",), channels=("color", "hit"),
                  trace=TraceSettings(mode="fixed", iterations=(40, 0)))
    traced = render(asset, scene, camera=CAM, dtype=dtype)
    hit = traced["hit"]
    np.testing.assert_allclose(traced["color"][hit][:, 0], 0.52, atol=1e-3)  # within the tracer's tolerance
    mapped = render(asset, scene.with_(effects=("texture", "normal_mapping"), normal_level=1), camera=CAM, dtype=dtype)
    np.testing.assert_allclose(mapped["color"][hit][:, 0], 0.5, atol=1e-4)
    # a texture fitted to a band of δ moves its reads by δ at most
    near = render(nested_sphere_asset().with_texture(replace(radial, delta=0.005)),
                  scene.with_(effects=("texture", "normal_mapping"), normal_level=1), camera=CAM, dtype=dtype)
    np.testing.assert_allclose(near["color"][hit][:, 0], traced["color"][hit][:, 0] - 0.005, atol=1e-5)


def test_texture_colours_the_hits_only():
    r = render(_asset(), Scene(effects=("texture",), channels=("color", "hit")), camera=CAM)
    np.testing.assert_allclose(r["color"][r["hit"]], np.tile([0.9, 0.1, 0.1], (int(r["hit"].sum()), 1)), atol=1e-6)
    np.testing.assert_allclose(r["color"][~r["hit"]], 1.0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_texture_network_of_srgb_colours_renders_linear_ones(dtype):
    # a constant network that outputs sRGB (0.5, 0.25, 1.0): the renderer shows their linear values
    from neural_bake.fields import TextureField
    from neural_bake.io.colour import srgb_to_linear
    from neural_bake.nets.siren import Siren

    net = Siren(8, 0, 3, 3)
    with torch.no_grad():
        net.layers[-1].weight.zero_()
        net.layers[-1].bias.copy_(torch.tensor([0.5, 0.25, 1.0]))
    scene = Scene(effects=("texture",), channels=("color", "hit"))
    for encoding, expected in (("srgb", srgb_to_linear(np.array([0.5, 0.25, 1.0]))), ("linear", [0.5, 0.25, 1.0])):
        field = TextureField.from_model(net, encoding=encoding)
        r = render(as_render_asset(nested_sphere_asset(), texture=field), scene, camera=CAM, dtype=dtype)
        np.testing.assert_allclose(r["color"][r["hit"]], np.tile(expected, (int(r["hit"].sum()), 1)), atol=1e-5)


def test_a_texture_with_normal_inputs_reads_the_hits_normals():
    # a colour field whose colour is the normal it reads, (n + 1) / 2: the colour channel shows the normal channel
    from neural_bake.fields import TextureField

    field = TextureField(lambda x: (x[:, 3:] + 1.0) / 2.0, normal_inputs=True, name="sided")
    scene = Scene(effects=("texture",), channels=("color", "normal", "hit"))
    r = render(as_render_asset(nested_sphere_asset(), texture=field), scene, camera=CAM)
    hit = r["hit"]
    assert hit.sum() > 100 and r.counter.total(network="sided") == int(hit.sum())
    np.testing.assert_allclose(r["color"][hit], (r["normal"][hit] + 1.0) / 2.0, atol=1e-5)


def test_shading_follows_the_analytic_normal():
    light = DirectionalLight(direction=(0.0, 0.0, -1.0))
    mat = Material(ambient=0.0, specular=0.0)
    cam = Camera(position=(0.0, 0.0, 3.0), width=33, height=33)
    r = render(_asset(), Scene(lights=(light,), material=mat, channels=("color", "hit")), camera=cam)
    hit, t = exact_sphere_hits(cam, 0.5)
    pts = np.asarray(cam.position) + np.where(hit, t, 0)[..., None] * cam.pixel_directions()
    lambert = 0.8 * np.clip(pts[..., 2] / 0.5, 0, None)
    inner = hit & r["hit"] & (pts[..., 2] > 0.2)
    np.testing.assert_allclose(r["color"][inner][:, 0], lambert[inner], atol=3e-3)


def test_a_sphere_shadows_the_one_behind_it():
    front = sphere_level(0.25, name="front", center=(0.0, 0.0, 0.6))
    back = sphere_level(0.5, name="back", center=(0.0, 0.0, -0.3))
    light = DirectionalLight(direction=(0.0, 0.0, -1.0))
    cam = Camera(position=(0.0, 2.5, 2.5), look_at=(0.0, 0.0, 0.0), width=40, height=40)
    scene = Scene(lights=(light,), effects=("shading", "shadows"), channels=("color", "hit", "depth"), skip=False)
    lit = render(RenderAsset([back]), scene, camera=cam)
    shadowed = render([RenderAsset([back]), RenderAsset([front])],
                      scene.with_(objects=(SceneObject(), SceneObject())), camera=cam)
    # points of the back sphere whose (x, y) lie under the front sphere's disc, facing the light, go dark
    pts = np.asarray(cam.position) + np.where(shadowed["hit"], shadowed["depth"], 0)[..., None] * cam.pixel_directions()
    on_back = shadowed["hit"] & (np.linalg.norm(pts - [0, 0, -0.3], axis=-1) < 0.51)
    under = on_back & (np.hypot(pts[..., 0], pts[..., 1]) < 0.2) & (pts[..., 2] > -0.3)
    assert under.sum() > 5
    assert (shadowed["color"][under] < lit["color"][under] - 0.3).all()
    assert shadowed.counter.total("shadows") > 0


def test_ambient_occlusion_darkens_a_crease_not_an_open_sphere():
    r = render(_asset(), Scene(effects=("shading", "ambient_occlusion"), channels=("color", "hit"),
                               material=Material(ambient=1.0, specular=0.0),
                               lights=(DirectionalLight(intensity=0.0),)), camera=CAM)
    np.testing.assert_allclose(r["color"][r["hit"]], 0.8, atol=1e-4)  # convex: nothing occludes


def test_transform_places_the_object():
    moved = Scene(objects=(SceneObject(transform=Transform(translate=(0.3, 0.0, 0.0), scale=0.5)),),
                  channels=("hit", "depth"), skip=False)
    cam = Camera(position=(0.0, 0.0, 3.0), width=41, height=41)
    r = render(nested_sphere_asset(), moved, camera=cam)
    hit, _ = exact_sphere_hits(cam, 0.25, center=(0.3, 0.0, 0.0))
    assert np.abs(r["hit"].astype(int) - hit.astype(int)).sum() <= 8  # silhouette pixels at most


def test_matcap_material_renders_finite_colours():
    r = render(_asset(), Scene(material=Material(kind="matcap"), effects=("shading", "texture"),
                               channels=("color",)), camera=CAM)
    assert np.isfinite(r["color"]).all() and r["color"][r["hit"]].std() > 0


@pytest.mark.parametrize("scene, match", [
    (Scene(effects=("texture",)), "no texture field"),
    (Scene(effects=("normal_mapping",), normal_level=5), "normal_level 5"),
])
def test_effects_the_asset_cannot_serve_are_refused(scene, match):
    with pytest.raises(RenderError, match=match):
        render(nested_sphere_asset(), scene, camera=CAM)


def test_asset_and_object_counts_must_agree():
    with pytest.raises(RenderError, match="2 assets for 1 scene objects"):
        render([_asset(), _asset()], Scene(objects=(SceneObject(),)), camera=CAM)
    with pytest.raises(RenderError, match="no object"):
        render([], Scene(), camera=CAM)
