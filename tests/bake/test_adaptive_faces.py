"""The face pass of adaptive evaluation: within the tolerance of a direct evaluation on analytic fields, exact
on linear ones, stopped by its probe where the fields vary too fast, decision points within the hybrid's reach,
(the pass inside a real bake: tests/bake/test_adaptive.py)."""

import numpy as np
import pytest

from neural_bake.bake import adaptive_faces as af
from neural_bake.bake.adaptive import AdaptiveOptions
from neural_bake.bake.adaptive_faces import FaceGeometry, face_pass

from neural_bake.geometry import angular_error as angle_deg

#: One face in space and on the sample grid: 3-D corners and UV corners (sample-grid positions).
CORNERS = np.array([[[0.1, -0.2, 0.3], [0.6, -0.1, 0.35], [0.2, 0.4, 0.1]]])
GRID_UV = np.array([[0.0, 0.0], [96.0, 8.0], [20.0, 90.0]])


def one_face(rng, n=4000):
    """Random barycentrics in the face, with samples on its edges and corners (hard cases)."""
    b = rng.dirichlet(np.ones(3), size=n)
    b[:30] = np.eye(3)[rng.integers(0, 3, 30)]  # corners
    t = rng.random(60)
    b[30:90] = np.stack([t, 1 - t, np.zeros(60)], axis=1)[:, rng.permutation(3)]  # edges
    pts = np.einsum("nk,kd->nd", b, CORNERS[0])
    side = np.sqrt(((GRID_UV - np.roll(GRID_UV, 1, axis=0)) ** 2).sum(axis=1)).max()
    return b, pts, FaceGeometry(corners=CORNERS, side=np.array([side]))


def sphere_field(center, radius, dtype=np.float64):
    def evaluate(p, face=None):
        p = np.asarray(p, dtype=np.float64)
        d = p - center
        r = np.linalg.norm(d, axis=1)
        return {"values": (r - radius).astype(dtype).astype(np.float64),
                "normals": (d / r[:, None]).astype(dtype).astype(np.float64),
                "valid": np.ones(len(p), dtype=bool), "colors": None}
    return evaluate


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_smooth_field_is_interpolated_within_the_tolerance(rng, dtype):
    b, pts, geom = one_face(rng)
    field = sphere_field(np.array([0.3, 0.1, -1.2]), 1.0, dtype)
    calls = []
    opt = AdaptiveOptions()
    res = face_pass(np.arange(len(b)), np.zeros(len(b), dtype=np.int64), b, pts, geom,
                    lambda p, f: calls.append(len(p)) or field(p), tolerance_deg=opt.tolerance_deg,
                    value_tol=opt.value_tol, color_tol=opt.color_tol)
    done = res["done"]
    exact = field(pts)
    assert done.mean() > 0.9 and res["nodes"] == sum(calls) < 0.1 * len(b)  # it saves evaluations
    assert angle_deg(res["normals"][done], exact["normals"][done]).max() <= opt.tolerance_deg
    assert np.abs(res["values"][done] - exact["values"][done]).max() <= opt.value_tol
    assert res["decide"].sum() >= res["accepted"] and not res["decide"][~done].any()


def test_linear_field_is_interpolated_exactly(rng):
    b, pts, geom = one_face(rng)
    n = np.array([0.2, -0.3, 0.9])
    n /= np.linalg.norm(n)

    def plane(p, face=None):
        return {"values": p @ n - 0.05, "normals": np.repeat(n[None], len(p), axis=0),
                "valid": np.ones(len(p), dtype=bool), "colors": np.stack([p[:, 0], 2 * p[:, 1] + 0.5], axis=1)}

    res = face_pass(np.arange(len(b)), np.zeros(len(b), dtype=np.int64), b, pts, geom, plane, tolerance_deg=0.5,
                    value_tol=5e-3, color_tol=1e-3)
    exact = plane(pts)
    first_level = int(np.ceil(np.log2(geom.side[0] / af.FACE_START_SIDE)))
    assert res["done"].all() and res["accepted"] == (1 << first_level) ** 2  # every sub-triangle of the first level
    assert np.abs(res["normals"] - exact["normals"]).max() < 1e-12
    assert np.abs(res["values"] - exact["values"]).max() < 1e-12
    assert np.abs(res["colors"] - exact["colors"]).max() < 1e-12


