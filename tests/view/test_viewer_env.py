"""The sun HDR (read back through OpenImageIO) and the model-viewer camera attributes."""

import math

import numpy as np
import pytest

from neural_bake.io.images import read_image
from neural_bake.render.camera import Camera
from neural_bake.view import ViewError
from neural_bake.view.environment import equirect_directions, sun_environment, write_hdr
from neural_bake.view.viewer import model_viewer_attributes, models_js


def test_sun_hdr_round_trip_puts_the_sun_where_asked_with_the_asked_irradiance(tmp_path):
    sun = np.array([-0.3, 0.8, 0.5])
    img = sun_environment(sun, width=256, sky=0.1, irradiance=math.pi)
    path = write_hdr(tmp_path / "sun.hdr", img)
    back = read_image(path, colour="linear")
    assert back.shape == (128, 256, 3)
    assert np.allclose(back, img, rtol=0.01, atol=1e-3)  # RGBE keeps 8 bits of mantissa
    dirs = equirect_directions(256, 128)
    brightest = dirs.reshape(-1, 3)[np.argmax(back[..., 0])]
    assert np.degrees(np.arccos(brightest @ (sun / np.linalg.norm(sun)))) < 8.0
    # irradiance on a surface facing the sun: the sun's share is π (the sky adds π·sky·(1/2 hemisphere·2))
    h = 128
    lat = (0.5 - (np.arange(h) + 0.5) / h) * math.pi
    omega = (2 * math.pi / 256) * (math.pi / h) * np.cos(lat)[:, None]
    cosine = np.clip(dirs @ (sun / np.linalg.norm(sun)), 0, None)
    e = float(((back[..., 0] - 0.1) * cosine * omega).sum())
    assert e == pytest.approx(math.pi, rel=0.02)


def test_sun_errors():
    with pytest.raises(ViewError, match="sun direction"):
        sun_environment((0, 0, 0))
    with pytest.raises(ViewError, match="even number"):
        sun_environment((0, 1, 0), width=7)
    with pytest.raises(ViewError, match=r"\(H, W, 3\)"):
        write_hdr("x.hdr", np.zeros((4, 4)))


def test_model_viewer_orbit_reproduces_the_camera():
    cam = Camera(position=(1.0, 2.0, 3.0), look_at=(0.5, -0.5, 0.25), fov_deg=30.0)
    a = model_viewer_attributes(cam)
    theta, phi, r = (float(x.rstrip("degm")) for x in a["camera-orbit"].split())
    t, p = math.radians(theta), math.radians(phi)
    # model-viewer's spherical position about the target: (r sinφ sinθ, r cosφ, r sinφ cosθ)
    pos = np.array([r * math.sin(p) * math.sin(t), r * math.cos(p), r * math.sin(p) * math.cos(t)]) + cam.look_at
    assert np.allclose(pos, cam.position, atol=1e-4)
    assert a["field-of-view"] == "30deg" and a["camera-target"] == "0.5m -0.5m 0.25m"
    assert float(a["max-camera-orbit"].split()[2].rstrip("m")) > r


def test_models_js_embeds_data_uris(tmp_path):
    glb = tmp_path / "a.glb"
    glb.write_bytes(b"glTF1234")
    text = models_js({"baked": glb}, None)
    assert '"baked": "data:model/gltf-binary;base64,Z2xURjEyMzQ="' in text and "NEURAL_BAKE_ENV = null" in text
