"""Buried faces: the parts of a mesh's shells inside another shell, against boxes and spheres whose answer is known."""

import math

import numpy as np
import pytest
import trimesh

from neural_bake.fit.sampling import inside_mask, sample_surface, signed_distance, surface_faces
from neural_bake.mesh.shells import buried_faces, shell_labels
from neural_bake.types import Mesh


def _box(lo, hi, subdivisions=2):
    """A closed box [lo, hi] split so that quarter lines of each side are edges (no face straddles them)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    for _ in range(subdivisions):
        m = m.subdivide()
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def _join(*parts, watertight=True):
    verts, faces, off = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + off)
        off += len(v)
    return Mesh(np.concatenate(verts), np.concatenate(faces), watertight=watertight)


def _strictly_inside(p, lo, hi):
    return np.all((p > np.asarray(lo) + 1e-9) & (p < np.asarray(hi) - 1e-9), axis=1)


# A = [-0.75, 0.25] x [-0.5, 0.5]^2 and B = [-0.25, 0.75] x [-0.25, 0.25]^2 overlap in [-0.25, 0.25] x [-0.25, 0.25]^2;
# their union's boundary is everything but A's faces inside B and B's inside A
A_LO, A_HI = (-0.75, -0.5, -0.5), (0.25, 0.5, 0.5)
B_LO, B_HI = (-0.25, -0.25, -0.25), (0.75, 0.25, 0.25)


@pytest.fixture(scope="module")
def boxes():
    return _join(_box(A_LO, A_HI), _box(B_LO, B_HI, subdivisions=3))


def test_faces_inside_the_other_box_are_buried(boxes):
    n_a = len(_box(A_LO, A_HI)[1])
    c = boxes.triangles.mean(axis=1)
    expect = np.concatenate([_strictly_inside(c[:n_a], B_LO, B_HI), _strictly_inside(c[n_a:], A_LO, A_HI)])
    assert expect.sum() > 0 and (~expect).sum() > 0
    np.testing.assert_array_equal(buried_faces(boxes), expect)
    count, labels = shell_labels(boxes)
    assert count == 2 and np.array_equal(labels, np.repeat([0, 1], [n_a, boxes.n_faces - n_a]))


def test_the_union_distance_ignores_buried_faces(boxes):
    # the origin is in both boxes: the union's nearest boundary is B's side beyond A, e.g. (0.25, 0.25, 0)
    want = -math.sqrt(2) / 4
    for sign in ("auto", "winding"):
        np.testing.assert_allclose(signed_distance(boxes, np.zeros((1, 3)), sign=sign), [want], atol=1e-6)
    # ray parity alone reads the overlap as outside; the auto test does not use it here
    assert inside_mask(boxes, np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.4, 0.0]])).all()
    assert not inside_mask(boxes, np.array([[0.0, 0.0, 0.0]]), method="raycast")[0]


def test_surface_samples_never_lie_on_buried_faces(boxes):
    buried = buried_faces(boxes)
    s = sample_surface(boxes, 4000, seed=3, colors=False)
    assert not buried[s.face_index].any()
    idx, areas = surface_faces(boxes)
    assert not buried[idx].any() and len(idx) == int((~buried).sum())
    np.testing.assert_allclose(areas, boxes.face_areas[idx])


def test_a_cavity_is_not_buried():
    outer = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
    inner = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
    hollow = _join((np.asarray(outer.vertices), np.asarray(outer.faces)),
                   (np.asarray(inner.vertices), np.asarray(inner.faces)[:, ::-1]))  # wound inwards: a cavity
    assert not buried_faces(hollow).any()
    d = signed_distance(hollow, np.array([[0.0, 0.0, 0.0], [0.6, 0.0, 0.0]]))
    np.testing.assert_allclose(d, [0.4, -0.2], atol=0.01)  # outside in the cavity, inside in the wall


def test_the_part_of_an_open_sheet_inside_a_box_is_buried():
    box = _box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    sheet = trimesh.creation.box(extents=(2.0, 0.6, 1e-3))  # its top face, a 2 x 0.6 plane through the box
    top = sheet.faces[sheet.face_normals[:, 2] > 0.9]
    sheet = trimesh.Trimesh(sheet.vertices, top).subdivide().subdivide().subdivide()
    mesh = _join(box, (np.asarray(sheet.vertices), np.asarray(sheet.faces)), watertight=False)
    n_box = len(box[1])
    c = mesh.triangles.mean(axis=1)[n_box:]
    buried = buried_faces(mesh)
    assert not buried[:n_box].any()
    inside = np.abs(c[:, 0]) < 0.5 - 0.125
    outside = np.abs(c[:, 0]) > 0.5 + 0.01
    assert buried[n_box:][inside].all() and not buried[n_box:][outside].any()


def test_one_shell_and_degenerate_shells_bury_nothing():
    v, f = _box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    assert not buried_faces(Mesh(v, f)).any()
    # a separate zero-area face inside the box: a shell of its own, never buried, never counted
    dv = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0]])
    mesh = Mesh(np.concatenate([v, dv]), np.concatenate([f, [[len(v), len(v) + 1, len(v) + 2]]]),
                degenerate=np.r_[np.zeros(len(f), bool), True])
    assert shell_labels(mesh)[0] == 2 and not buried_faces(mesh).any()


def test_the_mask_is_kept_per_mesh_and_handed_out_as_a_copy(boxes):
    first = buried_faces(boxes)
    first[:] = False
    again = buried_faces(boxes)
    assert again.any()
    np.testing.assert_array_equal(again, buried_faces(Mesh(boxes.vertices.copy(), boxes.faces.copy())))


def test_a_shell_split_along_its_seams_is_one_shell(boxes):
    # every face with corners of its own (as an unwrap leaves a mesh): the same shells, the same buried faces
    split = Mesh(boxes.triangles.reshape(-1, 3), np.arange(3 * boxes.n_faces).reshape(-1, 3))
    assert shell_labels(split)[0] == 2
    np.testing.assert_array_equal(buried_faces(split), buried_faces(boxes))


def test_shells_that_touch_at_a_corner_are_two():
    a = trimesh.creation.box(extents=(1, 1, 1))
    b = trimesh.creation.box(extents=(1, 1, 1))
    b.apply_translation((1, 1, 1))  # b's corner (0.5, 0.5, 0.5) is a's
    mesh = _join((np.asarray(a.vertices), np.asarray(a.faces)), (np.asarray(b.vertices), np.asarray(b.faces)))
    count, labels = shell_labels(mesh)
    assert count == 2 and len(set(labels[:12])) == 1 and labels[0] != labels[-1]
