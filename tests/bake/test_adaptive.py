"""Adaptive texel evaluation: within the tolerance of a full evaluation on analytic samples, never across a
seam, islands and borders evaluated, creases refined, the report's figures, and the errors."""

from types import SimpleNamespace
import warnings

import numpy as np
import pytest
import torch

from neural_bake.bake.adaptive import (_NODES, _QUARTERS, KERNEL, AdaptiveOptions, _box, _grid_positions_from_uv,
                                       _integral, _interp, _interpolate, _interpolate_native, _interpolate_quadratic,
                                       _next_to, _pack, _quadratic_ok, _surplus_ok, _Store, _weights, adaptive_evaluate, chart_labels,
                                       grid_positions, kernel_status, vertex_positions)
from neural_bake.bake.baker import Baker, _evaluate
from neural_bake.errors import NeuralBakeError
from neural_bake.fields import SdfField, TextureField
from neural_bake.nets.native import compiler
from neural_bake.io.mesh_io import load_mesh
from neural_bake.mesh.decimate import decimate
from neural_bake.samples.generate import sample_path
from neural_bake.samples.shapes import get_sample


def angle_deg(a, b):
    """Angles (degrees) between the rows' directions, exact near 0° (the bake's own measure)."""
    from neural_bake.geometry import angular_error

    return angular_error(a, b)


def analytic_fields(name, frame):
    """The sample's exact SDF (value and normal) and albedo as fields of unit-frame points."""
    sample = get_sample(name)

    def pair(p):
        q = frame.to_source(p.cpu().numpy())
        return (torch.as_tensor(sample.sdf(q) * frame.scale, dtype=p.dtype),
                torch.as_tensor(sample.normal(q), dtype=p.dtype))

    def albedo(p):
        return torch.as_tensor(sample.albedo(frame.to_source(p.cpu().numpy())), dtype=p.dtype)

    return sample, SdfField.from_value_and_gradient(pair, name=name), TextureField(albedo, name=name)


@pytest.fixture(scope="module")
def torus_baker():
    mesh = load_mesh(sample_path("torus"))
    return Baker(decimate(mesh, faces=600), 256), mesh.frame


@pytest.fixture(scope="module")
def sphere_baker():
    mesh = load_mesh(sample_path("sphere"))
    baker = Baker(decimate(mesh, faces=400), 512)
    _, sdf, tex = analytic_fields("sphere", mesh.frame)
    return baker, sdf, tex, baker.bake(sdf, tex)


@pytest.mark.parametrize("tolerance, colours", [(0.05, True), (0.5, False)])
def test_adaptive_bake_keeps_every_sample_within_the_tolerance(sphere_baker, tolerance, colours):
    baker, sdf, tex, full = sphere_baker
    tex = tex if colours else None
    opt = AdaptiveOptions(tolerance_deg=tolerance)
    res = baker.bake(sdf, tex, adaptive=opt)
    err = angle_deg(res.normals, full.normals)
    assert err.max() <= tolerance
    assert np.abs(res.values - full.values).max() <= opt.value_tol
    if colours:
        assert np.abs(res.colors - full.colors).max() <= opt.color_tol
    st = res.stats["adaptive"]
    assert st["evaluated"] + st["interpolated"] == st["samples"] == full.stats["samples"]
    assert res.stats["evaluated_fraction"] < 0.45  # it does interpolate
    assert full.stats["evaluated_fraction"] == 1.0 and full.stats["adaptive"] is None
    assert "error_control" not in full.stats
    assert res.stats["kernels"]["interpolation"] == kernel_status() and "interpolation" not in full.stats["kernels"]
    # the report's sampled check is the same comparison on a seeded subsample
    control = res.stats["error_control"]
    assert 0 < control["samples"] <= full.stats["samples"] and control["interpolated"] > 0
    assert control["angle_deg"]["max"] <= err.max() + 1e-9
    if colours:
        assert control["color_max"] <= opt.color_tol
    again = baker.bake(sdf, tex, adaptive=opt)
    assert again.stats["error_control"] == control  # seeded
    # the maps hold the same normals within the tolerance
    assert np.abs(res.normal_map - full.normal_map).max() < np.radians(tolerance)


def grid_texels(rows, cols, shape):
    """A synthetic band: samples at grid positions (rows, cols) of a ``shape`` grid, points on the plane z = 0."""
    rows, cols = np.asarray(rows), np.asarray(cols)
    points = np.stack([cols * 0.01, rows * 0.01, np.zeros(len(rows))], axis=1)
    return SimpleNamespace(n_samples=len(rows), points=points, size=shape, supersample=1)


def chart_field(charts, tilt_deg=10.0):
    """Normals constant per chart (chart c tilted by c × tilt about y), f = 0, colours = chart id: a field
    discontinuous across every seam. Returns (evaluate, counter of evaluated samples)."""
    seen = []
    t = np.radians(tilt_deg) * charts

    def evaluate(idx):
        seen.append(np.asarray(idx))
        n = np.stack([np.sin(t[idx]), np.zeros(len(idx)), np.cos(t[idx])], axis=1)
        return {"values": np.zeros(len(idx)), "normals": n, "valid": np.ones(len(idx), bool),
                "colors": np.repeat(charts[idx, None].astype(float), 3, axis=1)}

    return evaluate, seen


