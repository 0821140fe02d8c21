"""Hybrid bake: unfaithful texels take the classical mesh-to-mesh normal; faithful fields keep ∇f everywhere."""

import functools
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from neural_bake.bake.baker import Baker
from neural_bake.bake.baseline import baseline_bake
from neural_bake.fields import SdfField
from neural_bake.bake.hybrid import HybridFallback, unfaithful
from neural_bake.constants import HYBRID_DETAIL_SIDE
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


def test_f_at_the_source_is_tested_only_where_the_angle_rule_keeps_the_sample():
    # a sphere SDF as the field of a plank, every sample decided: the samples the angle rule replaces take no
    # forward pass at their source points; the rest are tested for f, and the replaced set is the union of the rules
    plank = thin_box()
    coarse = unwrap(plank, resolution=128)
    baker = Baker(coarse, 48)
    hybrid = HybridFallback(plank, sphere_field(0.5), decide="all")
    asked = []
    real = hybrid.field_values
    hybrid.field_values = lambda points: asked.append(len(points)) or real(points)
    res = baker.bake(sphere_field(0.5), hybrid=hybrid)
    tx = baker.texels
    base = baseline_bake(baker.mesh, plank, tx)
    f_src = sphere_field(0.5).value(__import__("torch").as_tensor(base["points"])).numpy()
    why = unfaithful(f_src, res.neural, base["normals"], np.ones(len(f_src), dtype=bool), sdf_tol=hybrid.sdf_tol,
                     angle_deg=hybrid.angle_deg)
    np.testing.assert_array_equal(res.replaced, why["mask"])  # the same samples as testing every rule everywhere
    kept = ~why["angle"]
    assert hybrid.counts["angle"] == why["angle"].sum() > 0 and hybrid.counts["sdf"] == (why["sdf"] & kept).sum()
    assert sum(asked) <= kept.sum() < len(f_src)  # forward passes only where the angle rule kept the sample


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


@pytest.mark.parametrize("scale", [1.0, 2.0])  # 2: the field in another unit frame, its points mapped there
def test_native_rules_decide_as_the_numpy_path(scale, monkeypatch):
    """The C kernel of the per-sample rules (hybrid.c ``nb_decide``: the angle and validity rules, the first-order
    estimate of f at the source and where it is safe) decides as numpy does: the same reasons, the same f at the
    source points to rounding, on a bumped sphere whose bump is off by more than the angle and whose side is off
    by more than the distance, with invalid samples, and with f at the texels known."""
    import torch

    from neural_bake.bake import hybrid as hybrid_module
    from neural_bake.types import Frame

    if hybrid_module.KERNEL.lib() is None:
        pytest.skip(hybrid_module.kernel_status())
    coarse = unwrap(ico(4), resolution=128)  # near the source: short rays, the estimate used
    bump = bumped_sphere_field(radius=R * scale, centre=(0.0, 0.0, R * scale)).fn

    def f(p):  # and off by 0.03 where x > 0.3 (the field's surface inside the source there, its normals right)
        return bump(p) - 0.03 * scale * (p[:, 0] > 0.3 * scale).to(p.dtype)

    field = SdfField(f, frame=Frame((0.0, 0.0, 0.0), scale) if scale != 1.0 else None)
    tx = Baker(coarse, 96).texels
    m = tx.n_samples
    pts = torch.as_tensor(np.asarray(tx.points) * scale)
    values, normals, valid = (a.detach().numpy().astype(np.float64) for a in field.value_and_normal(pts))
    valid = valid.astype(bool)
    valid[::97] = False
    idx = np.arange(0, m, 3)
    out = {}
    for path in ("kernel", "numpy"):
        hybrid = HybridFallback(ico(5), field)
        with monkeypatch.context() as mp:
            if path == "numpy":
                mp.setattr(hybrid_module.KERNEL, "lib", lambda: None)
            why, _ = hybrid._decide(coarse, tx, idx, normals, valid, None, values=values)
        out[path] = (why, np.concatenate(hybrid.f_abs), dict(hybrid.estimate))
    (why_k, f_k, est_k), (why_n, f_n, est_n) = out["kernel"], out["numpy"]
    for k in ("mask", "sdf", "angle", "invalid"):
        np.testing.assert_array_equal(why_k[k], why_n[k])
    assert why_k["angle"].sum() > 10 and why_k["sdf"].sum() > 0 and why_k["invalid"].sum() > 0
    np.testing.assert_allclose(f_k, f_n, rtol=0, atol=1e-15)
    assert est_k == est_n and est_k["estimated"] > 0


def bumped_sphere_field(radius=R, centre=(0.0, 0.0, R), height=0.06, width=0.2):
    """A sphere SDF with a bump of ``height`` over a cap of about ``width`` around ``centre``: off the true
    sphere (|f| at its surface up to ``height``) there, exact elsewhere."""
    import torch

    c = torch.tensor(centre, dtype=torch.float64)

    def f(p):
        return p.norm(dim=1) - radius - height * torch.exp(-((p - c.to(p.dtype)) ** 2).sum(dim=1) / width**2)

    return SdfField(f)


