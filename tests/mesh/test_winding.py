"""Generalised winding numbers: solid angles, inside/outside, the accelerated sum against the exact one."""

import math

import numpy as np
import pytest
import trimesh

from neural_bake.fit.sampling import sample_near, signed_distance
from neural_bake.mesh import winding as S
from neural_bake.mesh.winding import winding_number
from neural_bake.types import Mesh

R = 0.9


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=3, radius=R)  # 1280 faces
    return Mesh(np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64))


@pytest.fixture(scope="module")
def open_sphere(sphere):
    c = sphere.triangles.mean(1)
    keep = c[:, 2] < 0.8  # remove the cap above z = 0.8: a hole of radius ~0.4
    return Mesh(sphere.vertices, sphere.faces[keep], watertight=False)


def test_solid_angle_of_an_octant_is_pi_over_2():
    import torch

    tri = torch.tensor([[[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]], dtype=torch.float64)
    origin = torch.zeros(1, 3, dtype=torch.float64)
    np.testing.assert_allclose(S._solid_angles(origin, tri).numpy(), [[math.pi / 2]], rtol=1e-12)
    # the other winding is seen from the front: negative
    np.testing.assert_allclose(S._solid_angles(origin, tri.flip(1)).numpy(), [[-math.pi / 2]], rtol=1e-12)
    # float32 agrees
    np.testing.assert_allclose(S._solid_angles(origin.float(), tri.float()).numpy(), [[math.pi / 2]], rtol=1e-6)


def test_winding_number_is_one_inside_zero_outside(sphere, rng):
    p = rng.uniform(-1.3, 1.3, (400, 3))
    r = np.linalg.norm(p, axis=1)
    clear = np.abs(r - R) > 0.05
    w = winding_number(sphere, p[clear], exact=True)
    np.testing.assert_allclose(w, (r[clear] < R).astype(float), atol=1e-9)


def test_fast_winding_number_agrees_with_the_exact_sum(open_sphere, rng):
    p = np.concatenate([rng.uniform(-1.3, 1.3, (1500, 3)), sample_near(open_sphere, 500, sigma=0.01, seed=2).points])
    exact = winding_number(open_sphere, p, exact=True)
    fast = winding_number(open_sphere, p)
    np.testing.assert_array_equal(fast > 0.5, exact > 0.5)
    assert np.abs(fast - exact).max() < 0.05
    # the accelerated path really ran (mesh larger than the exact-only threshold)
    assert open_sphere.n_faces > 4 * S.CLUSTER_SIZE
    assert np.abs(S._fast_winding(__import__("torch").from_numpy(p), open_sphere.triangles).numpy() - exact).max() < 0.1


def test_flipped_winding_flips_the_winding_number(sphere, rng):
    flipped = Mesh(sphere.vertices, sphere.faces[:, ::-1].copy(), watertight=False)
    p = rng.uniform(-1, 1, (500, 3))
    w = winding_number(sphere, p, exact=True)
    np.testing.assert_allclose(winding_number(flipped, p, exact=True), -w, atol=1e-9)
    # the accelerated sum flips too, up to its approximation (ties may group the faces differently)
    np.testing.assert_allclose(winding_number(flipped, p), -winding_number(sphere, p), atol=0.02)
    # an inward-wound mesh has w = -1 inside: nothing is inside it
    inside = np.linalg.norm(p, axis=1) < R - 0.05
    assert inside.sum() > 100 and (signed_distance(flipped, p[inside], sign="winding") > 0).all()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_matrix_form_winding_equals_the_direct_formula(rng, dtype):
    import torch

    tri = rng.normal(size=(60, 3, 3)).astype(dtype)
    p = rng.normal(size=(40, 3)).astype(dtype)
    direct = S._solid_angles(torch.from_numpy(p).double(), torch.from_numpy(tri).double()).sum(1) / (4 * math.pi)
    fast = S._exact_winding(torch.from_numpy(p), torch.from_numpy(tri))  # computes in float64 whatever the input
    assert fast.dtype == torch.float64
    np.testing.assert_allclose(fast.numpy(), direct.numpy(), atol=1e-10)
    # the direct formula in float32 agrees to float32 accuracy
    d32 = S._solid_angles(torch.from_numpy(p).float(), torch.from_numpy(tri).float()).sum(1) / (4 * math.pi)
    np.testing.assert_allclose(d32.numpy(), direct.numpy(), atol=1e-4)
