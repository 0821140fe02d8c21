"""Orthographic ray-cast views of a mesh: hit points on the surface, the disc's share of the image."""

import math

import numpy as np
import pytest
import trimesh

from neural_bake.mesh.views import render_views
from neural_bake.types import Mesh

R = 0.9


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=3, radius=R)  # facets within 1 % of the sphere
    return Mesh(np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64))


def test_render_views_hit_the_sphere_where_expected(sphere):
    res = 48
    views = render_views(sphere, n_views=4, resolution=res)
    assert len(views) == 4
    for v in views:
        r = np.linalg.norm(v["points"], axis=1)
        assert r.max() <= R + 1e-5 and r.min() > R * 0.98  # on the inscribed facets
        # orthographic image of side 2: the disc of radius ~R covers π R² / 4 of it
        frac = len(v["pixels"]) / res**2
        assert frac == pytest.approx(math.pi * R * R / 4, rel=0.05)
        assert np.allclose(v["bary"].sum(axis=1), 1.0) and (v["bary"] >= -1e-6).all()
