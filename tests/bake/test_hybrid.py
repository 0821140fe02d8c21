"""Hybrid bake: unfaithful texels take the classical mesh-to-mesh normal; faithful fields keep ∇f everywhere."""

import numpy as np
import pytest
import trimesh

from neural_bake.bake.baker import Baker
from neural_bake.bake.baseline import baseline_bake
from neural_bake.fields import SdfField
from neural_bake.bake.hybrid import HybridFallback, unfaithful
from neural_bake.errors import NeuralBakeError
from neural_bake.mesh.unwrap import unwrap
from neural_bake.types import Mesh

R = 0.7


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


def ico(sub, radius=R):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=radius)
    return Mesh(vertices=np.asarray(m.vertices, dtype=np.float64), faces=np.asarray(m.faces, dtype=np.int64))


def thin_box():
    """A thin plank 1.6 x 0.08 x 0.6 subdivided so its vertex normals are the faces' away from the edges."""
    b = trimesh.creation.box(extents=(1.6, 0.08, 0.6))
    for _ in range(3):
        b = b.subdivide()
    return Mesh(vertices=np.asarray(b.vertices, dtype=np.float64), faces=np.asarray(b.faces, dtype=np.int64))


def sphere_field(radius=R):
    return SdfField(lambda p: p.norm(dim=1) - radius)


def test_unfaithful_reasons_and_nan():
    n = np.array([[0, 0, 1.0]] * 5)
    tilt = lambda deg: np.array([np.sin(np.radians(deg)), 0, np.cos(np.radians(deg))])  # noqa: E731
    src = np.stack([tilt(0), tilt(19.9), tilt(20.1), tilt(0), tilt(0)])
    f = np.array([0.0, 0.0, 0.0, 0.0101, np.nan])
    valid = np.array([True, True, True, True, True])
    why = unfaithful(f, n, src, valid, sdf_tol=0.01, angle_deg=20.0)
    assert why["mask"].tolist() == [False, False, True, True, True]
    assert why["angle"].tolist() == [False, False, True, False, False]
    assert why["sdf"].tolist() == [False, False, False, True, True]
    valid[0] = False
    why = unfaithful(f, n, src, valid, sdf_tol=0.01, angle_deg=20.0)
    assert why["mask"][0] and why["invalid"][0] and not why["angle"][0]


@pytest.mark.parametrize("kwargs, message", [({"sdf_tol": 0.0}, "sdf_tol"), ({"sdf_tol": float("nan")}, "sdf_tol"),
                                             ({"angle_deg": 0.0}, "angle_deg"), ({"angle_deg": 181.0}, "angle_deg")])
def test_bad_thresholds_raise(kwargs, message):
    with pytest.raises(NeuralBakeError, match=message):
        HybridFallback(ico(1), sphere_field(), **kwargs)


def test_faithful_field_replaces_nothing():
    """The exact sphere SDF against a finely tessellated sphere: every texel keeps ∇f."""
    coarse = unwrap(ico(2), resolution=128)
    baker = Baker(coarse, 64)
    hybrid = HybridFallback(ico(5), sphere_field())
    res = baker.bake(sphere_field(), hybrid=hybrid)
    assert res.stats["hybrid_texels"] == 0 and res.stats["hybrid_samples"] == 0 and not res.hybrid.any()
    assert not res.replaced.any() and np.array_equal(res.normals, res.neural)
    assert hybrid.counts["samples"] == len(res.normals) > 1000
    s = hybrid.summary()
    assert s["replaced"] == 0 and s["f_at_source"]["max"] < 2e-3  # the fine sphere lies on the field's surface


def test_poor_field_takes_the_baseline_normals():
    """A sphere SDF as the field of a thin plank: wherever it is off, the texel holds the classical normal."""
    plank = thin_box()
    coarse = unwrap(plank, resolution=128)
    baker = Baker(coarse, 64)
    hybrid = HybridFallback(plank, sphere_field(0.5), keep_baseline=True)
    res = baker.bake(sphere_field(0.5), hybrid=hybrid)
    base = baseline_bake(baker.mesh, plank, baker.texels)
    rep = res.replaced
    assert rep.mean() > 0.9  # a sphere is nowhere near the plank's surface
    np.testing.assert_array_equal(res.normals[rep], base["normals"][rep])
    np.testing.assert_array_equal(res.normals[~rep], res.neural[~rep])
    # no sample further than the angle threshold from the source mesh's normal where the rays land
    assert angle_deg(res.normals, base["normals"]).max() <= hybrid.angle_deg + 1e-6
    # the classical bake the hybrid kept is the one it used (the report reuses it)
    np.testing.assert_array_equal(hybrid.baseline()["normals"], base["normals"])
    assert res.stats["hybrid_texels"] == int(res.hybrid.sum()) and res.hybrid[~res.coverage].sum() == 0
    assert 0.9 < res.stats["hybrid_fraction"] <= 1.0
    s = hybrid.summary()
    assert s["replaced"] == rep.sum() and s["sdf"] > 0 and s["samples"] == len(rep)


def test_streamed_hybrid_matches_cached():
    plank = thin_box()
    coarse = unwrap(plank, resolution=128)
    field = sphere_field(0.5)
    cached = Baker(coarse, 48).bake(field, hybrid=HybridFallback(plank, field))
    streamed = Baker(coarse, 48, cache_texels=False, band_samples=400).bake(
        field, hybrid=HybridFallback(plank, field), report_samples=500)
    np.testing.assert_array_equal(cached.hybrid, streamed.hybrid)
    np.testing.assert_allclose(cached.normal_map, streamed.normal_map, atol=1e-6)
    smp = streamed.sample
    assert smp.replaced is not None and len(smp.replaced) == 500
    np.testing.assert_array_equal(smp.replaced, cached.replaced[smp.index])


def test_field_frame_is_honoured():
    """A field living in another unit frame (scale 2) is evaluated at the converted source points."""
    from neural_bake.types import Frame

    coarse = unwrap(ico(2), resolution=128)
    frame2 = Frame((0.0, 0.0, 0.0), 2.0)
    field = SdfField(lambda p: p.norm(dim=1) - 2 * R, frame=frame2)
    hybrid = HybridFallback(ico(5), field)
    Baker(coarse, 32).bake(field, hybrid=hybrid)
    assert hybrid.counts["replaced"] == 0 and hybrid.summary()["f_at_source"]["max"] < 4e-3
