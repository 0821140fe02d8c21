"""The pinhole camera: pixel-centre rays, row 0 on top, framing, frames and orbits, and its errors."""

import math

import numpy as np
import pytest
import torch

from neural_bake.render.camera import Camera, CameraError
from neural_bake.types import Frame


def test_basis_is_right_handed_and_orthonormal():
    cam = Camera(position=(1.0, 2.0, 3.0), look_at=(0.0, 0.5, -1.0), up=(0.0, 1.0, 0.2))
    r, u, f = cam.basis()
    m = np.stack([r, u, f])
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.cross(r, u), -f, atol=1e-12)  # OpenGL: the camera looks down -Z
    assert u @ np.array([0.0, 1.0, 0.2]) > 0


def test_single_pixel_ray_is_the_view_direction():
    cam = Camera(position=(0.0, 0.0, 5.0), width=1, height=1)
    o, d = cam.rays(dtype=torch.float64)
    np.testing.assert_allclose(d.numpy(), [[0.0, 0.0, -1.0]], atol=1e-12)
    np.testing.assert_allclose(o.numpy(), [[0.0, 0.0, 5.0]])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_rays_through_pixel_centres_row_zero_on_top(dtype):
    cam = Camera(position=(0.0, 0.0, 4.0), fov_deg=60.0, width=4, height=2)
    o, d = cam.rays(dtype=dtype)
    assert o.dtype == dtype and d.dtype == dtype and d.shape == (8, 3)
    np.testing.assert_allclose(d.norm(dim=-1).numpy(), 1.0, atol=1e-6)
    grid = d.reshape(2, 4, 3).double().numpy()
    assert np.all(grid[0, :, 1] > 0) and np.all(grid[1, :, 1] < 0)  # top row looks up
    assert np.all(np.diff(grid[0, :, 0]) > 0)  # columns run left to right
    # the centre of pixel (row 0) sits at a quarter of the vertical half-extent: y/z = tan(30°)/2
    np.testing.assert_allclose(grid[0, 0, 1] / -grid[0, 0, 2], math.tan(math.radians(30)) / 2, rtol=1e-6)
    # square pixels: column 0's x offset is 3/4 of the horizontal half-extent (aspect 2)
    np.testing.assert_allclose(grid[0, 0, 0] / -grid[0, 0, 2], -0.75 * 2 * math.tan(math.radians(30)), rtol=1e-6)


def test_project_inverts_rays():
    cam = Camera(position=(0.3, 1.0, 3.0), look_at=(0.0, 0.1, 0.0), fov_deg=45.0, width=7, height=5)
    d = cam.pixel_directions()
    pts = np.asarray(cam.position) + 2.5 * d.reshape(-1, 3)
    pix, depth = cam.project(pts)
    rows, cols = np.mgrid[0:5, 0:7]
    np.testing.assert_allclose(pix[:, 0], cols.ravel() + 0.5, atol=1e-9)
    np.testing.assert_allclose(pix[:, 1], rows.ravel() + 0.5, atol=1e-9)
    assert np.all(depth > 0)


def test_framing_keeps_the_box_in_view():
    lo, hi = (-2.0, 0.0, -1.0), (4.0, 3.0, 1.0)
    cam = Camera.framing(lo, hi, direction=(1.0, 0.5, 2.0), width=64, height=48)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pix, depth = cam.project(corners)
    assert np.all(depth > 0)
    assert np.all((pix[:, 0] >= 0) & (pix[:, 0] <= 64) & (pix[:, 1] >= 0) & (pix[:, 1] <= 48))
    np.testing.assert_allclose(cam.look_at, [1.0, 1.5, 0.0])


def test_unit_frame_and_orbit():
    frame = Frame(center=(10.0, 0.0, 0.0), scale=0.5)
    cam = Camera(position=(10.0, 0.0, 4.0), look_at=(10.0, 0.0, 0.0))
    unit = cam.in_unit_frame(frame)
    np.testing.assert_allclose(unit.position, [0.0, 0.0, 2.0])
    np.testing.assert_allclose(unit.look_at, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(unit.pixel_directions(), cam.pixel_directions(), atol=1e-12)
    quarter = cam.orbit(90.0)
    np.testing.assert_allclose(quarter.position, [14.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(cam.orbit(360.0).position, cam.position, atol=1e-12)


def test_dict_round_trip():
    cam = Camera(position=(1.0, 2.0, 3.0), fov_deg=30.0, width=10, height=20)
    assert Camera.from_dict(cam.to_dict()) == cam


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"position": (0.0, 0.0, 0.0)}, "coincide"),
        ({"up": (0.0, 0.0, 1.0)}, "parallel"),
        ({"up": (0.0, 0.0, 0.0)}, "zero vector"),
        ({"fov_deg": 0.0}, "fov_deg"),
        ({"fov_deg": 180.0}, "fov_deg"),
        ({"fov_deg": "wide"}, "fov_deg"),
        ({"width": 0}, "width"),
        ({"height": 2.5}, "height"),
        ({"position": (0.0, math.nan, 1.0)}, "position"),
        ({"look_at": (1.0, 2.0)}, "look_at"),
    ],
)
def test_bad_cameras_are_refused_in_one_line(kwargs, match):
    with pytest.raises(CameraError, match=match) as info:
        Camera(**kwargs)
    assert "\n" not in str(info.value)


def test_unknown_key_and_bad_framing():
    with pytest.raises(CameraError, match="unknown key 'zoom'"):
        Camera.from_dict({"zoom": 2})
    with pytest.raises(CameraError, match="above its upper corner"):
        Camera.framing((1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
