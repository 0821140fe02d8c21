"""Residual fine-level SDF construction: band-only supervision on a sphere, sums of SIRENs and their normals."""

import numpy as np
import pytest
import torch
import trimesh

import neural_bake.fit.sdf as sdf_module
from neural_bake.errors import FitError
from neural_bake.fit.residual import COARSE_OMEGA_0, CONSTRUCTIONS, ResidualSdfFit, fit_sdf_construction
from neural_bake.fit.sdf import SdfFit, fit_sdf, load_sdf
from neural_bake.fit.sdf_pools import band_pools
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.nets.gemm import gemm_gradient
from neural_bake.nets.siren import Siren
from neural_bake.nets.siren_sum import siren_sum

R = 0.7
TINY = dict(width=32, depth=1, omega_0=15.0, lr=1e-3, batch=512, batch_near=512, batch_uniform=128, pool_surface=4000,
            pool_near=4000, pool_uniform=1000, progress=False, log_every=10)


def sphere(r=R, sub=3):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=r)
    return mesh_from_arrays(np.asarray(m.vertices), np.asarray(m.faces), normalise=False)


def random_siren(width, depth, omega_0, seed, dtype=torch.float32):
    return Siren(width, depth, omega_0=omega_0, generator=torch.Generator().manual_seed(seed)).to(dtype)


def test_residual_level_trains_only_inside_the_coarse_band(fit_sphere_siren, monkeypatch):
    h = fit_sphere_siren(r=R, steps=300)
    band = 0.05
    seen = []
    real = sdf_module.sdf_step_backward

    def spy(loss_fn, model, sp, sn, vp, vd, cfg, **kwargs):
        seen.append((sp, vp, kwargs["base"]))
        return real(loss_fn, model, sp, sn, vp, vd, cfg, **kwargs)

    monkeypatch.setattr(sdf_module, "sdf_step_backward", spy)
    fit = fit_sdf(sphere(), steps=40, seed=0, base=h, band=band, hard_fraction=0.0, **TINY)
    assert len(seen) == 40 and fit.distance_error is None
    for sp, vp, (sv, sg, vv, vg) in seen:
        for pts, values, grads in ((sp, sv, sg), (vp, vv, vg)):
            assert pts.shape[0] > 0
            hv, hg = gemm_gradient(h, pts)
            assert float(hv.abs().max()) < band  # every training point inside |h| < δ
            torch.testing.assert_close(values, hv[:, 0])  # the coarse level's values and gradients beside them
            torch.testing.assert_close(grads, hg)
        # the sphere's oracle: the band around h's zero set is the shell | |x| − R | ≲ δ
        assert float((vp.norm(dim=1) - R).abs().max()) < band + 0.02
    # the sum still fits the sphere: |h + r| on the sphere stays within the band, and h + r vanishes there
    x = torch.nn.functional.normalize(torch.randn(2000, 3, generator=torch.Generator().manual_seed(3)), dim=1) * R
    with torch.no_grad():
        total = h(x)[:, 0] + fit.model(x)[:, 0]
    assert float(total.abs().max()) < band
    assert float(total.abs().mean()) < 0.01


def test_band_pools_keep_the_band_and_refuse_an_empty_one(fit_sphere_siren):
    h = fit_sphere_siren(r=R, steps=300)
    gen = torch.Generator().manual_seed(0)
    cube = torch.rand(20000, 3, generator=gen) * 2 - 1
    surf = torch.nn.functional.normalize(torch.randn(500, 3, generator=gen), dim=1)
    data = {"surf_p": surf * R, "surf_n": surf, "vol_p": cube, "vol_d": cube.norm(dim=1) - R, "n_near": 5000}
    kept = band_pools(h, 0.05)(data)
    assert kept["surf_p"].shape[0] == 500
    assert 0 < kept["vol_p"].shape[0] < 0.2 * cube.shape[0]  # a thin shell of the cube
    inside = (h(cube)[:, 0].abs() < 0.05)
    assert kept["n_near"] == int(inside[:5000].sum()) and kept["vol_p"].shape[0] == int(inside.sum())
    with pytest.raises(FitError, match="no surface sample lies in the band"):
        band_pools(h, 0.05)(dict(data, surf_p=surf * 0.1))


