"""Nested sequences whose fine SDF is a tiled one (a coarse SIREN and its tiles): the difference bound that
certifies δ, distillation, the file (format version 2) and the renderer."""

import copy

import pytest
import torch

from neural_bake.errors import ModelFileError
from neural_bake.fields import load_field, save_field
from neural_bake.fit.nested import NestedSequence, fit_nested
from neural_bake.nets.range_analysis import difference_bound
from neural_bake.nets.siren import Siren
from neural_bake.nets.tiles import TiledSdf, TileGrid, TiledSiren
from neural_bake.types import Frame

SMALL = dict(steps=120, pool=8000, batch=1024, eval_every=40, eval_samples=2000, n_estimate=5000,
             stability_samples=(500,), stability_bands=(0.1,), max_boxes=2000, progress=False)


@pytest.fixture(scope="module")
def tiled(fit_sphere_siren):
    """The fitted sphere SIREN and a small random tile level on it (a few hundredths of a unit)."""
    gen = torch.Generator().manual_seed(2)
    tiles = TiledSiren(TileGrid([-0.8, -0.8, -0.8], 0.4, 4, 0.1, torch.arange(64)), 8, 1, omega_0=6.0,
                       hidden_omega=6.0, zero_output=False, generator=gen)
    with torch.no_grad():
        tiles.weights[-1].mul_(0.1)
        tiles.biases[-1].mul_(0.1)
    return TiledSdf(fit_sphere_siren(), tiles).eval()


@pytest.mark.parametrize("order", ["siren-tiled", "tiled-siren"])
def test_difference_bound_with_a_tiled_sdf_holds(tiled, order):
    h = Siren(16, 1, generator=torch.Generator().manual_seed(3)).eval()
    a, b = (h, tiled) if order == "siren-tiled" else (tiled, h)
    gen = torch.Generator().manual_seed(4)
    c = torch.rand(40, 3, generator=gen) * 1.6 - 0.8
    axes = torch.diag_embed(torch.full((40, 3), 0.06))
    lo, hi = difference_bound(a, b, c, axes)
    x = c[:, None, :] + (torch.rand(40, 300, 3, generator=gen) * 2 - 1) * 0.06
    with torch.no_grad():
        d = (a(x.reshape(-1, 3)) - b(x.reshape(-1, 3)))[:, 0].reshape(40, -1)
    assert bool((d >= lo[:, None]).all() and (d <= hi[:, None]).all())


def test_a_tiled_fine_sdf_nests_saves_loads_and_renders(tiled, tmp_path):
    from neural_bake.render.load import load_asset

    seq = fit_nested(tiled, levels=[(8, 0)], **SMALL)
    assert isinstance(seq, NestedSequence) and seq.levels[-1] is tiled and isinstance(seq.levels[0], Siren)
    info = seq.levels_info[0]
    assert info["sup_certified"] >= info["sup_estimated"] > 0  # the certified bound holds over the samples'
    seq.frame = Frame((0.0, 0.0, 0.0), 0.5)
    path = tmp_path / "n.nested"
    save_field(seq, path)
    again = load_field(path)
    assert isinstance(again.levels[-1], TiledSdf) and again.header()["format_version"] == 2
    x = torch.rand(500, 3) * 2 - 1
    assert torch.equal(again.levels[-1](x), tiled(x)) and torch.equal(again.levels[0](x), seq.levels[0](x))
    assert again.deltas == pytest.approx(seq.deltas)
    asset = load_asset(path)
    assert [lv.name for lv in asset.levels] == ["h1 (8,0)", f"f {tiled.label}"]
    assert asset.levels[1].bound is not None and asset.levels[0].delta == pytest.approx(seq.deltas[0])
    # a tiled level is the fine one only
    bad = tmp_path / "bad.nested"
    save_field(NestedSequence(levels=[tiled, copy.deepcopy(tiled.coarse)], frame=seq.frame, levels_info=seq.levels_info[-2:],
                              band=seq.band, eps=seq.eps), bad)
    with pytest.raises(ModelFileError, match=r"bad\.nested: corrupt model header \(level 0 architecture"):
        load_field(bad)