def test_interpolation_never_crosses_a_seam_and_small_islands_are_evaluated():
    # a 64 × 64 grid: chart 0 on the left, chart 1 on the right (a seam at column 37, off the lattice), an
    # uncovered hole, and a 5 × 5 island of chart 2 inside the hole (smaller than the 16-lattice)
    r, c = np.meshgrid(np.arange(64), np.arange(64), indexing="ij")
    charts = np.where(c < 37, 0, 1)
    hole = (r >= 20) & (r < 40) & (c >= 5) & (c < 25)
    island = (r >= 27) & (r < 32) & (c >= 10) & (c < 15)
    charts = np.where(island, 2, charts)
    keep = ~hole | island
    rows, cols, labels = r[keep], c[keep], charts[keep]
    tx = grid_texels(rows, cols, (64, 64))
    evaluate, seen = chart_field(labels)
    res = adaptive_evaluate(tx, labels, (rows, cols), evaluate, AdaptiveOptions(lattice=16))
    exact, _ = chart_field(labels)
    truth = exact(np.arange(len(rows)))
    np.testing.assert_allclose(res["normals"], truth["normals"], atol=1e-12)  # no mixing of charts
    np.testing.assert_allclose(res["colors"], truth["colors"], atol=1e-12)
    assert res["evaluated"][labels == 2].all()  # the island: every sample evaluated
    assert (res["evaluated"] | res["interpolated"]).all() and not (res["evaluated"] & res["interpolated"]).any()
    # evaluated exactly once each
    ids = np.concatenate(seen)
    assert len(ids) == len(np.unique(ids)) == res["stats"]["evaluated"]
    assert res["interpolated"].sum() > 0.5 * len(rows)


def test_samples_off_the_grid_and_border_samples_are_evaluated():
    r, c = np.meshgrid(np.arange(32), np.arange(32), indexing="ij")
    rows, cols = r.reshape(-1), c.reshape(-1)
    rows = np.where(np.arange(len(rows)) % 97 == 0, -1, rows)  # some samples off the grid (border samples)
    cols = np.where(rows < 0, -1, cols)
    labels = np.zeros(len(rows), dtype=np.int64)
    tx = grid_texels(np.maximum(rows, 0), np.maximum(cols, 0), (32, 32))
    evaluate, _ = chart_field(labels)
    res = adaptive_evaluate(tx, labels, (rows, cols), evaluate)
    assert res["evaluated"][rows < 0].all()
    assert res["interpolated"].any()


def test_linear_field_is_interpolated_exactly_float64_and_float32():
    # normals and values that are affine in space: the interpolation reproduces them (up to renormalising)
    r, c = np.meshgrid(np.arange(33), np.arange(33), indexing="ij")
    rows, cols = r.reshape(-1), c.reshape(-1)
    tx = grid_texels(rows, cols, (33, 33))
    labels = np.zeros(len(rows), dtype=np.int64)
    for dtype in (np.float64, np.float32):
        def evaluate(idx, dtype=dtype):
            p = tx.points[idx].astype(dtype)
            v = (0.3 * p[:, 0] - 0.2 * p[:, 1]).astype(np.float64)
            return {"values": v, "normals": np.tile([0.0, 0.0, 1.0], (len(idx), 1)), "valid": np.ones(len(idx), bool)}

        res = adaptive_evaluate(tx, labels, (rows, cols), evaluate, AdaptiveOptions(lattice=16))
        ref = 0.3 * tx.points[:, 0] - 0.2 * tx.points[:, 1]
        atol = 1e-12 if dtype == np.float64 else 1e-7
        np.testing.assert_allclose(res["values"], ref, atol=atol)
        assert res["stats"]["evaluated"] < 0.1 * len(rows)


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (9, 1), (37, 23)])
def test_integral_image_sums_match_brute_force(shape, rng):
    image = rng.random(shape) < 0.4
    s = _integral(image)
    assert s.shape == (shape[0] + 1, shape[1] + 1) and s[0].sum() == 0 and s[:, 0].sum() == 0
    for r in range(shape[0]):
        for c in range(shape[1]):
            assert s[r + 1, c + 1] == image[: r + 1, : c + 1].sum()
    k = min(shape) - 1
    if k >= 0:  # the closed squares the cells test
        r0, c0 = np.array([0, shape[0] - 1 - k]), np.array([shape[1] - 1 - k, 0])
        assert list(_box(s, r0, c0, k)) == [image[r: r + k + 1, c: c + k + 1].sum() for r, c in zip(r0, c0)]


@pytest.mark.parametrize("dtype,atol", [(torch.float64, 1e-10), (torch.float32, 2e-4)])
def test_quadratic_weights_reproduce_quadratic_fields(dtype, atol, rng):
    """On skewed cells in space (random affine images of the unit square) with nodes moved off their ideal
    places, the weights reproduce any quadratic polynomial of the cell's coordinates at the nodes and at random
    points, and sum to one."""
    from neural_bake.bake.adaptive import _NODES, _quadratic_weights

    n, m = 50, 30
    origin, e_t, e_u = (rng.normal(size=(n, 3)) for _ in range(3))
    ideal = _NODES / 2.0  # (9, 2): (t, u) of the nodes
    tu_nodes = ideal[None] + rng.uniform(-0.04, 0.04, size=(n, 9, 2))
    tu_nodes[:, [0, 2, 6, 8]] = ideal[[0, 2, 6, 8]]  # the corners define the cell's coordinates
    tu_points = rng.uniform(-0.2, 1.2, size=(n, m, 2))

    def place(tu):  # (n, k, 2) -> (3, n, k) points of each cell's parallelogram
        return np.einsum("nkt,ntd->dnk", tu, np.stack([e_t, e_u], axis=1)) + origin.T[:, :, None]

    coef = rng.normal(size=(n, 6))

    def q(tu):  # a quadratic polynomial per cell
        t, u = tu[..., 0], tu[..., 1]
        return (coef[:, 0:1] + coef[:, 1:2] * t + coef[:, 2:3] * u + coef[:, 3:4] * t * t + coef[:, 4:5] * t * u
                + coef[:, 5:6] * u * u)

    nodes = torch.from_numpy(place(tu_nodes).transpose(0, 2, 1)).to(dtype)  # (3, 9, n)
    for tu in (tu_nodes, tu_points):
        w, good = _quadratic_weights(nodes, torch.from_numpy(place(tu)).to(dtype))
        assert good.all() and w.dtype == dtype
        np.testing.assert_allclose(w.sum(-1).double().numpy(), 1.0, atol=atol)
        got = torch.einsum("nmk,nk->nm", w.double(), torch.from_numpy(q(tu_nodes))).numpy()
        np.testing.assert_allclose(got, q(tu), atol=atol * 10)
    degenerate = nodes.clone()
    degenerate[:, :, 0] = degenerate[:, 0:1, 0]  # every node of cell 0 at one point
    _, good = _quadratic_weights(degenerate, torch.from_numpy(place(tu_points)).to(dtype))
    assert not good[0] and good[1:].all()