def test_residual_construction_splits_the_steps_and_saves_the_sum(tmp_path, monkeypatch):
    from neural_bake.fit.sdf_pools import _Pools

    draws = []
    real = _Pools._sample
    monkeypatch.setattr(_Pools, "_sample", lambda self, idx: draws.append(idx) or real(self, idx))
    fit = fit_sdf_construction(sphere(), "residual", steps=40, coarse_width=16, coarse_share=0.25,
                               **dict(TINY, omega_0=30.0))
    assert draws == [0]  # one pool drawn from the mesh, shared by both levels
    assert isinstance(fit, ResidualSdfFit) and fit.label == "16x1+32x1"
    # a smooth coarse level (ω0 15) under the fine one's ω0: the sum rescales its first layer
    assert (fit.coarse.model.omega_0, fit.fine.omega_0, fit.model.omega_0) == (COARSE_OMEGA_0, 30.0, 30.0)
    assert fit.coarse.steps == 10 and fit.steps == 30 and fit.band == pytest.approx(4.0 * fit.coarse.distance_error)
    x = torch.rand(500, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1
    with torch.no_grad():
        torch.testing.assert_close(fit.model(x), fit.coarse.model(x) + fit.fine(x), rtol=1e-5, atol=1e-5)
    back = load_sdf(fit.save(tmp_path / "sum.sdf"))  # the sum is an ordinary SDF file
    assert isinstance(back, SdfFit) and back.model.width == 48
    with torch.no_grad():
        torch.testing.assert_close(back.model(x), fit.model(x))


def test_warm_start_begins_as_the_coarse_level():
    fit = fit_sdf_construction(sphere(), "residual-warm", steps=20, coarse_width=16, **TINY)
    assert fit.label == "16x1→32x1" and fit.band is None and fit.fine is None and fit.model.width == 32
    h = fit.coarse.model
    fresh = random_siren(16, 1, 15.0, 5)
    with torch.no_grad():
        fresh.layers[-1].weight.zero_()
        fresh.layers[-1].bias.zero_()
        x = torch.rand(200, 3) * 2 - 1
        torch.testing.assert_close(siren_sum(h, fresh)(x), h(x), rtol=1e-5, atol=1e-6)


def test_bad_constructions_and_residual_settings_are_refused(fit_sphere_siren):
    assert CONSTRUCTIONS == ("plain", "residual", "residual-warm")
    with pytest.raises(FitError, match="unknown SDF construction 'nested'"):
        fit_sdf_construction(sphere(), "nested", steps=2, **TINY)
    with pytest.raises(FitError, match="coarse_share must be in"):
        fit_sdf_construction(sphere(), "residual", steps=2, coarse_share=1.0, **TINY)
    with pytest.raises(FitError, match="warm start needs coarse_width below"):
        fit_sdf_construction(sphere(), "residual-warm", steps=2, coarse_width=32, **TINY)
    h = fit_sphere_siren(r=R, steps=300)
    with pytest.raises(FitError, match="needs a positive band"):
        fit_sdf(sphere(), steps=2, base=h, hard_fraction=0.0, **TINY)
    with pytest.raises(FitError, match="does not support hard_fraction"):
        fit_sdf(sphere(), steps=2, base=h, band=0.05, **dict(TINY, hard_fraction=0.25))
    with pytest.raises(FitError, match="band is the residual level's band"):
        fit_sdf(sphere(), steps=2, band=0.05, **TINY)
    with pytest.raises(FitError, match="init must be a Siren of width 32"):
        fit_sdf(sphere(), steps=2, init=random_siren(16, 1, 15.0, 0), **TINY)