def test_each_node_is_evaluated_with_its_own_face(rng):
    """A field reading a per-face input (the normal of a colour field with normal inputs) gets each node's face:
    colours that are the face's index come out as that index on every interpolated sample."""
    b, pts, geom = one_face(rng)
    two = FaceGeometry(corners=np.concatenate([CORNERS, CORNERS]), side=np.concatenate([geom.side, geom.side]))
    face = np.ones(len(b), dtype=np.int64)
    seen = []

    def by_face(p, f):
        seen.append(np.asarray(f))
        return {"values": np.zeros(len(p)), "normals": np.repeat([[0.0, 0.0, 1.0]], len(p), axis=0),
                "valid": np.ones(len(p), dtype=bool), "colors": np.asarray(f, dtype=np.float64)[:, None] * [1.0, 2.0]}

    res = face_pass(np.arange(len(b)), face, b, pts, two, by_face, tolerance_deg=0.5, value_tol=5e-3, color_tol=1e-3)
    assert res["done"].any() and np.concatenate(seen).tolist() == [1] * sum(len(s) for s in seen)
    assert np.abs(res["colors"][res["done"]] - [1.0, 2.0]).max() < 1e-12


def test_a_rough_field_stops_the_pass_after_its_probe(rng):
    b, pts, geom = one_face(rng, n=20000)

    def rough(p, face=None):
        g = np.stack([40 * np.cos(400 * p[:, 0]), 40 * np.sin(300 * p[:, 1]), np.ones(len(p))], axis=1)
        return {"values": 0.1 * np.sin(400 * p[:, 0]), "normals": g / np.linalg.norm(g, axis=1, keepdims=True),
                "valid": np.ones(len(p), dtype=bool), "colors": None}

    res = face_pass(np.arange(len(b)), np.zeros(len(b), dtype=np.int64), b, pts, geom, rough, tolerance_deg=0.5,
                    value_tol=5e-3, color_tol=1e-3)
    # the probe tests every FACE_PROBE_STRIDE-th sub-triangle of the first level (at most six nodes each)
    first_level = int(np.ceil(np.log2(geom.side[0] / af.FACE_START_SIDE)))
    sub_triangles = (1 << first_level) ** 2
    assert res["done"].sum() < res["nodes"] <= 6 * -(-sub_triangles // af.FACE_PROBE_STRIDE)


def test_decision_points_lie_within_the_hybrids_reach(rng):
    b, pts, geom = one_face(rng, n=6000)
    res = face_pass(np.arange(len(b)), np.zeros(len(b), dtype=np.int64), b, pts, geom,
                    sphere_field(np.array([0.0, 0.0, -0.5]), 0.4), tolerance_deg=0.5, value_tol=5e-3, color_tol=1e-3)
    grid = b @ GRID_UV
    done, decide = res["done"], res["decide"]
    assert done.any() and decide.any()
    d = np.linalg.norm(grid[done][:, None] - grid[decide][None], axis=2).min(axis=1)
    assert d.max() <= af.FACE_START_SIDE


def test_a_mesh_beyond_the_packed_face_index_is_left_to_evaluation(rng):
    b, pts, geom = one_face(rng, n=500)
    many = FaceGeometry(corners=np.broadcast_to(CORNERS[0], (af._MAX_FACES + 1, 3, 3)),
                        side=np.broadcast_to(geom.side, (af._MAX_FACES + 1,)))
    face = np.full(len(b), af._MAX_FACES, dtype=np.int64)
    res = face_pass(np.arange(len(b)), face, b, pts, many, lambda p, f: pytest.fail("evaluated"), tolerance_deg=0.5,
                    value_tol=5e-3, color_tol=1e-3)
    assert not res["done"].any() and res["nodes"] == 0


@pytest.mark.parametrize("n,groups", [(0, 1), (1, 1), (7, 3), (2000, 1), (2000, 50), (5000, 4000)])
def test_group_argmax_is_the_lexsort_choice(n, groups):
    # per group, the position of the largest score, the first of ties (scores rounded to force them): what
    # np.lexsort((-score, groups)) puts first in each group, in the same order
    from neural_bake.bake.adaptive_faces import group_argmax

    rng = np.random.default_rng(n + groups)
    t = rng.integers(0, groups, n)
    scores = [rng.random(n), np.round(rng.random(n), 1), np.zeros(n), -np.abs(rng.random(n) - 1 / 3)]
    for score, got in zip(scores, group_argmax(t, scores)):
        order = np.lexsort((-score, t))
        first = np.ones(len(order), dtype=bool)
        first[1:] = t[order][1:] != t[order][:-1]
        np.testing.assert_array_equal(got, order[first])