def _sphere_over_grid(n: int, centre, colours: bool = False):
    """An n × n grid band of one chart whose normals point away from ``centre`` (a radial field, bending
    smoothly across the band), optionally with smooth colours: (texels, rows, cols, charts, evaluate)."""
    r, c = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    rows, cols = r.reshape(-1), c.reshape(-1)
    tx = grid_texels(rows, cols, (n, n))
    centre = np.asarray(centre, dtype=np.float64)

    def evaluate(idx):
        d = tx.points[idx] - centre
        out = {"values": np.zeros(len(idx)), "normals": d / np.linalg.norm(d, axis=1, keepdims=True),
               "valid": np.ones(len(idx), bool)}
        if colours:
            p = tx.points[idx]
            out["colors"] = 0.5 + 0.1 * np.stack([np.sin(p[:, 0]), p[:, 1] ** 2, p[:, 0]], 1)
        return out

    return tx, rows, cols, np.zeros(len(rows), dtype=np.int64), evaluate


def test_quadratic_pass_accepts_curved_fields_with_fewer_evaluations_within_tolerance(monkeypatch):
    """A field whose normals bend quadratically across the band (a large sphere over the plane, 2.5° over 16
    samples): bilinear cells fail at side 16 and 8 where quadratic ones pass. With the quadratic pass fewer
    samples are evaluated, and every interpolated normal is within the tolerance of the true one."""
    from neural_bake.bake import adaptive

    tx, rows, cols, labels, evaluate = _sphere_over_grid(129, [0.64, 0.64, -3.0], colours=True)
    opt = AdaptiveOptions(lattice=16, tolerance_deg=0.05)
    with_quad = adaptive_evaluate(tx, labels, (rows, cols), evaluate, opt)
    monkeypatch.setattr(adaptive, "_QUADRATIC_SIDE", 1 << 30)
    without = adaptive_evaluate(tx, labels, (rows, cols), evaluate, opt)
    assert with_quad["stats"]["cells_quadratic"] and not without["stats"]["cells_quadratic"]
    assert with_quad["stats"]["evaluated"] < 0.8 * without["stats"]["evaluated"]
    truth = evaluate(np.arange(len(rows)))
    for res in (with_quad, without):
        assert (res["evaluated"] | res["interpolated"]).all()
        assert angle_deg(res["normals"], truth["normals"]).max() <= opt.tolerance_deg
        assert np.abs(res["colors"] - truth["colors"]).max() <= opt.color_tol


def test_side_four_cells_that_fail_bilinear_pass_quadratic_at_no_extra_cost(monkeypatch):
    """At side 4 the quadratic test's points (the quarters' centres) are samples: a side-4 cell that fails the
    bilinear test is accepted quadratically where the field is smooth enough, and its test points are the
    evaluations a failed cell would make anyway. A curved field over a lattice of side 4: fewer samples are
    evaluated with the side-4 quadratic pass than without it, never more, and every interpolated normal is
    within the tolerance of the true one."""
    from neural_bake.bake import adaptive

    tx, rows, cols, labels, evaluate = _sphere_over_grid(65, [0.32, 0.32, -0.3])
    opt = AdaptiveOptions(lattice=4, tolerance_deg=0.1)
    with_quad = adaptive_evaluate(tx, labels, (rows, cols), evaluate, opt)
    monkeypatch.setattr(adaptive, "_QUADRATIC_SIDE", 8)
    without = adaptive_evaluate(tx, labels, (rows, cols), evaluate, opt)
    assert with_quad["stats"]["cells_quadratic"].get("4", 0) > 0 and not without["stats"]["cells_quadratic"]
    assert with_quad["stats"]["evaluated"] < 0.9 * without["stats"]["evaluated"]
    truth = evaluate(np.arange(len(rows)))
    for res in (with_quad, without):
        assert (res["evaluated"] | res["interpolated"]).all()
        assert angle_deg(res["normals"], truth["normals"]).max() <= opt.tolerance_deg
    # the evaluated samples keep their own values: interpolation never overwrites them
    ev = with_quad["evaluated"]
    assert np.array_equal(with_quad["normals"][ev], truth["normals"][ev] / np.linalg.norm(truth["normals"][ev],
                                                                                     axis=1, keepdims=True))

