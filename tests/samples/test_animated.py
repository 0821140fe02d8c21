"""Animated samples: the analytic SDF and normals at every t agree with finite differences and with the
frames' meshes; the splitting sphere changes topology; frames are written as numbered OBJ files."""

import json

import numpy as np
import pytest
import trimesh

import neural_bake as nb
from neural_bake.errors import NeuralBakeError
from neural_bake.samples import (ANIMATED, FRAMES_FILE, BumpySphere, SplittingSphere, Torus, TravellingBumps,
                                 TwistingTorus, generate, get_animation, write_animation)


def _on_surface(anim, t, n=400, seed=0):
    """Points of the smooth surface at t: frame vertices moved by Newton steps along the exact normal."""
    m = anim.mesh(t, 2000)
    rng = np.random.default_rng(seed)
    p = m.vertices[rng.choice(len(m.vertices), n, replace=False)]
    for _ in range(4):
        p = p - anim.sdf(p, t)[:, None] * anim.normal(p, t)
    return p


@pytest.mark.parametrize("name", list(ANIMATED))
@pytest.mark.parametrize("t", [0.0, 0.4, 1.0])
def test_normal_is_the_normalised_gradient_of_the_sdf_at_every_t(name, t, fd_gradient):
    anim = ANIMATED[name]
    p = _on_surface(anim, t)
    assert np.abs(anim.sdf(p, t)).max() < 1e-9
    g = fd_gradient(lambda q: anim.sdf(q, t), p)
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    cos = (g * anim.normal(p, t)).sum(1)
    if name == "splitting_sphere" and 0 < t < 1:  # the crease where the balls meet is a kink of the sdf
        assert np.mean(cos > 1 - 1e-6) > 0.97
    else:
        assert cos.min() > 1 - 1e-6


@pytest.mark.parametrize("name", list(ANIMATED))
def test_frame_vertices_lie_on_the_analytic_surface(name):
    anim = ANIMATED[name]
    for t in (0.0, 0.5, 1.0):
        m = anim.mesh(t, 3000)
        assert np.abs(anim.sdf(m.vertices, t)).max() < 1e-7
        tri = m.vertices[m.faces]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        # outward winding: face normals agree with the analytic normals at the face centres
        assert np.mean((fn * anim.normal(tri.mean(1), t)).sum(1) > 0) > 0.99


def test_travelling_bumps_turn_into_dents_and_start_as_the_bumpy_sphere():
    anim = TravellingBumps()
    rng = np.random.default_rng(1)
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    base = BumpySphere()
    np.testing.assert_allclose(anim.at(0.0).surface_radius(d), base.surface_radius(d), atol=1e-12)
    # half a period of the x factor: h(d, 1) = -h(d, 0)
    np.testing.assert_allclose(anim.at(1.0).surface_radius(d) - base.radius,
                               -(base.surface_radius(d) - base.radius), atol=1e-12)
    # the bumps move: halfway the shape is neither end
    mid = anim.at(0.5).surface_radius(d)
    assert np.abs(mid - base.surface_radius(d)).max() > 0.02


def test_twisting_torus_is_the_torus_at_t0_and_a_diffeomorphic_twist_later():
    anim = TwistingTorus()
    m0, m1 = anim.mesh(0.0, 800), anim.mesh(1.0, 800)
    base = Torus().mesh(800, 8)
    np.testing.assert_allclose(m0.vertices, base.vertices, atol=1e-12)
    assert np.array_equal(m1.faces, m0.faces)
    assert np.abs(m1.vertices - m0.vertices).max() > 0.2  # it moved
    # x is kept and the distance to the x axis too (a rotation about x)
    np.testing.assert_allclose(m1.vertices[:, 0], m0.vertices[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.hypot(*m1.vertices[:, 1:].T), np.hypot(*m0.vertices[:, 1:].T), atol=1e-12)
    # sign of the first-order sdf is exact: points pushed out along the normal are outside
    p = _on_surface(anim, 1.0)
    n = anim.normal(p, 1.0)
    assert (anim.sdf(p + 0.02 * n, 1.0) > 0).all() and (anim.sdf(p - 0.02 * n, 1.0) < 0).all()


def test_splitting_sphere_changes_topology_and_vertex_count():
    anim = SplittingSphere()
    counts, bodies = [], []
    for t in (0.0, 0.5, 1.0):
        m = anim.mesh(t, 2000)
        tm = trimesh.Trimesh(m.vertices, m.faces, process=True)
        counts.append(len(m.vertices))
        bodies.append(len(tm.split(only_watertight=False)))
    assert bodies == [1, 1, 2]
    assert len(set(counts)) == 3
    # exact outside: distance from a far point is the distance to the nearer ball
    centres, r = anim.centres_radius(1.0)
    np.testing.assert_allclose(anim.sdf(np.array([[3.0, 0, 0]]), 1.0), 3.0 - centres[0, 0] - r)


def test_splitting_sphere_colours_travel_with_each_ball():
    anim = SplittingSphere()
    d = np.random.default_rng(0).normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[d[:, 0] > 0.2]  # the +x ball's outer half: nearer its own centre at every t
    ref = anim.albedo(d * anim.r0, 0.0)  # t = 0: one sphere at the origin
    assert ref.min() >= 0.1 and ref.max() <= 0.8
    for t in (0.5, 1.0):
        centres, r = anim.centres_radius(t)
        # the same direction from the moving centre has the same colour, at any distance from it
        np.testing.assert_allclose(anim.albedo(centres[0] + d * r, t), ref, atol=1e-12)
        np.testing.assert_allclose(anim.albedo(centres[0] + d * 1.2 * r, t), ref, atol=1e-12)
        # the mirrored ball carries the mirrored pattern: x flipped
        np.testing.assert_allclose(anim.albedo(centres[1] + d * [-1, 1, 1] * r, t),
                                   anim.albedo(d * [-1, 1, 1] * anim.r0, 0.0), atol=1e-12)


def test_write_animation_numbered_frames_and_index(tmp_path):
    anim = SplittingSphere()
    folder = write_animation(anim, tmp_path, times=[0.0, 0.5, 1.0], resolution=800)
    index = json.loads((folder / FRAMES_FILE).read_text())
    assert index["times"] == [0.0, 0.5, 1.0] and index["sdf_kind"] == "exact outside"
    assert index["frames"] == [f"splitting_sphere_{k:04d}.obj" for k in range(3)]
    for t, f in zip(index["times"], index["frames"]):
        mesh = nb.load_mesh(folder / f)
        assert mesh.watertight and mesh.uv is None
        src = mesh.frame.to_source(mesh.vertices)
        assert np.abs(anim.sdf(src, t)).max() < 2e-6  # 6 decimals in the file


def test_generate_writes_animations_with_static_samples(tmp_path):
    written = generate(tmp_path, ["sphere", "twisting_torus"], resolution=200, texture_size=16)
    assert written["sphere"] == tmp_path / "sphere.obj"
    assert written["twisting_torus"] == tmp_path / "twisting_torus" and written["twisting_torus"].is_dir()
    assert len(list((tmp_path / "twisting_torus").glob("twisting_torus_*.obj"))) == len(TwistingTorus().times)


def test_errors():
    with pytest.raises(NeuralBakeError, match=r"unknown animation 'wobble' \(known: travelling_bumps"):
        get_animation("wobble")
    with pytest.raises(ValueError, match="t must be a finite number"):
        TwistingTorus().sdf(np.zeros((1, 3)), float("nan"))
    with pytest.raises(NeuralBakeError, match="unknown sample 'wobble'"):
        generate("unused", ["wobble"])