@pytest.mark.parametrize("supersample", [1, 2])
def test_lattice_decision_matches_deciding_every_sample(supersample):
    """On an adaptive bake, deciding on the lattice (evaluated samples on the stride's texels, then the ring around
    unfaithful ones) replaces exactly the samples that deciding every sample replaces, at a fraction of the
    decisions, when no cell is given up; the stride decides fewer than every evaluated sample, and the same ones are
    replaced. Cells given up (most nodes unfaithful) add only their own samples to what is replaced, with the
    classical normal, and spare evaluations."""
    from neural_bake.bake.adaptive import AdaptiveOptions

    coarse = unwrap(ico(2), resolution=256)
    field = bumped_sphere_field()
    baker = Baker(coarse, 256 // supersample, supersample=supersample)
    full = HybridFallback(ico(5), field, decide="all")
    lattice = HybridFallback(ico(5), field, give_up_nodes=10, detail_side=0)
    every_evaluated = HybridFallback(ico(5), field, stride=1, give_up_nodes=10, detail_side=0)
    giving_up = HybridFallback(ico(5), field, detail_side=0)
    a = baker.bake(field, hybrid=full, adaptive=AdaptiveOptions())
    b = baker.bake(field, hybrid=lattice, adaptive=AdaptiveOptions())
    c = baker.bake(field, hybrid=every_evaluated, adaptive=AdaptiveOptions())
    d = baker.bake(field, hybrid=giving_up, adaptive=AdaptiveOptions())
    assert a.replaced.sum() > 200  # the bump is off the sphere by more than the tolerance over a cap
    for other in (b, c):
        np.testing.assert_array_equal(a.replaced, other.replaced)
        np.testing.assert_array_equal(a.normal_map, other.normal_map)
    s_full, s_lat = full.summary(), lattice.summary()
    assert s_full["decided"] == s_full["samples"] and s_full["lattice_check"] is None
    assert s_lat["decided"] < 0.7 * s_lat["samples"]  # the lattice rule decides a fraction of the samples
    assert s_lat["decided"] < every_evaluated.summary()["decided"]
    check = s_lat["lattice_check"]
    assert check["samples"] > 0 and check["missed"] == 0 and check["missed_fraction"] == 0.0
    # giving up: the cap's cells are given up, their samples take the classical normal, nothing else changes
    given = d.stats["adaptive"]["given_up"]
    assert given > 0 and giving_up.summary()["given_up"] == given and s_lat["given_up"] == 0
    assert d.stats["adaptive"]["evaluated"] < b.stats["adaptive"]["evaluated"]
    assert (a.replaced & ~d.replaced).sum() == 0  # every unfaithful sample is still replaced
    extra = d.replaced & ~a.replaced
    assert 0 <= extra.sum() <= given
    np.testing.assert_array_equal(np.isnan(d.neural).any(axis=1), np.isnan(d.neural).all(axis=1))
    assert np.isnan(d.neural).any(axis=1).sum() == given  # no ∇f of the fields at given-up samples
    rep = np.flatnonzero(d.replaced)  # replaced by the classical bake's normal, given up or decided
    tx = baker.texels
    sub = SimpleNamespace(points=np.asarray(tx.points)[rep], normal=np.asarray(tx.normal)[rep], face=None, bary=None)
    np.testing.assert_allclose(d.normals[rep], baseline_bake(coarse, ico(5), sub)["normals"], atol=1e-12)
    assert giving_up.summary()["lattice_check"]["missed"] == 0


@pytest.mark.parametrize("detail_side", [4, 8])
def test_cells_too_fine_for_the_lattice_take_the_classical_normal(detail_side):
    """A cell no wider than ``detail_side`` that fails its interpolation test, with the classical rays hitting at
    all its nodes, is given up to the classical bake (reason "detail"): its samples and its nodes take the classical
    normal, fewer samples are evaluated, every unfaithful sample is still replaced, no wider cell is given up;
    where the rays miss (a cage too small to reach the source) no cell is."""
    from neural_bake.bake.adaptive import AdaptiveOptions

    coarse = unwrap(ico(2), resolution=256)
    field = bumped_sphere_field()
    baker = Baker(coarse, 256)
    opt = AdaptiveOptions(tolerance_deg=0.1)
    plain = HybridFallback(ico(5), field, give_up_nodes=10, detail_side=0)
    detail = HybridFallback(ico(5), field, give_up_nodes=10, detail_side=detail_side)
    a = baker.bake(field, hybrid=plain, adaptive=opt)
    d = baker.bake(field, hybrid=detail, adaptive=opt)
    s = detail.summary()
    cells = d.stats["adaptive"]["cells_given_up"]
    sourced = d.stats["adaptive"]["cells_source_detail"]
    assert s["detail_cells"] > 0 and s["detail_nodes"] > 0
    assert sum(cells.values()) == s["detail_cells"] + sum(sourced.values())
    assert all(int(k) <= detail_side for k in cells) and plain.summary()["detail_cells"] == 0
    assert d.stats["adaptive"]["evaluated"] < a.stats["adaptive"]["evaluated"]
    assert (a.replaced & ~d.replaced).sum() == 0
    given = d.stats["adaptive"]["given_up"]
    given_up = np.isnan(d.neural).any(axis=1)  # no ∇f of the fields at given-up samples
    assert given > 0 and given_up.sum() == given and d.replaced[given_up].all()
    rep = np.flatnonzero(d.replaced)
    tx = baker.texels
    sub = SimpleNamespace(points=np.asarray(tx.points)[rep], normal=np.asarray(tx.normal)[rep], face=None, bary=None)
    np.testing.assert_allclose(d.normals[rep], baseline_bake(coarse, ico(5), sub)["normals"], atol=1e-12)
    # a detail cell's nodes (evaluated: decided, or given up with a cell given up on the source's detail) take the
    # classical normal as its samples do
    assert (d.replaced & ~a.replaced).sum() >= s["detail_nodes"] > 0
    missing = HybridFallback(ico(5), field, give_up_nodes=10, detail_side=detail_side, cage=1e-5)
    m = baker.bake(field, hybrid=missing, adaptive=opt)
    assert missing.summary()["detail_cells"] == 0 and m.stats["adaptive"]["rim"] == 0
    assert not m.stats["adaptive"]["cells_source_detail"] and m.stats["adaptive"]["given_up"] == 0


@pytest.mark.parametrize("detail_side", [4, 8])
def test_samples_next_to_given_up_cells_take_the_classical_normal(monkeypatch, detail_side):
    """The detail rim: samples no cell holds (chart borders, border samples) within half ``detail_side`` of a given-up
    sample take the classical normal where their rays hit, without an evaluation: fewer evaluations than without the
    rim, by its count; every sample replaced without it still is, and the rim's samples have the classical bake's
    normal and no ∇f of the fields'."""
    from neural_bake.bake import adaptive as adaptive_module
    from neural_bake.bake.adaptive import AdaptiveOptions

    coarse = unwrap(ico(2), resolution=256)
    field = bumped_sphere_field()
    baker = Baker(coarse, 256)
    opt = AdaptiveOptions(tolerance_deg=0.1)
    r = baker.bake(field, hybrid=HybridFallback(ico(5), field, give_up_nodes=10, detail_side=detail_side), adaptive=opt)
    with monkeypatch.context() as mp:
        mp.setattr(adaptive_module, "_next_to", lambda candidates, *a: candidates[:0])
        p = baker.bake(field, hybrid=HybridFallback(ico(5), field, give_up_nodes=10, detail_side=detail_side),
                       adaptive=opt)
    n = r.stats["adaptive"]["rim"]
    assert n > 0 and p.stats["adaptive"]["rim"] == 0
    assert r.stats["adaptive"]["evaluated"] == p.stats["adaptive"]["evaluated"] - n
    assert r.stats["adaptive"]["given_up"] == p.stats["adaptive"]["given_up"] + n
    assert not (p.replaced & ~r.replaced).any()
    extra = np.isnan(r.neural).any(axis=1) & ~np.isnan(p.neural).any(axis=1)  # the rim's samples
    assert extra.sum() == n and r.replaced[extra].all()
    tx = baker.texels
    sub = SimpleNamespace(points=np.asarray(tx.points)[extra], normal=np.asarray(tx.normal)[extra], face=None,
                          bary=None)
    np.testing.assert_allclose(r.normals[extra], baseline_bake(coarse, ico(5), sub)["normals"], atol=1e-12)


def rippled_sphere(level=5, amplitude=0.002, waves=24):
    """A sphere mesh of radius R with ripples of ``amplitude`` (``waves`` around it; normals up to ~3° off the
    sphere's, under the hybrid's angle): detail a sphere SDF lacks."""
    mesh = ico(level)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    u = v / np.linalg.norm(v, axis=1, keepdims=True)
    ripple = 1.0 + amplitude * np.sin(waves * np.arctan2(u[:, 1], u[:, 0])) * np.cos(waves * u[:, 2])
    return Mesh(vertices=u * R * ripple[:, None], faces=mesh.faces)


def test_cells_where_the_source_has_detail_are_given_up_unevaluated(monkeypatch):
    """The source's detail: a cell no wider than ``detail_side`` whose nodes' classical rays all hit a source whose
    normals fail the cell's interpolation test is given up before ∇f is evaluated at its nodes. A smooth field (a
    sphere) over a rippled source: cells are given up on the source's normals alone, their samples take the
    classical normal (the source's, so the map is closer to it than the field's), fewer samples are evaluated than
    without the rule, and none where the rays miss (a cage too small to reach the source)."""
    from neural_bake.bake import adaptive as adaptive_module
    from neural_bake.bake.adaptive import AdaptiveOptions

    coarse = unwrap(ico(2), resolution=256)
    source = rippled_sphere()
    field = sphere_field()
    baker = Baker(coarse, 256)
    opt = AdaptiveOptions()
    d = baker.bake(field, hybrid=HybridFallback(source, field, give_up_nodes=10), adaptive=opt)
    with monkeypatch.context() as mp:
        mp.setattr(adaptive_module, "_source_detail", lambda classical, flat_f, points, nodes, *a:
                   np.zeros(len(nodes), bool))
        p = baker.bake(field, hybrid=HybridFallback(source, field, give_up_nodes=10), adaptive=opt)
    st = d.stats["adaptive"]
    assert sum(st["cells_source_detail"].values()) > 50 and not p.stats["adaptive"]["cells_source_detail"]
    assert all(int(k) <= HYBRID_DETAIL_SIDE for k in st["cells_source_detail"])
    # a wider cell (the lattice's 16) where the source fails is split without evaluating ∇f at its nodes
    assert st["cells_source_split"].get("16", 0) > 0 and not p.stats["adaptive"]["cells_source_split"]
    assert st["evaluated"] < p.stats["adaptive"]["evaluated"]
    given = np.isnan(d.neural).any(axis=1)
    assert given.sum() == st["given_up"] > 0 and d.replaced[given].all()
    src = given & ~np.isnan(p.neural).any(axis=1)  # given up on the source's detail alone
    tx = baker.texels
    sub = SimpleNamespace(points=np.asarray(tx.points)[src], normal=np.asarray(tx.normal)[src], face=None, bary=None)
    truth = baseline_bake(coarse, source, sub)["normals"]
    np.testing.assert_allclose(d.normals[src], truth, atol=1e-12)
    assert src.sum() > 1000 and np.median(angle_deg(p.normals[src], truth)) > 0.5  # the field has no ripples
    # f where it was not evaluated: the source's signed distance (the ripples' 0.0014 off the sphere at most)
    x = np.asarray(tx.points)[src]
    assert np.abs(d.values[src] - (np.linalg.norm(x, axis=1) - R)).max() < 0.002
    assert d.replaced.sum() > p.replaced.sum() + 1000
    missing = HybridFallback(source, field, give_up_nodes=10, cage=1e-5)
    m = baker.bake(field, hybrid=missing, adaptive=opt)
    assert not m.stats["adaptive"]["cells_source_detail"] and m.stats["adaptive"]["given_up"] == 0


def test_stride_decides_evaluated_samples_between_its_texels_only_near_unfaithful_ones():
    """Every sample evaluated (an adaptive bake's hard region: ``side`` 0): with stride 2 the samples on even rows and
    columns are decided first and the others only within 2 positions (3 texels) of an unfaithful one, so an
    unfaithful region is found whole, while a lone unfaithful sample between the stride's texels, with none of them
    unfaithful near it, is left to the check; with stride 1 every evaluated sample is decided."""
    coarse = unwrap(ico(2), resolution=256)
    field = bumped_sphere_field()
    baker = Baker(coarse, 256)
    tx = baker.texels
    m = tx.n_samples
    valid, evaluated, side = np.ones(m, dtype=bool), np.ones(m, dtype=bool), np.zeros(m, dtype=np.int16)
    normals = np.asarray(tx.points, dtype=np.float64) / np.linalg.norm(tx.points, axis=1, keepdims=True)
    pix = np.asarray(tx.pixel)
    far = np.flatnonzero((np.asarray(tx.points)[:, 2] < -0.3) & (pix[:, 0] % 2 == 1) & (pix[:, 1] % 2 == 1))
    lone = far[len(far) // 2]
    normals[lone] = -normals[lone]  # one sample's normal flipped, far from the bump's cap
    runs = {}
    for stride in (1, 2):
        hybrid = HybridFallback(ico(5), field, stride=stride, seed=3)
        runs[stride] = (hybrid(baker.mesh, tx, normals, valid, evaluated, side=side).replaced, hybrid.summary())
    (every, s1), (strided, s2) = runs[1], runs[2]
    assert every[lone] and not strided[lone]
    cap = every.copy()
    cap[lone] = False
    assert cap.sum() > 200 and not (cap & ~strided).any()  # the cap's region found whole
    assert s2["decided"] < 0.6 * s1["decided"] and s1["decided"] == m


def test_lattice_decision_without_adaptive_decides_every_sample():
    """A bake that evaluates every sample (no adaptive lattice) decides every sample: nothing left to check."""
    coarse = unwrap(ico(2), resolution=128)
    field = bumped_sphere_field()
    hybrid = HybridFallback(ico(5), field)
    Baker(coarse, 48).bake(field, hybrid=hybrid)
    s = hybrid.summary()
    assert s["decided"] == s["samples"] > 0 and s["lattice_check"]["samples"] == 0 and s["replaced"] > 0


def test_lattice_check_counts_what_the_rule_missed():
    """Where the evaluated samples miss an unfaithful region (here: none of them lies on the bump's cap), the
    lattice rule leaves it undecided; the seeded check decides a share of the undecided samples in full,
    replaces the unfaithful ones it finds, and counts them as missed."""
    coarse = unwrap(ico(2), resolution=256)
    field = bumped_sphere_field()
    baker = Baker(coarse, 256)
    tx = baker.texels
    normals, valid = np.asarray(tx.normal, dtype=np.float64), np.ones(tx.n_samples, dtype=bool)
    evaluated = np.asarray(tx.points)[:, 2] < 0  # the cap is around +Z
    every = HybridFallback(ico(5), field, decide="all")(baker.mesh, tx, normals, valid, evaluated).replaced
    hybrid = HybridFallback(ico(5), field)
    lattice = hybrid(baker.mesh, tx, normals, valid, evaluated).replaced
    assert every.sum() > 500 and 0 < lattice.sum() < every.sum()
    assert not (lattice & ~every).any()  # it never replaces a faithful sample
    c = hybrid.summary()["lattice_check"]
    assert c["missed"] == lattice.sum() and c["samples"] >= 256 and c["missed_fraction"] == c["missed"] / c["samples"]
    assert hybrid.summary()["decided"] == evaluated.sum() + c["samples"]


def test_decision_points_of_interpolated_samples_are_decided():
    """The adaptive bake's face pass interpolates samples without evaluating any of them; its decision points
    (``decide``) are decided like evaluated samples, and the ring around an unfaithful one follows."""
    coarse = unwrap(ico(2), resolution=256)
    field = bumped_sphere_field()
    baker = Baker(coarse, 256)
    tx = baker.texels
    normals, valid = np.asarray(tx.normal, dtype=np.float64), np.ones(tx.n_samples, dtype=bool)
    evaluated = np.asarray(tx.points)[:, 2] < 0  # the cap is around +Z: no evaluated sample lies on it
    on_cap = np.flatnonzero(np.linalg.norm(np.asarray(tx.points) - (0.0, 0.0, R), axis=1) < 0.1)
    decide = evaluated.copy()
    decide[on_cap[::50]] = True
    without = HybridFallback(ico(5), field)
    missed = without(baker.mesh, tx, normals, valid, evaluated).replaced
    hybrid = HybridFallback(ico(5), field)
    found = hybrid(baker.mesh, tx, normals, valid, evaluated, decide=decide).replaced
    assert found[on_cap].sum() > 10 * max(1, missed[on_cap].sum())  # the cap, found through its decision points
    assert hybrid.summary()["decided"] > decide.sum()  # and the ring around them


@pytest.mark.parametrize("path", ["kernel", "numpy"])
@pytest.mark.parametrize("supersample", [1, 2])
@pytest.mark.parametrize("h, w, reach", [(40, 56, 16), (150, 170, 4)])
def test_ring_is_every_candidate_within_its_cell_side_of_a_seed(path, supersample, h, w, reach, rng, monkeypatch):
    """The ring around unfaithful nodes against brute force, by the C kernel (hybrid.c) and by numpy: Chebyshev
    distance in texels at most ⌈reach / s⌉ + 1, reach the candidate's own cell side (at most the hybrid's reach; the
    reach where the side is 0 or unknown). On the larger grid most blocks hold no seed: numpy's block test rules their
    candidates out."""
    from neural_bake.bake import hybrid as hybrid_module

    if path == "numpy":
        monkeypatch.setattr(hybrid_module.KERNEL, "lib", lambda: None)
    elif hybrid_module.KERNEL.lib() is None:
        pytest.skip(hybrid_module.kernel_status())
    pix = np.stack(np.meshgrid(np.arange(3, 3 + h), np.arange(w), indexing="ij"), axis=-1).reshape(-1, 2)
    texels = SimpleNamespace(pixel=pix, size=(h + 24, w), supersample=supersample)
    seeds = rng.choice(len(pix), 6, replace=False)
    candidates = np.setdiff1d(np.arange(len(pix)), seeds)
    side = rng.choice([0, 2, 4, 8, 16, 32], len(pix)).astype(np.int16)
    hybrid = HybridFallback(ico(1), sphere_field(), reach=reach)
    cheb = np.abs(pix[candidates, None, :] - pix[None, seeds, :]).max(axis=2).min(axis=1)
    for sides in (None, side):
        own = np.full(len(candidates), reach) if sides is None else np.where(
            sides[candidates] > 0, np.minimum(sides[candidates], reach), reach)
        expected = cheb <= -(-own // supersample) + 1
        found = hybrid._near(texels, seeds, candidates, sides)
        np.testing.assert_array_equal(found, expected)
        assert 0 < found.sum() < len(candidates)
    assert not hybrid._near(texels, seeds[:0], candidates, side).any()


@pytest.mark.parametrize("kwargs, message", [({"decide": "some"}, "decide"), ({"reach": 0}, "reach"),
                                             ({"reach": 2.5}, "reach"), ({"stride": 0}, "stride"),
                                             ({"stride": 1.5}, "stride"), ({"stride": True}, "stride"),
                                             ({"stride": 8, "reach": 4}, "stride"), ({"give_up_nodes": 0}, "give_up"),
                                             ({"give_up_nodes": 11}, "give_up"), ({"give_up_nodes": 7.5}, "give_up"),
                                             ({"give_up_nodes": True}, "give_up"),
                                             ({"detail_side": -1}, "detail_side"),
                                             ({"detail_side": 2.5}, "detail_side"),
                                             ({"detail_side": True}, "detail_side")])
def test_bad_decision_settings_raise(kwargs, message):
    with pytest.raises(NeuralBakeError, match=message):
        HybridFallback(ico(1), sphere_field(), **kwargs)


RED, BLUE = (0.8, 0.1, 0.1), (0.1, 0.1, 0.8)


def red_textured_sphere():
    """The fine sphere with UVs and a flat red texture: the source colour is red everywhere (a copy of one
    unwrap per test session: unwrapping 20k faces takes seconds)."""
    import dataclasses

    return dataclasses.replace(_unwrapped_fine_sphere(), texture=np.tile(np.array(RED, dtype=np.float32), (8, 8, 1)))


@functools.lru_cache(maxsize=1)
def _unwrapped_fine_sphere():
    return unwrap(ico(5), resolution=256)


def half_blue_texture():
    """Red on z > 0, blue below: faithful to the red source on the upper half only (ΔE red/blue ≫ 5)."""
    import torch

    from neural_bake.fields import TextureField

    red, blue = torch.tensor(RED), torch.tensor(BLUE)
    return TextureField(lambda p: torch.where((p[:, 2:3] > 0), red.to(p.dtype), blue.to(p.dtype)))


def test_colour_difference_is_ciede2000_of_the_srgb_colours():
    from skimage.color import deltaE_ciede2000, rgb2lab

    from neural_bake.bake.hybrid import colour_difference
    from neural_bake.io.colour import linear_to_srgb

    rng = np.random.default_rng(0)
    a, b = rng.random((50, 3)), rng.random((50, 3))
    assert np.array_equal(colour_difference(a, a), np.zeros(50))
    want = [deltaE_ciede2000(rgb2lab(linear_to_srgb(a[i: i + 1])), rgb2lab(linear_to_srgb(b[i: i + 1])))[0]
            for i in range(50)]
    np.testing.assert_allclose(colour_difference(a, b), want, rtol=1e-12)
    # an alpha channel is ignored; white against black is the lightness range, 100
    np.testing.assert_allclose(colour_difference(np.c_[a, np.zeros(50)], np.c_[b, np.ones(50)]), want, rtol=1e-12)
    assert abs(colour_difference(np.ones((1, 3)), np.zeros((1, 3)))[0] - 100.0) < 1e-6


@pytest.mark.parametrize("decide", ["all", "lattice"])
def test_unfaithful_colours_take_the_source_texture(decide):
    """Colours the texture field gets wrong (blue below the equator, the source is red) take the source's
    colour; faithful ones (red above) keep the field's; the lattice rule replaces what deciding every sample
    replaces; the normals of a faithful SDF are untouched."""
    from neural_bake.bake.adaptive import AdaptiveOptions

    coarse = unwrap(ico(2), resolution=128)
    field, tex = sphere_field(), half_blue_texture()
    hybrid = HybridFallback(red_textured_sphere(), field, color_tol=5.0, decide=decide)
    res = Baker(coarse, 96).bake(field, tex, hybrid=hybrid, adaptive=AdaptiveOptions())
    below = np.asarray(Baker(coarse, 96).texels.points)[:, 2] < 0
    assert res.replaced.sum() == 0  # the sphere SDF is exact: every normal is faithful
    # with colours no cell is given up on the source's normals alone, and no rim (a cell's colours may be faithful)
    assert not res.stats["adaptive"]["cells_source_detail"] and res.stats["adaptive"]["rim"] == 0
    np.testing.assert_array_equal(res.colors_replaced, below)
    np.testing.assert_allclose(res.colors, np.tile(RED, (len(below), 1)), atol=1e-6)
    np.testing.assert_allclose(res.neural_colors[below], np.tile(BLUE, (below.sum(), 1)), atol=1e-6)
    covered = res.coverage
    np.testing.assert_allclose(res.albedo[covered][:, :3], np.tile(RED, (covered.sum(), 1)), atol=1e-5)
    assert res.hybrid_color.sum() == res.stats["hybrid_color_texels"] > 0
    s = hybrid.summary()
    assert s["color_tol"] == 5.0 and s["color_replaced"] == below.sum()
    if decide == "lattice":
        assert s["lattice_check"]["missed"] == 0


def test_colours_untouched_without_a_colour_tolerance():
    coarse = unwrap(ico(2), resolution=128)
    field, tex = sphere_field(), half_blue_texture()
    res = Baker(coarse, 64).bake(field, tex, hybrid=HybridFallback(red_textured_sphere(), field))
    assert res.hybrid_color is None and res.colors_replaced is None and "hybrid_color_texels" not in res.stats
    below = np.asarray(Baker(coarse, 64).texels.points)[:, 2] < 0
    np.testing.assert_allclose(res.colors[below], np.tile(BLUE, (below.sum(), 1)), atol=1e-6)


@pytest.mark.parametrize("tol", [0.0, -1.0, float("nan")])
def test_bad_colour_tolerance_and_a_source_without_texture_raise(tol):
    with pytest.raises(NeuralBakeError, match="color_tol"):
        HybridFallback(red_textured_sphere(), sphere_field(), color_tol=tol)
    with pytest.raises(NeuralBakeError, match="UVs and a texture"):
        HybridFallback(ico(1), sphere_field(), color_tol=5.0)


def test_colour_psnr_of_known_srgb_offsets():
    from neural_bake.bake.hybrid import colour_psnr
    from neural_bake.io.colour import linear_to_srgb, srgb_to_linear

    rng = np.random.default_rng(1)
    srgb = rng.uniform(0.2, 0.8, size=(40, 3))
    offset = np.array([0.001, 0.01, 0.1, 0.0])  # the same sRGB offset on all three channels
    a = srgb_to_linear(srgb)
    for d in offset:
        got = colour_psnr(srgb_to_linear(srgb + d), a)
        want = np.full(40, np.inf) if d == 0 else np.full(40, -10 * np.log10(d * d))
        np.testing.assert_allclose(got, want, rtol=1e-9)
    assert np.allclose(linear_to_srgb(a), srgb)
    np.testing.assert_allclose(colour_psnr(np.c_[a, np.zeros(40)], np.c_[a, np.ones(40)]), np.inf)  # alpha ignored


def test_colour_psnr_rule_bounds_the_colours_psnr_against_the_source():
    """Colours off the red source by a small sRGB step above the equator (50 dB) and a large one below (30 dB):
    with a least PSNR of 40 dB the lower half takes the source's colour, the upper keeps the field's, and
    the hybrid colours' PSNR against the source's is at least 40 dB; with 55 dB every colour is replaced."""
    import torch

    from neural_bake.bake.hybrid import colour_psnr
    from neural_bake.fields import TextureField
    from neural_bake.io.colour import linear_to_srgb, srgb_to_linear

    red = linear_to_srgb(np.array([RED]))[0]
    up, down = (torch.tensor(srgb_to_linear(red + d)) for d in (10 ** (-50 / 20), 10 ** (-30 / 20)))
    tex = TextureField(lambda p: torch.where(p[:, 2:3] > 0, up.to(p.dtype), down.to(p.dtype)))
    coarse = unwrap(ico(2), resolution=128)
    field, fine = sphere_field(), red_textured_sphere()
    z = np.asarray(Baker(coarse, 64).texels.points)[:, 2]
    below, clear = z < 0, np.abs(z) > 0.02  # at the equator the field is read on either side
    hybrid = HybridFallback(fine, field, color_psnr=40.0)
    res = Baker(coarse, 64).bake(field, tex, hybrid=hybrid)
    np.testing.assert_array_equal(res.colors_replaced[clear], below[clear])
    source = np.tile(RED, (len(below), 1))
    mse = np.mean(10 ** (-colour_psnr(res.colors, source) / 10))
    assert -10 * np.log10(mse) >= 40.0 and hybrid.summary()["color_psnr"] == 40.0
    strict = Baker(coarse, 64).bake(field, tex, hybrid=HybridFallback(fine, field, color_psnr=55.0))
    assert strict.colors_replaced.all()
    np.testing.assert_allclose(strict.colors, source, atol=1e-6)


@pytest.mark.parametrize("psnr", [0.0, -3.0, float("nan"), float("inf")])
def test_bad_colour_psnr_raises(psnr):
    with pytest.raises(NeuralBakeError, match="color_psnr"):
        HybridFallback(red_textured_sphere(), sphere_field(), color_psnr=psnr)
    with pytest.raises(NeuralBakeError, match="UVs and a texture"):
        HybridFallback(ico(1), sphere_field(), color_psnr=40.0)


def _srgb_steps(steps, bits=8):
    """Linear colours (len(steps), 3): red's 8-bit sRGB value moved by ``steps`` (n, 3) quantisation steps."""
    from neural_bake.io.colour import linear_to_srgb, srgb_to_linear

    top = 2 ** bits - 1
    red = np.rint(linear_to_srgb(np.array([RED]))[0] * top)
    return srgb_to_linear((red + np.asarray(steps, dtype=np.float64)) / top)


def test_colour_budget_keeps_the_closest_colours_within_the_allowed_share_of_quantisation_noise():
    """1,000 colours against red: 800 equal after quantisation (free), 100 one step off in one channel, 100 two
    steps off. 0.5 dB allows 1000 × (10^0.05 − 1) / 12 steps² of summed mean-channel squared difference, i.e.
    30 one-step colours (each 1/3 step²): the equal ones stay, 30 one-step ones stay, the rest are replaced,
    larger differences first; the kept colours' MSE is within the budget; pre-replaced colours stay replaced."""
    from neural_bake.bake.hybrid import colour_budget
    from neural_bake.io.colour import linear_to_srgb

    steps = np.zeros((1000, 3))
    steps[:800] = 0.2 * np.random.default_rng(0).uniform(-1, 1, (800, 3))  # rounds to red's own value
    steps[800:900, 1] = 1.0
    steps[900:, 0] = -2.0
    a, b = _srgb_steps(steps), np.tile(RED, (1000, 1))
    out = colour_budget(a, b, 0.5)
    allowed = int(1000 * (10 ** 0.05 - 1) / 12 * 3)
    assert allowed == 30
    assert not out[:800].any() and out[900:].all() and (~out[800:900]).sum() == allowed
    d = np.rint(linear_to_srgb(np.where(out[:, None], b, a)) * 255) - np.rint(linear_to_srgb(b) * 255)
    assert np.mean(d ** 2) / 255 ** 2 <= (10 ** 0.05 - 1) / (12 * 255 ** 2)
    pre = np.zeros(1000, dtype=bool)
    pre[:10] = True
    again = colour_budget(a, b, 0.5, replaced=pre)
    assert again[:10].all() and (~again[800:900]).sum() == allowed
    # 0 dB (the bake's default): only the colours the map stores as the source's stay
    zero = colour_budget(a, b, 0.0)
    assert not zero[:800].any() and zero[800:].all()
    # at 16 bits the same colours are hundreds of steps apart: every colour off is replaced
    assert colour_budget(a, b, 0.5, bits=16)[800:].all()
    assert not colour_budget(a[:0], b[:0], 0.5).size


def test_colour_within_keeps_the_map_at_the_classical_transfers_psnr():
    """The field's colours equal the red source's 8-bit value above the equator and are 30 steps off below:
    with 0.5 dB the lower half takes the source's colour (its squared difference is far beyond the
    budget) and the upper keeps the field's; the map's PSNR against the source is then the transfer's."""
    import torch

    from neural_bake.fields import TextureField

    up, down = (torch.tensor(_srgb_steps([s])[0]) for s in ((0.1, 0.0, 0.0), (-30.0, 30.0, 30.0)))
    tex = TextureField(lambda p: torch.where(p[:, 2:3] > 0, up.to(p.dtype), down.to(p.dtype)))
    coarse = unwrap(ico(2), resolution=128)
    field, fine = sphere_field(), red_textured_sphere()
    z = np.asarray(Baker(coarse, 64).texels.points)[:, 2]
    below, clear = z < 0, np.abs(z) > 0.02
    hybrid = HybridFallback(fine, field, color_within=0.5, decide="all")
    res = Baker(coarse, 64).bake(field, tex, hybrid=hybrid)
    np.testing.assert_array_equal(res.colors_replaced[clear], below[clear])
    s = hybrid.summary()
    assert s["color_within"] == 0.5 and s["color_bits"] == 8 and s["color_within_replaced"] == res.colors_replaced.sum()
    q = lambda c: np.rint(np.clip(c, 0, 1) * 255) / 255  # noqa: E731
    from neural_bake.io.colour import linear_to_srgb

    np.testing.assert_array_equal(q(linear_to_srgb(res.colors)), q(linear_to_srgb(np.tile(RED, (len(z), 1)))))
    np.testing.assert_allclose(res.colors[below], np.tile(RED, (below.sum(), 1)), atol=1e-6)


@pytest.mark.parametrize("kwargs, message", [({"color_within": -0.5}, "color_within"),
                                             ({"color_within": float("inf")}, "color_within"),
                                             ({"color_within": float("nan")}, "color_within"),
                                             ({"color_within": 0.5, "color_bits": 12}, "color_bits")])
def test_bad_colour_within_raises(kwargs, message):
    with pytest.raises(NeuralBakeError, match=message):
        HybridFallback(red_textured_sphere(), sphere_field(), **kwargs)
    if "color_bits" not in kwargs:
        return
    with pytest.raises(NeuralBakeError, match="UVs and a texture"):
        HybridFallback(ico(1), sphere_field(), color_within=0.5)


def _analytic_band(field, baker):
    """f, unit ∇f and a valid mask at every texel sample of ``baker`` (its cached layout)."""
    import torch

    tx = baker.texels
    p = torch.as_tensor(np.asarray(tx.points), dtype=torch.float64).requires_grad_(True)
    f = field.fn(p)
    (g,) = torch.autograd.grad(f.sum(), p)
    g = g / g.norm(dim=1, keepdim=True)
    return tx, f.detach().numpy(), g.numpy(), np.ones(tx.n_samples, dtype=bool)


def test_first_order_estimate_spares_forward_passes_and_decides_alike(monkeypatch):
    """With f known at the texel points, f at the source points is estimated to first order where the ray is
    short and the estimate well inside the tolerance: the same samples are replaced as when f is evaluated at
    every source point, with the forward pass run at a fraction of them; the check finds no wrong estimate."""
    coarse = unwrap(ico(3), resolution=256)  # its faces lie within sdf_tol / 2 of the sphere
    field = bumped_sphere_field()
    baker = Baker(coarse, 128)
    tx, values, normals, valid = _analytic_band(field, baker)
    evaluated = np.ones(tx.n_samples, dtype=bool)
    exact = HybridFallback(ico(5), field)
    estimated = HybridFallback(ico(5), field)
    evaluated_points = []
    real = HybridFallback.field_values
    monkeypatch.setattr(HybridFallback, "field_values",
                        lambda self, pts: (evaluated_points.append(len(pts)) if self is estimated else None)
                        or real(self, pts))
    a = exact(baker.mesh, tx, normals, valid, evaluated)
    b = estimated(baker.mesh, tx, normals, valid, evaluated, values=values)
    assert a.replaced.sum() > 200
    np.testing.assert_array_equal(a.replaced, b.replaced)
    s = estimated.summary()["estimate_check"]
    assert s["estimated"] > 0.5 * tx.n_samples and sum(evaluated_points) < 0.5 * tx.n_samples
    assert s["samples"] >= 256 and s["missed"] == 0 and s["missed_fraction"] == 0.0
    assert exact.summary()["estimate_check"] == {"estimated": 0, "samples": 0, "missed": 0, "missed_fraction": None}


def test_estimate_check_catches_and_decides_a_wrong_estimate():
    """f values that put every texel point on the surface of a field that is far from the source: every
    estimate says faithful, the checked ones are evaluated, found far, counted as missed and replaced."""
    plank = thin_box()
    baker = Baker(unwrap(plank, resolution=128), 64)
    tx = baker.texels
    normals, valid = np.asarray(tx.normal, dtype=np.float64), np.ones(tx.n_samples, dtype=bool)
    hybrid = HybridFallback(plank, sphere_field(0.3))
    out = hybrid(baker.mesh, tx, normals, valid, np.ones(tx.n_samples, dtype=bool), values=np.zeros(tx.n_samples))
    s = hybrid.summary()["estimate_check"]
    assert s["samples"] >= 256 and s["missed"] > 0.5 * s["samples"]
    assert out.replaced.sum() == s["missed"] and s["estimated"] + s["samples"] == tx.n_samples


def test_ring_estimates_from_interpolated_values_within_a_quarter_of_the_tolerance(monkeypatch):
    """The interpolated samples the ring decides are estimated from the bake's f at their points, like the
    evaluated ones, but only where the estimate is under sdf_tol / 4: the same samples are replaced as with f
    evaluated at their source points, with fewer forward passes; with f known only at the evaluated samples
    (NaN elsewhere) the ring is evaluated as before."""
    coarse = unwrap(ico(3), resolution=256)
    field = bumped_sphere_field()
    baker = Baker(coarse, 128)
    tx, values, normals, valid = _analytic_band(field, baker)
    pix = np.asarray(tx.pixel)
    evaluated = (pix[:, 0] % 4 == 0) & (pix[:, 1] % 4 == 0)  # a lattice of nodes; the rest "interpolated"
    passes: dict[int, list[int]] = {}
    real = HybridFallback.field_values
    monkeypatch.setattr(HybridFallback, "field_values",
                        lambda self, pts: passes.setdefault(id(self), []).append(len(pts)) or real(self, pts))
    known_everywhere = HybridFallback(ico(5), field)
    known_at_nodes = HybridFallback(ico(5), field)
    a = known_everywhere(baker.mesh, tx, normals, valid, evaluated, values=values)
    b = known_at_nodes(baker.mesh, tx, normals, valid, evaluated, values=np.where(evaluated, values, np.nan))
    assert a.replaced.sum() > 100
    np.testing.assert_array_equal(a.replaced, b.replaced)
    sa, sb = known_everywhere.summary(), known_at_nodes.summary()
    assert sa["decided"] == sb["decided"] > evaluated.sum()  # the same ring
    ring_estimated = sa["estimate_check"]["estimated"] - sb["estimate_check"]["estimated"]
    assert ring_estimated > 100 and sum(passes[id(known_everywhere)]) < sum(passes[id(known_at_nodes)])
    assert sa["estimate_check"]["missed"] == 0
    # the quarter: a sample whose estimate lies between sdf_tol / 4 and sdf_tol / 2 is estimated at a half, not a quarter
    h = HybridFallback(ico(5), field)
    idx = np.flatnonzero(np.abs(values) < 1e-3)
    src = np.asarray(tx.points) + (0.3 * h.sdf_tol - values)[:, None] * normals  # first order: f(p) = 0.3·sdf_tol
    h._source_values(baker.mesh, tx, idx, src[idx], normals, values, valid, share=0.5)
    half = dict(h.estimate)
    assert half["estimated"] + half["samples"] == len(idx) > 500  # every one estimated (or checked)
    h._source_values(baker.mesh, tx, idx, src[idx], normals, values, valid, share=0.25)
    assert h.estimate == half  # none


def test_kept_rays_kernel_matches_numpy(monkeypatch):
    """The band's kept rays (normals, points, hit and the source's signed distance (x − p)·n, by rows): the C kernel
    writes what numpy does; a sample's rays are cast once, a second call casts none."""
    from neural_bake.bake import hybrid as hybrid_module

    if hybrid_module.KERNEL.lib() is None:
        pytest.skip(hybrid_module.kernel_status())
    coarse = unwrap(ico(2), resolution=128)
    tx = Baker(coarse, 64).texels
    idx = np.arange(0, tx.n_samples, 3)
    out = {}
    for path in ("kernel", "numpy"):
        hybrid = HybridFallback(rippled_sphere(), sphere_field())
        with monkeypatch.context() as mp:
            if path == "numpy":
                mp.setattr(hybrid_module.KERNEL, "lib", lambda: None)
            rays = hybrid._cached_rays(SimpleNamespace(base=None), coarse, tx)(idx)
        out[path] = rays
    k, n = out["kernel"], out["numpy"]
    for name in ("done", "hit", "normals", "points"):
        np.testing.assert_array_equal(getattr(k, name), getattr(n, name))
    np.testing.assert_allclose(k.values, n.values, rtol=0, atol=1e-15)  # the sum's rounding
    assert k.done.sum() == len(idx) and k.hit[idx].all()
    x = np.asarray(tx.points)[idx]
    assert np.abs(k.values[idx] - (np.linalg.norm(x, axis=1) - R)).max() < 0.002  # the rippled sphere's distance
    calls = []
    hybrid = HybridFallback(rippled_sphere(), sphere_field())
    classical = hybrid._cached_rays(SimpleNamespace(base=None), coarse, tx)
    classical(idx)
    monkeypatch.setattr(hybrid, "_cast_rays", lambda *a: calls.append(a))
    classical(idx[::2])
    assert calls == []