def test_cells_with_mostly_unfaithful_nodes_are_given_up_not_refined():
    """A hybrid's early decision (``give_up``, here: at least 7 of a failing cell's 9 nodes unfaithful): a cell it
    gives up is neither tested nor refined; its samples are interpolated from its nodes and returned as given up.
    Here every node in the band's left half is unfaithful: cells there are given up (fewer evaluations, each cell
    whole and none of its samples evaluated but its nodes), the right half refines as without a decision, and a
    decision that finds nothing unfaithful changes nothing."""
    tx, rows, cols, labels, evaluate = _sphere_over_grid(65, [0.32, 0.32, -0.3])
    opt = AdaptiveOptions(lattice=16, tolerance_deg=0.1)
    asked, sides = [], []

    def left_half(idx, normals, valid, values, colors):
        asked.append(np.asarray(idx))
        assert valid[idx].all() and np.allclose(np.linalg.norm(normals[idx], axis=1), 1.0)  # nodes: evaluated
        return cols[idx] < 32

    plain = adaptive_evaluate(tx, labels, (rows, cols), evaluate, opt)
    none = adaptive_evaluate(tx, labels, (rows, cols), evaluate, opt, give_up=lambda nodes, *a, **kw: np.zeros(len(nodes), bool))
    for k in ("evaluated", "interpolated", "normals"):
        np.testing.assert_array_equal(plain[k], none[k])
    assert not none["given_up"].any() and none["stats"]["given_up"] == 0
    res = adaptive_evaluate(tx, labels, (rows, cols), evaluate, opt,
                            give_up=lambda nodes, *a, side: (sides.append(side), left_half(nodes.reshape(-1), *a)
                                                             .reshape(-1, 9).sum(axis=1) >= 7)[1])
    given = res["given_up"]
    assert res["stats"]["given_up"] == given.sum() > 0 and res["stats"]["cells_given_up"]
    assert res["stats"]["evaluated"] < plain["stats"]["evaluated"]
    assert (res["evaluated"] | res["interpolated"]).all() and not (given & res["evaluated"]).any()
    assert (cols[given] <= 32).all()  # only cells of the unfaithful half (a cell's right edge may touch it)
    right = cols > 40
    for k in ("evaluated", "interpolated"):
        np.testing.assert_array_equal(res[k][right], plain[k][right])
    assert np.allclose(np.linalg.norm(res["normals"][given], axis=1), 1.0)  # interpolated: unit normals
    assert all(a.size for a in asked)
    assert set(sides) <= {16, 8, 4} and 16 in sides  # each call names its cells' side


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_spatial_weights_match_the_bilinear_reference(dtype, rng):
    # on a flat parallelogram the spatial coordinates are the parameters themselves: bilinear weights
    o, a, b = rng.normal(size=(3, 50, 3)).astype(dtype)
    corners = np.stack([o, o + b, o + a, o + a + b], axis=1).astype(np.float64)
    t, u = rng.uniform(0, 1, (2, 50))
    pts = o + t[:, None] * a + u[:, None] * b
    ref = np.stack([(1 - t) * (1 - u), (1 - t) * u, t * (1 - u), t * u], axis=1)
    tdt = torch.float64 if dtype == np.float64 else torch.float32
    w = _weights(torch.as_tensor(corners, dtype=tdt).permute(2, 1, 0), torch.as_tensor(pts, dtype=tdt).t())
    assert w.dtype == tdt
    np.testing.assert_allclose(w.t().numpy(), ref, atol=1e-9 if dtype == np.float64 else 1e-3)  # random, some thin


