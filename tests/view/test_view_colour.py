"""The colour comparison: source texture and baked albedo at the same surface points, through both UV layouts."""

import numpy as np
import pytest

from neural_bake.io.colour import linear_to_srgb, srgb_to_linear
from neural_bake.types import Frame, Mesh
from neural_bake.view.colour import colour_error, colour_heat, compare_colours
from neural_bake.view.meshes import ViewError, ViewMesh


def _plane(flip_u: bool):
    """A unit square in z = 0 (two triangles), UVs (x, y) or (1 − x, y)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    uv = v[f][..., :2].copy()
    if flip_u:
        uv[..., 0] = 1 - uv[..., 0]
    return v, f, uv


def _gradient(n: int) -> np.ndarray:
    """An (n, n, 3) linear texture whose sRGB values are linear in the pixel position (exact under bilinear)."""
    x = (np.arange(n) + 0.5) / n
    srgb = np.stack(np.broadcast_arrays(x[None, :], x[::-1, None], np.full((n, n), 0.5)), axis=2)
    return srgb_to_linear(0.1 + 0.8 * srgb).astype(np.float32)


def _source(tex):
    v, f, uv = _plane(False)
    return Mesh(vertices=v, faces=f, uv=uv, texture=tex, vertex_normals=np.tile([0.0, 0, 1], (4, 1)), frame=Frame())


def _baked(albedo, flip_u=True):
    v, f, uv = _plane(flip_u)
    t = np.tile([-1.0 if flip_u else 1.0, 0, 0, 1], (4, 1))
    return ViewMesh(v, f, uv=uv, texture=albedo, vertex_normals=np.tile([0.0, 0, 1], (4, 1)), tangents=t)


def test_a_bake_of_its_own_texture_through_another_uv_layout_has_no_error():
    tex = _gradient(32)
    # the bake's layout mirrors u: the same surface point's texel is the source texel mirrored left-right
    cmp = compare_colours(_baked(tex[:, ::-1].copy()), _source(tex))
    assert cmp.coverage.mean() > 0.9
    assert cmp.stats["max"] < 0.05 and cmp.stats["count"] == cmp.coverage.sum()
    # read the wrong way (no mirror), the same maps disagree: the check can fail
    assert compare_colours(_baked(tex[:, ::-1].copy(), flip_u=False), _source(tex)).stats["median"] > 10


def test_a_known_colour_shift_gives_the_known_error():
    tex = _gradient(32)
    shifted = srgb_to_linear(linear_to_srgb(tex[:, ::-1]) + np.array([12, -6, 0]) / 255).astype(np.float32)
    cmp = compare_colours(_baked(shifted), _source(tex))
    assert cmp.stats["median"] == pytest.approx(6.0, abs=0.05)  # mean of |12|, |−6|, 0 levels
    assert cmp.stats["max"] == pytest.approx(6.0, abs=0.05)


def test_colour_error_and_heat():
    a = np.full((2, 2, 3), 0.2)
    assert colour_error(a, a).max() == 0
    b = srgb_to_linear(linear_to_srgb(a) + 30 / 255)
    assert colour_error(a, b) == pytest.approx(np.full((2, 2), 30.0))
    heat = colour_heat(np.array([[0.0, 64.0]]), np.array([[True, True]]))
    assert heat[0, 0].tolist() == [0, 0, 0] and heat[0, 1].tolist() == [1, 1, 1]
    with pytest.raises(ViewError, match="one shape"):
        colour_error(a, a[..., :2])


def test_compare_colours_needs_both_textures():
    tex = _gradient(8)
    with pytest.raises(ViewError, match="no texture"):
        compare_colours(_baked(tex), _source(None))
    v, f, uv = _plane(False)
    with pytest.raises(ViewError, match="no baked albedo"):
        compare_colours(ViewMesh(v, f, vertex_normals=np.tile([0.0, 0, 1], (4, 1))), _source(tex))
