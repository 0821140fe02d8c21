"""Blinn-Phong and matcap shading against hand-computed values; zero normals never give NaN."""

import math

import numpy as np
import pytest
import torch

from neural_bake.render.camera import Camera
from neural_bake.render.shading import (
    DirectionalLight,
    Material,
    PointLight,
    ShadingError,
    default_lights,
    shade_blinn_phong,
    shade_matcap,
)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_blinn_phong_matches_the_formula(dtype):
    light = DirectionalLight(direction=(0.0, 0.0, -1.0), color=(1.0, 0.5, 0.25), intensity=2.0)
    mat = Material(albedo=(0.5, 0.5, 0.5), ambient=0.1, specular=0.3, shininess=8.0)
    n = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 0.0, -1.0]], dtype=dtype)
    p = torch.zeros(3, 3, dtype=dtype)
    view = torch.tensor([[0.0, 0.0, -1.0]] * 3, dtype=dtype)  # camera on +Z looking down -Z
    albedo = torch.full((3, 3), 0.5, dtype=dtype)
    rgb = shade_blinn_phong(n, p, view, albedo, [light], mat)
    assert rgb.dtype == dtype
    radiance = np.array([2.0, 1.0, 0.5])
    # facing light and eye: n·l = 1, n·h = 1
    np.testing.assert_allclose(rgb[0].numpy(), 0.05 + radiance * (0.5 + 0.3), rtol=1e-5)
    # 45° off: n·l = n·h = cos 45°
    c = math.cos(math.pi / 4)
    np.testing.assert_allclose(rgb[1].numpy(), 0.05 + radiance * (0.5 * c + 0.3 * c**8), rtol=1e-5)
    # facing away: ambient only, no specular leak
    np.testing.assert_allclose(rgb[2].numpy(), [0.05] * 3, rtol=1e-6)


def test_shadow_point_light_and_ambient_occlusion():
    light = PointLight(position=(0.0, 0.0, 2.0), intensity=4.0)
    mat = Material(ambient=0.2, specular=0.0)
    n = torch.tensor([[0.0, 0.0, 1.0]] * 2, dtype=torch.float64)
    p = torch.zeros(2, 3, dtype=torch.float64)
    view = torch.tensor([[0.0, 0.0, -1.0]] * 2, dtype=torch.float64)
    albedo = torch.ones(2, 3, dtype=torch.float64)
    vis = [torch.tensor([1.0, 0.0], dtype=torch.float64)]
    ao = torch.tensor([1.0, 0.5], dtype=torch.float64)
    rgb = shade_blinn_phong(n, p, view, albedo, [light], mat, visibility=vis, ambient_occlusion=ao)
    np.testing.assert_allclose(rgb[0].numpy(), 0.2 + 4.0 / 4.0, rtol=1e-12)  # 1/d² at d = 2
    np.testing.assert_allclose(rgb[1].numpy(), 0.1, rtol=1e-12)  # shadowed, half occluded ambient


def test_zero_and_nan_normals_shade_as_ambient_without_nan():
    n = torch.tensor([[0.0, 0.0, 0.0], [math.nan, 0.0, 1.0]])
    out = shade_blinn_phong(n, torch.zeros(2, 3), torch.tensor([[0.0, 0.0, -1.0]] * 2), torch.ones(2, 3),
                            [DirectionalLight()], Material(ambient=0.25))
    assert torch.isfinite(out).all()
    np.testing.assert_allclose(out.numpy(), 0.25)


def test_matcap_reads_the_view_space_normal():
    cam = Camera(position=(0.0, 0.0, 3.0))
    img = np.zeros((3, 3, 3), np.float32)
    img[0, 1] = (1, 0, 0)  # top centre: normals pointing up in the image
    img[1, 2] = (0, 1, 0)  # right centre
    img[1, 1] = (0, 0, 1)  # centre: facing the camera
    n = torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    out = shade_matcap(n, cam, img).numpy()
    np.testing.assert_allclose(out, [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1]])


def test_default_light_comes_from_behind_the_camera():
    cam = Camera(position=(0.0, 0.0, 5.0))
    (light,) = default_lights(cam)
    assert light.direction[2] < 0 and light.direction[1] < 0  # travels into the scene and downwards


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: DirectionalLight(direction=(0.0, 0.0, 0.0)), "zero vector"),
        (lambda: DirectionalLight(intensity=-1.0), "intensity"),
        (lambda: PointLight(position=(0.0, math.inf, 0.0)), "position"),
        (lambda: Material(kind="pbr"), "kind 'pbr'"),
        (lambda: Material(shininess=math.nan), "shininess"),
        (lambda: Material(albedo=(1.0, 1.0)), "albedo"),
    ],
)
def test_bad_lights_and_materials_are_refused(make, match):
    with pytest.raises(ShadingError, match=match):
        make()