@pytest.mark.parametrize("dtype, atol", [(torch.float64, 1e-10), (torch.float32, 1e-4)])
def test_interpolation_kernel_matches_a_per_sample_reference(dtype, atol, rng):
    # cells: squares of side 0.01 bent a little out of plane, samples inside; fields: random smooth-ish
    n = 300
    o = rng.uniform(-1, 1, (n, 3))
    a, b = rng.normal(size=(2, n, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True) * 100
    b -= (b * a).sum(1, keepdims=True) * a / (a * a).sum(1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True) * 100
    bend = rng.normal(scale=1e-3, size=(n, 3))
    corners = np.stack([o, o + b, o + a, o + a + b + bend], axis=1)
    t, u = rng.uniform(0, 1, (2, n))
    at = o + t[:, None] * a + u[:, None] * b
    points = np.concatenate([corners.reshape(-1, 3), at])
    normals = rng.normal(size=(len(points), 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    store = _Store(values=rng.normal(scale=0.01, size=len(points)), normals=normals, valid=np.ones(len(points), bool),
                   colors=rng.uniform(size=(len(points), 3)))
    cidx = np.arange(4 * n).reshape(n, 4)
    aidx = 4 * n + np.arange(n)
    nrm, val, col = _interp(_pack(store, points, None, dtype), torch.from_numpy(cidx), torch.from_numpy(aidx))
    assert nrm.dtype == val.dtype == col.dtype == dtype
    for i in range(n):  # the reference: one sample at a time, least squares by numpy
        c = corners[i]
        e_t, e_u = 0.5 * (c[2] - c[0] + c[3] - c[1]), 0.5 * (c[1] - c[0] + c[3] - c[2])
        base = c.mean(axis=0) - 0.5 * e_t - 0.5 * e_u
        (tt, uu), *_ = np.linalg.lstsq(np.stack([e_t, e_u], axis=1), at[i] - base, rcond=None)
        w = np.array([(1 - tt) * (1 - uu), (1 - tt) * uu, tt * (1 - uu), tt * uu])
        nc = normals[cidx[i]]
        ref_n = w @ nc
        ref_n /= np.linalg.norm(ref_n)
        ref_v = w @ (store.values[cidx[i]] + ((at[i] - c) * nc).sum(axis=1))
        np.testing.assert_allclose(nrm[i].double().numpy(), ref_n, atol=atol)
        np.testing.assert_allclose(float(val[i]), ref_v, atol=atol)
        np.testing.assert_allclose(col[i].double().numpy(), w @ store.colors[cidx[i]], atol=atol)


def cell_store(rng, colours: bool):
    """A 33×33 sample grid on a bent sheet with smooth fields, its 3×3-node samples of the side-16 and side-8 cells
    evaluated, some other samples already done, and a hole (-1) outside the cells."""
    r, c = np.meshgrid(np.arange(33), np.arange(33), indexing="ij")
    index = (r * 33 + c).astype(np.int64)
    x, y = 0.01 * c.reshape(-1), 0.01 * r.reshape(-1)
    points = np.stack([x, y, 0.3 * np.sin(3 * x) * np.cos(2 * y) + 0.05 * rng.normal(size=x.size) * 0.01], axis=1)
    normals = np.stack([np.sin(2 * x + y), np.cos(3 * y), 1.0 + x * y], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    m = len(points)
    store = _Store(values=rng.normal(scale=0.01, size=m), normals=normals, valid=np.zeros(m, bool),
                   colors=rng.uniform(size=(m, 4)) if colours else None, evaluated=np.zeros(m, bool),
                   interpolated=np.zeros(m, bool))
    cells = [(np.array([0, 16]), np.array([0, 0]), 16), (np.array([0, 8, 24]), np.array([16, 24, 16]), 8)]
    for r0, c0, k in cells:
        for a in range(3):
            for b in range(3):
                store.evaluated[index[r0 + a * k // 2, c0 + b * k // 2]] = True
    store.valid[store.evaluated] = True
    store.evaluated[index[5, 3]] = store.valid[index[5, 3]] = True  # evaluated already: left alone
    index[32, 32] = -1  # outside every cell
    return store, points, index, cells


@pytest.mark.skipif(compiler() is None, reason="no C compiler: the torch path is the only one")
@pytest.mark.parametrize("quadratic", [False, True])
@pytest.mark.parametrize("colours", [False, True])
def test_native_cell_interpolation_matches_the_torch_path_float64_and_float32(colours, quadratic, rng):
    # the C kernel computes in float64: equal to the float64 torch path to rounding, within float32's precision of
    # the float32 path; the same samples, the same flags, the nodes untouched
    assert "C kernel" in kernel_status()
    runs = {}
    for how in ("native", torch.float64, torch.float32):
        store, points, index, cells = cell_store(np.random.default_rng(7), colours)
        before = store.normals.copy(), store.values.copy()
        packed = None if how == "native" else _pack(store, points, None, how)
        for r0, c0, k in cells:
            if how == "native":
                _interpolate_native(KERNEL.lib(), store, points, index, r0, c0, k, quadratic=quadratic)
            else:
                (_interpolate_quadratic if quadratic else _interpolate)(store, packed, index, r0, c0, k)
        ev = store.evaluated
        np.testing.assert_array_equal(store.normals[ev], before[0][ev])
        np.testing.assert_array_equal(store.values[ev], before[1][ev])
        runs[how] = store
    native, ref64, ref32 = runs["native"], runs[torch.float64], runs[torch.float32]
    for ref in (ref64, ref32):
        np.testing.assert_array_equal(native.interpolated, ref.interpolated)
        np.testing.assert_array_equal(native.valid, ref.valid)
    inside = np.zeros((33, 33), bool)
    for r0, c0, k in cells:  # the same cells in every run
        for r, c in zip(r0, c0):
            inside[r: r + k + 1, c: c + k + 1] = True
    np.testing.assert_array_equal(native.interpolated, inside.reshape(-1) & ~native.evaluated)
    for ref, atol in ((ref64, 1e-12), (ref32, 2e-6)):
        np.testing.assert_allclose(native.normals, ref.normals, atol=atol)
        np.testing.assert_allclose(native.values, ref.values, atol=atol)
        if colours:
            np.testing.assert_allclose(native.colors, ref.colors, atol=atol)
    assert np.allclose(np.linalg.norm(native.normals[native.interpolated], axis=1), 1.0, atol=1e-12)


@pytest.mark.skipif(compiler() is None, reason="no C compiler: the torch path is the only one")
@pytest.mark.parametrize("colours", [False, True])
@pytest.mark.parametrize("which", ["surplus", "quadratic"])
def test_native_cell_tests_decide_as_the_torch_path(which, colours, monkeypatch):
    # cells of side 4 on a bent sheet whose normals turn at a seeded rate per cell: the C kernels (float64) of the
    # bilinear and the quadratic test and their float64 torch paths accept the same cells, some and not all; an
    # invalid node (and for the quadratic test an invalid test sample and a cell whose nodes are one point, no
    # parallelogram) are refused by both
    from neural_bake.bake import adaptive

    rng = np.random.default_rng(11)
    n_cells = 400
    r, c = np.meshgrid(np.arange(5), np.arange(5), indexing="ij")
    local = np.stack([0.01 * c.reshape(-1), 0.01 * r.reshape(-1)], axis=1)  # (25, 2)
    freq = np.repeat(rng.uniform(0.0, 60.0, n_cells), 25)[:, None]  # how fast each cell's normals turn
    xy = (local[None] + rng.uniform(-1, 1, (n_cells, 1, 2))).reshape(-1, 2)
    points = np.concatenate([xy, 0.2 * np.sin(3 * xy[:, :1]) * np.cos(2 * xy[:, 1:])], axis=1)
    normals = np.concatenate([np.sin(freq * xy), np.ones((len(xy), 1))], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    m = len(points)
    store = _Store(values=rng.normal(scale=1e-4, size=m), normals=normals, valid=np.ones(m, bool),
                   colors=rng.uniform(0.5, 0.5 + 1e-4, size=(m, 3)) if colours else None,
                   evaluated=np.ones(m, bool), interpolated=np.zeros(m, bool))
    cell = np.arange(n_cells)[:, None] * 25
    nodes = cell + (2 * _NODES[:, 0] * 5 + 2 * _NODES[:, 1])[None]  # (P, 9): every other position
    tests = cell + (_QUARTERS[:, 0] * 5 + _QUARTERS[:, 1])[None]  # (P, 4)
    store.valid[nodes[0, 4]] = False  # an invalid node
    store.valid[tests[1, 2]] = False  # an invalid test sample
    points[cell[2, 0]: cell[2, 0] + 25] = points[cell[2, 0]]  # a cell whose samples are one point
    opt = AdaptiveOptions(tolerance_deg=0.5 if which == "quadratic" else 2.0)

    def decide():
        if which == "surplus":
            return _surplus_ok(store, points, nodes, opt, torch.float64)
        return _quadratic_ok(store, points, nodes, tests, opt, torch.float64)

    native = decide()
    monkeypatch.setattr(adaptive.KERNEL, "lib", lambda: None)
    reference = decide()
    np.testing.assert_array_equal(native, reference)
    assert not native[0] and (which == "surplus" or not native[:3].any())
    assert 0.1 < native.mean() < 0.9


@pytest.mark.skipif(compiler() is None, reason="no C compiler: scipy is the only path")
@pytest.mark.parametrize("seed", range(6))
def test_chart_labels_union_find_numbers_the_components_as_scipy_does(seed):
    # random faces over few and many vertices (one big component, many small ones, unused vertices)
    from neural_bake.bake.adaptive import _chart_labels_scipy

    rng = np.random.default_rng(seed)
    nv = int(rng.integers(3, 400))
    faces = rng.integers(0, nv, (int(rng.integers(1, 300)), 3))
    mesh = SimpleNamespace(faces=faces, n_vertices=nv + 5)
    labels = chart_labels(mesh)
    np.testing.assert_array_equal(labels, _chart_labels_scipy(faces.astype(np.int64), nv + 5))
    assert labels[0] == 0 and (np.diff(np.maximum.accumulate(labels)) <= 1).all()  # numbered by first face


def test_grid_positions_of_one_sample_per_texel_are_the_texels():
    # the shortcut at supersample 1 against the positions recovered from the samples' UVs, on a mesh whose
    # UVs leave [0, 1] (wrapped copies) and with border samples
    import dataclasses

    unwrapped = Baker(decimate(load_mesh(sample_path("torus")), faces=300), 8).mesh
    shifted = dataclasses.replace(unwrapped, uv=unwrapped.uv + np.array([1.0, -1.0]), uv_policy="wrap")
    for mesh in (unwrapped, shifted):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the wrap is announced
            baker = Baker(mesh, 96)
        tx = baker.texels
        fast = grid_positions(tx, baker.mesh)
        slow = _grid_positions_from_uv(tx, baker.mesh, np.asarray(tx.face, dtype=np.int64))
        np.testing.assert_array_equal(fast[0], slow[0])
        np.testing.assert_array_equal(fast[1], slow[1])
        assert tx.border.any() and (fast[0][tx.border] < 0).all()  # border samples off the grid
        assert (fast[0] >= 0).mean() > 0.5


def test_jack_refines_along_its_creases():
    mesh = load_mesh(sample_path("jack"))
    baker = Baker(decimate(mesh, faces=2000), 512)
    sample, sdf, _ = analytic_fields("jack", mesh.frame)
    tx = baker.texels
    pts = tx.points
    full = _evaluate(pts, baker.mesh.frame, sdf, None, 1 << 16)
    gr, gc = grid_positions(tx, baker.mesh)
    on = gr >= 0
    index = np.full(baker.shape, -1)
    index[gr[on], gc[on]] = np.flatnonzero(on)
    # crease samples: a grid neighbour of the same chart lies on another part of the union (the ball or
    # another spike) with a normal more than 5° away: where a spike meets the ball the normal jumps
    charts = chart_labels(baker.mesh)[tx.face]
    part = np.argmin(sample._parts(mesh.frame.to_source(pts))[0], axis=1)
    crease = np.zeros(len(pts), bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            nb = np.full(len(pts), -1)
            r, c = gr[on] + dy, gc[on] + dx
            inside = (r >= 0) & (r < baker.size) & (c >= 0) & (c < baker.size)
            nb[np.flatnonzero(on)[inside]] = index[r[inside], c[inside]]
            ok = (nb >= 0) & (charts == charts[np.maximum(nb, 0)]) & (part != part[np.maximum(nb, 0)])
            jump = angle_deg(full["normals"], full["normals"][np.maximum(nb, 0)]) > 5.0
            crease |= ok & jump
    assert crease.sum() > 200
    for tolerance in (0.05, AdaptiveOptions().tolerance_deg):
        res = adaptive_evaluate(tx, charts, (gr, gc),
                                lambda i: _evaluate(pts[i], baker.mesh.frame, sdf, None, 1 << 16),
                                AdaptiveOptions(tolerance_deg=tolerance),
                                vertices=vertex_positions(baker.mesh, baker.shape, 1))
        err = angle_deg(res["normals"], full["normals"])
        assert err.max() <= tolerance
        assert res["evaluated"][on & ~crease].mean() < 0.6  # away from the creases mostly interpolated
        if tolerance == 0.05:
            assert res["evaluated"][crease].all()  # every sample at a crease is evaluated
        else:  # a looser tolerance may interpolate a crease sample from nodes on its own side, within it
            assert res["evaluated"][crease].mean() > 0.98


def test_chart_labels_are_the_uv_charts(torus_baker):
    baker, _ = torus_baker
    labels = chart_labels(baker.mesh)
    assert labels.shape == (baker.mesh.n_faces,) and labels.min() == 0
    # faces sharing a vertex share a chart
    f = baker.mesh.faces
    for k in range(3):
        first = np.full(baker.mesh.n_vertices, -1)
        first[f[:, k]] = labels
        assert np.all(labels[np.flatnonzero(first[f[:, k]] >= 0)] == first[f[:, k]][first[f[:, k]] >= 0])


@pytest.mark.parametrize("kwargs, name", [({"tolerance_deg": 0}, "tolerance_deg"), ({"tolerance_deg": float("nan")},
                                          "tolerance_deg"), ({"tolerance_deg": 90}, "tolerance_deg"),
                                          ({"lattice": 12}, "lattice"), ({"lattice": 1}, "lattice"),
                                          ({"color_tol": -1.0}, "color_tol"), ({"value_tol": 0.0}, "value_tol")])
def test_bad_options_are_refused(kwargs, name):
    with pytest.raises(NeuralBakeError, match=name) as info:
        AdaptiveOptions(**kwargs)
    assert info.value.parameter == name


def test_bake_refuses_a_bad_adaptive_argument_and_check_count(torus_baker):
    baker, frame = torus_baker
    _, sdf, _ = analytic_fields("torus", frame)
    with pytest.raises(NeuralBakeError, match="adaptive must be AdaptiveOptions"):
        baker.bake(sdf, adaptive=0.05)
    with pytest.raises(NeuralBakeError, match="check_samples"):
        baker.bake(sdf, adaptive=AdaptiveOptions(), check_samples=-1)


def test_reduced_precision_bake_states_its_decision_and_error(torus_baker):
    from neural_bake.nets.siren import Siren

    baker, frame = torus_baker
    field = SdfField.from_model(Siren(32, 1, generator=torch.Generator().manual_seed(0)))
    slow = baker.bake(field, precision="auto", precision_measure=lambda w, d: 1.0)
    assert slow.stats["precision"]["sdf"] == "fp32" and "measured 1.00×" in slow.stats["precision"]["sdf_reason"]
    assert "error_control" not in slow.stats  # float32, every sample: nothing to check
    low = baker.bake(field, precision="bf16")
    assert low.stats["precision"]["sdf"] == "bf16"
    control = low.stats["error_control"]
    assert control["interpolated"] == 0 and control["samples"] > 0
    measured = control["precision_angle_deg"]
    err = angle_deg(low.normals, slow.normals)
    assert 0 < measured["max"] <= err.max() and measured["median"] < 1.0
    both = baker.bake(field, precision="bf16", adaptive=AdaptiveOptions(tolerance_deg=1.0))
    assert both.stats["error_control"]["precision_angle_deg"]["median"] is not None
    analytic = baker.bake(analytic_fields("torus", frame)[1], precision="auto")
    assert analytic.stats["precision"]["sdf"] == "fp32"


def counting(field, method):
    """Wrap ``field.method`` to count the points it is called on; returns the list of call sizes."""
    calls = []
    inner = getattr(field, method)

    def wrapped(points, *a, **k):
        calls.append(len(points))
        return inner(points, *a, **k)

    setattr(field, method, wrapped)
    return calls


def test_one_evaluation_serves_every_output(sphere_baker, tmp_path):
    """Normal map, albedo map, per-sample arrays and the report come from one evaluation of each field per
    sample: the fields see exactly the evaluated samples plus the sampled check's interpolated ones."""
    from neural_bake.bake.report import bake_report

    baker, sdf, tex, _ = sphere_baker
    _, sdf, tex = analytic_fields("sphere", baker.mesh.frame)
    sdf_calls, tex_calls = counting(sdf, "value_and_normal"), counting(tex, "color")
    res = baker.bake(sdf, tex, adaptive=AdaptiveOptions(tolerance_deg=0.2))
    control = res.stats["error_control"]
    evaluated = res.stats["adaptive"]["evaluated"] + res.stats["adaptive"]["face_nodes"]  # samples and faces
    assert sum(sdf_calls) == sum(tex_calls) == evaluated + control["interpolated"]
    assert res.normal_map is not None and res.albedo is not None and res.colors.shape[0] == res.normals.shape[0]
    before = (len(sdf_calls), len(tex_calls))
    bake_report(res, baker, fine=None, out_dir=tmp_path)
    assert (len(sdf_calls), len(tex_calls)) == before  # the report evaluates nothing
    full_calls = []
    sdf2 = analytic_fields("sphere", baker.mesh.frame)[1]
    full_calls = counting(sdf2, "value_and_normal")
    full = baker.bake(sdf2)
    assert sum(full_calls) == full.stats["samples"]  # without adaptivity: each sample once


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_field_value_is_the_forward_pass_of_value_and_normal(dtype):
    """The hybrid's f at source points comes from the forward pass alone: the same values as the GEMM pass."""
    from neural_bake.nets.siren import Siren

    model = Siren(32, 2, generator=torch.Generator().manual_seed(0)).to(dtype)
    field = SdfField.from_model(model)
    x = torch.rand(500, 3, dtype=dtype, generator=torch.Generator().manual_seed(1)) - 0.5
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(field.value(x), field.value_and_normal(x)[0], atol=tol, rtol=tol)
    analytic = SdfField(lambda p: p.norm(dim=1) - 0.5)
    torch.testing.assert_close(analytic.value(x), x.norm(dim=1) - 0.5)
    nan = SdfField(lambda p: torch.full((len(p),), float("nan"), dtype=p.dtype))
    assert torch.isinf(nan.value(x)).all()


def test_bake_interpolates_inside_faces_and_stays_within_the_tolerance(monkeypatch):
    from neural_bake.bake import baker as baker_mod

    mesh = load_mesh(sample_path("sphere"))
    baker = Baker(decimate(mesh, faces=400), 512)
    _, sdf, _ = analytic_fields("sphere", mesh.frame)
    full = baker.bake(sdf)
    opt = AdaptiveOptions(tolerance_deg=0.5)
    res = baker.bake(sdf, adaptive=opt)
    st = res.stats["adaptive"]
    assert st["face_interpolated"] > st["face_nodes"] > 0
    assert angle_deg(res.normals, full.normals).max() <= opt.tolerance_deg
    # points of faces are in the frame of the samples: the face pass's geometry gives back their points
    geom = baker_mod.face_geometry(baker.mesh, baker.shape, baker.supersample)
    tx = next(iter(baker.bands()))
    again = np.einsum("nk,nkd->nd", np.asarray(tx.bary), geom.corners[np.asarray(tx.face)])
    assert np.abs(again - np.asarray(tx.points)).max() < 1e-9
    monkeypatch.setattr(baker_mod, "face_geometry", lambda *a: None)
    without = Baker(decimate(mesh, faces=400), 512).bake(sdf, adaptive=opt)
    assert without.stats["adaptive"]["face_nodes"] == 0
    assert res.stats["evaluated_fraction"] < without.stats["evaluated_fraction"]


def _folded_sheet(fold_deg: float, n: int = 8):
    """An n×n grid of unit squares (two triangles each) in the xy plane, folded by ``fold_deg`` along x = n/2,
    with a planar UV map (its own x, y scaled into [0, 1]): one chart, no seam."""
    from neural_bake.types import Mesh

    xs, ys = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="xy")
    x, y = xs.ravel(), ys.ravel()
    a = np.radians(fold_deg)
    right = x > n / 2
    v = np.stack([np.where(right, n / 2 + (x - n / 2) * np.cos(a), x), y,
                  np.where(right, (x - n / 2) * np.sin(a), 0.0)], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    q = np.stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()], axis=1)
    faces = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]).astype(np.int64)
    uv = (np.stack([x, y], axis=1) / n * 0.9 + 0.05)[faces]
    return Mesh(vertices=v, faces=faces, uv=uv)


def test_features_are_the_bent_edges_and_their_ends_not_every_vertex():
    """A flat sheet has no feature (its vertices are not: the surface does not bend there); folded by more than
    ADAPTIVE_EDGE_DEG, the fold line is one, sampled at most half a grid step apart from end to end."""
    from neural_bake.constants import ADAPTIVE_EDGE_DEG

    size = 64
    assert vertex_positions(_folded_sheet(0.0), (size, size), 1).shape == (0, 2)
    assert vertex_positions(_folded_sheet(ADAPTIVE_EDGE_DEG / 2), (size, size), 1).shape == (0, 2)
    for supersample in (1, 2):
        pts = vertex_positions(_folded_sheet(2 * ADAPTIVE_EDGE_DEG), (size, size), supersample)
        g = size * supersample
        col = (0.05 + 0.5 * 0.9) * g - 0.5  # the fold's column on the sample grid
        np.testing.assert_allclose(pts[:, 1], col, atol=1e-9)
        rows = np.unique(np.round(pts[:, 0], 9))
        assert rows.min() == pytest.approx(0.05 * g - 0.5) and rows.max() == pytest.approx(0.95 * g - 0.5)
        assert np.diff(rows).max() <= 0.5 + 1e-9


@pytest.mark.skipif(compiler() is None, reason="no C compiler: the torch path is the only one")
@pytest.mark.parametrize("quadratic", [False, True])
def test_native_cell_interpolation_gives_the_same_bits_on_any_thread_count(monkeypatch, quadratic):
    # enough cells to be split over the team (where the kernel shares torch's OpenMP), in a shuffled order, with
    # some samples done before: each colour of the cells' checkerboard in parallel (a shared edge goes to the black
    # cell; its neighbour would give it another value), the same bits on one thread and in any order
    from neural_bake.bake import adaptive as adaptive_module

    rng = np.random.default_rng(3)
    side, k = 129, 8
    r, c = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    index = (r * side + c).astype(np.int64)
    x, y = 0.004 * c.reshape(-1), 0.004 * r.reshape(-1)
    points = np.stack([x + 1e-4 * np.sin(40 * y), y, 0.3 * np.sin(3 * x) * np.cos(2 * y)], axis=1)
    r0, c0 = (a.reshape(-1) for a in np.meshgrid(np.arange(0, side - 1, k), np.arange(0, side - 1, k), indexing="ij"))
    order = rng.permutation(len(r0))
    r0, c0 = r0[order].astype(np.int64), c0[order].astype(np.int64)
    assert len(r0) == 256
    runs = {}
    for n in (1, 2):
        monkeypatch.setattr(adaptive_module, "threads", lambda n=n: n)
        m = len(points)
        normals = np.stack([np.sin(2 * x + y), np.cos(3 * y), 1.0 + x * y], axis=1)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        store = _Store(values=np.random.default_rng(5).normal(scale=0.01, size=m), normals=normals,
                       valid=np.zeros(m, bool), colors=np.random.default_rng(6).uniform(size=(m, 3)),
                       evaluated=(r.reshape(-1) % (k // 2) == 0) & (c.reshape(-1) % (k // 2) == 0),
                       interpolated=np.zeros(m, bool))
        store.evaluated[np.random.default_rng(8).choice(m, 500, replace=False)] = True
        store.valid[store.evaluated] = True
        _interpolate_native(KERNEL.lib(), store, points, index, r0, c0, k, quadratic=quadratic)
        runs[n] = store
    assert runs[1].interpolated.sum() > 10_000
    for name in ("normals", "values", "colors", "interpolated", "valid"):
        np.testing.assert_array_equal(getattr(runs[1], name), getattr(runs[2], name))
    # the same cells in another order: the same bits (the shared edges go by colour, not by order)
    monkeypatch.setattr(adaptive_module, "threads", lambda: 1)
    other = _Store(values=runs[1].values.copy(), normals=runs[1].normals.copy(), valid=np.zeros(len(points), bool),
                   colors=None, evaluated=runs[1].evaluated.copy(), interpolated=np.zeros(len(points), bool))
    ev = other.evaluated
    base = runs[2]
    other.values[~ev], other.normals[~ev] = 0.0, 0.0
    _interpolate_native(KERNEL.lib(), other, points, index, r0[::-1].copy(), c0[::-1].copy(), k, quadratic=quadratic)
    np.testing.assert_array_equal(other.values, base.values)
    np.testing.assert_array_equal(other.normals, base.normals)
    # and the colour decides: the white cells first would change some shared samples
    white_first = np.argsort(-((r0 // k + c0 // k) & 1), kind="stable")
    other.values[~ev], other.normals[~ev], other.interpolated[:] = 0.0, 0.0, False
    for part in (white_first[: len(r0) // 2], white_first[len(r0) // 2:]):  # each half one colour
        _interpolate_native(KERNEL.lib(), other, points, index, r0[part].copy(), c0[part].copy(), k,
                            quadratic=quadratic)
    assert not np.array_equal(other.values, base.values)


def test_next_to_finds_the_samples_within_reach_of_a_given_up_one():
    """The detail rim's neighbourhood: candidates within ``reach`` grid positions (a square) of a given-up sample, on
    the grid at their position and off it (border samples) at their texel's centre; the image may start at any row."""
    h = w = 10
    rows, cols = np.divmod(np.arange(h * w), w)
    index = np.arange(h * w).reshape(h, w)
    m = h * w + 2  # two border samples after the grid's
    gr = np.concatenate([rows + 20, [-1, -1]])  # the band's grid starts at row 20
    gc = np.concatenate([cols, [-1, -1]])
    pixel = np.stack([np.concatenate([rows + 20, [23, 20]]), np.concatenate([cols, [3, 0]])], axis=1)
    given = np.zeros(m, bool)
    given[5 * w + 5] = True
    texels = SimpleNamespace(supersample=1, pixel=pixel)
    out = _next_to(np.arange(m), given, index, texels, gr, gc, 20, 2)
    near = (np.abs(rows - 5) <= 2) & (np.abs(cols - 5) <= 2)
    np.testing.assert_array_equal(out, np.concatenate([np.flatnonzero(near), [m - 2]]))
    assert _next_to(np.arange(m), np.zeros(m, bool), index, texels, gr, gc, 20, 2).size == 0
