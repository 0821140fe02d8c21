"""One loader and one writer: every field type round-trips, old files load, bad headers are one-line errors."""

import json

import numpy as np
import pytest
import torch
from safetensors.torch import save_file

from neural_bake.cli.main import main
from neural_bake.errors import ModelFileError
from neural_bake.fields import (KINDS, NestedSequence, SdfField, TextureField, load_field, load_sdf_field,
                                register_kind, save_field, save_model, to_sdf_field)
from neural_bake.fields.nested import NESTED_FORMAT
from neural_bake.io.colour import srgb_to_linear
from neural_bake.nets.model_io import MODEL_FORMAT
from neural_bake.nets.siren import Siren
from neural_bake.types import Frame

FRAME = Frame((0.5, -1.0, 2.0), 0.25)


def _net(w=8, d=1, out=1, seed=0, in_dim=3):
    return Siren(w, d, in_dim=in_dim, out_dim=out, generator=torch.Generator().manual_seed(seed))


def _sequence():
    levels = [_net(8, 0, seed=1), _net(8, 1, seed=2), _net(16, 1, seed=3)]
    info = [{"width": m.width, "depth": m.depth, "delta": d, "delta_source": s, "delta_estimated": d,
             "delta_certified": None} for m, d, s in zip(levels, (0.05, 0.02, 0.001), ("estimated", "certified", "eps"))]
    return NestedSequence(levels=levels, frame=FRAME, levels_info=info, band=0.1, eps=0.001)


def _same(a, b):
    x = torch.rand(64, 3, generator=torch.Generator().manual_seed(5)) * 2 - 1
    with torch.no_grad():
        return torch.equal(a(x), b(x))


def test_sdf_and_texture_fields_round_trip(tmp_path):
    f = SdfField.from_model(_net(), frame=FRAME, delta=0.01, metadata={"delta_source": "given", "note": [1, 2]})
    back = load_field(save_field(f, tmp_path / "f.sdf"))
    assert isinstance(back, SdfField) and back.frame == FRAME and back.delta == 0.01 and back.name == "f.sdf"
    assert back.metadata["note"] == [1, 2] and back.metadata["kind"] == "sdf" and _same(back.model, f.model)
    against = {"name": "f.sdf", "kind": "nested", "delta": 0.05}
    g = TextureField.from_model(_net(out=3), frame=FRAME, delta=0.05, fitted_against=against)
    back = load_field(save_field(g, tmp_path / "g.tex"))
    assert isinstance(back, TextureField) and back.fitted_against == against and back.delta == 0.05
    assert _same(back.model, g.model) and back.encoding == "linear"
    # a network of sRGB-encoded colours: the file says so and the field decodes them, in float32 and float64
    h = TextureField.from_model(_net(out=3), frame=FRAME, delta=0.05, encoding="srgb")
    back = load_field(save_field(h, tmp_path / "h.tex"))
    assert back.encoding == "srgb" and back.metadata["encoding"] == "srgb"
    for dtype in (torch.float32, torch.float64):
        x = torch.rand(64, 3, dtype=dtype) * 2 - 1
        with torch.no_grad():
            raw = back.model.to(dtype)(x).clamp(0, 1).double().numpy()
        assert np.allclose(back.color(x).double().numpy(), srgb_to_linear(raw), atol=1e-6 if dtype == torch.float64
                           else 1e-5)


def test_nested_sequence_round_trip_and_views(tmp_path):
    seq = _sequence()
    back = load_field(save_field(seq, tmp_path / "s.nested"))
    assert isinstance(back, NestedSequence) and back.frame == FRAME and back.deltas == [0.05, 0.02, 0.001]
    assert back.name == "s.nested" and back.in_dim == 3
    assert all(_same(a, b) for a, b in zip(seq.levels, back.levels))
    lv = back.level(1)
    assert isinstance(lv, SdfField) and lv.model is back.levels[1] and lv.delta == 0.02 and lv.frame == FRAME
    assert back.finest.model is back.levels[-1] and back.finest.delta == 0.001
    band = to_sdf_field(back)  # what bake and fit texture use: f's normals, the widest band
    assert band.model is back.levels[-1] and band.delta == 0.05
    assert load_sdf_field(tmp_path / "s.nested", band_level=1).delta == 0.02
    with pytest.raises(ModelFileError, match=r"s\.nested: no level 3 \(the sequence has levels 0\.\.2\)"):
        back.level(3)
    assert NestedSequence.load(tmp_path / "s.nested").deltas == back.deltas


def test_files_of_the_first_release_load(tmp_path):
    # a nested-sequence file as the first release wrote it: no "kind" in its header
    seq = _sequence()
    header = {k: v for k, v in seq.header().items() if k != "kind"}
    tensors = {f"levels.{i}.{k}": v.contiguous() for i, m in enumerate(seq.levels) for k, v in m.state_dict().items()}
    save_file(tensors, str(tmp_path / "old.nested"), metadata={"format": NESTED_FORMAT, "neural_bake": json.dumps(header)})
    old = load_field(tmp_path / "old.nested")
    assert isinstance(old, NestedSequence) and old.deltas == seq.deltas
    # a model file as SdfFit.save / TextureFit.save wrote them
    sdf = load_field(save_model(_net(), tmp_path / "old.sdf", kind="sdf", frame=FRAME.to_dict(), config={"steps": 3}))
    tex = load_field(save_model(_net(out=3), tmp_path / "old.tex", kind="texture", frame=FRAME.to_dict(), delta=0.03))
    assert isinstance(sdf, SdfField) and sdf.delta is None and isinstance(tex, TextureField) and tex.delta == 0.03
    assert tex.encoding == "linear"  # written before the encoding was recorded: linear colours
    with pytest.raises(ModelFileError, match=r"bad\.tex: encoding = 'gamma' is not one of linear, srgb"):
        load_field(save_model(_net(out=3), tmp_path / "bad.tex", kind="texture", frame=FRAME.to_dict(),
                              encoding="gamma"))


def test_bare_network_says_how_to_save_a_fit(tmp_path):
    path = save_model(_net(), tmp_path / "bare.safetensors")
    with pytest.raises(ModelFileError, match=r"bare\.safetensors: a bare network without kind or frame; save a "
                                             r"fitted SDF with SdfFit\.save\(path\)"):
        load_field(path)
    # the way out the message gives: the network with its frame
    f = load_field(save_field(SdfField.from_model(_net(), frame=FRAME), tmp_path / "framed.sdf"))
    assert f.frame == FRAME


def test_unknown_kind_and_foreign_files_are_refused(tmp_path):
    with pytest.raises(ModelFileError, match=r"x\.sdf: unknown kind 'sdf4d' \(this neural_bake reads nested, sdf, "
                                             r"spacetime_sdf, texture\)"):
        load_field(save_model(_net(in_dim=4), tmp_path / "x.sdf", kind="sdf4d", frame=FRAME.to_dict()))
    save_file({"a": torch.zeros(2)}, str(tmp_path / "plain.safetensors"))
    with pytest.raises(ModelFileError, match=r"plain\.safetensors: a safetensors file but not a neural_bake field"):
        load_field(tmp_path / "plain.safetensors")
    with pytest.raises(ModelFileError, match=r"nothing\.sdf: no such model file"):
        load_field(tmp_path / "nothing.sdf")


def test_a_space_time_kind_slots_in_without_changing_callers(tmp_path):
    from neural_bake.fields.files import _read_network

    class SpaceTimeField(SdfField):
        pass

    def read(path, header, *, device=None, dtype=None):
        return SpaceTimeField.from_model(_read_network(path, header, device, dtype), name=path.name)

    register_kind("sdf4d", MODEL_FORMAT, read, SpaceTimeField)
    try:
        f = load_field(save_model(_net(in_dim=4), tmp_path / "t.sdf4d", kind="sdf4d", frame=FRAME.to_dict()))
        assert isinstance(f, SpaceTimeField) and f.in_dim == 4
        v, g = f.value_and_gradient(torch.rand(10, 4))
        assert v.shape == (10,) and g.shape == (10, 4)
    finally:
        KINDS.pop("sdf4d")


def test_a_kind_fixes_the_networks_inputs(tmp_path):
    """kind "sdf" is static (x, y, z): a 4-input network labelled so is refused on load, by every reader."""
    save_model(_net(in_dim=4), tmp_path / "st.sdf", kind="sdf", frame=FRAME.to_dict())
    for read in (load_field, load_sdf_field):
        with pytest.raises(ModelFileError, match=r"st\.sdf: kind 'sdf' is a static SDF mapping R\^3 \(x, y, z\) to R, "
                                                 r"this network maps R\^4 to R\^1 \(a space-time SDF is kind "
                                                 r"'spacetime_sdf', with its time range\)$"):
            read(tmp_path / "st.sdf")
    with pytest.raises(ModelFileError, match=r"five\.sdf: kind 'sdf' is a static SDF mapping R\^3 \(x, y, z\) to R, "
                                             r"this network maps R\^5 to R\^1$"):
        load_field(save_model(_net(in_dim=5), tmp_path / "five.sdf", kind="sdf", frame=FRAME.to_dict()))


def test_a_texture_reads_points_or_a_grid_networks_points_and_normals(tmp_path):
    from neural_bake.nets.grid import GridNet

    with pytest.raises(ModelFileError, match=r"six\.tex: a texture maps R\^3 \(or a grid network's points and "
                                             r"normals, R\^6\) to RGB\(A\), this network maps R\^6 to R\^3$"):
        load_field(save_model(_net(in_dim=6, out=3), tmp_path / "six.tex", kind="texture", frame=FRAME.to_dict()))
    grid = GridNet(levels=2, log2_table=6, base_resolution=2, max_resolution=8, width=8, in_dim=6)
    tex = load_field(save_model(grid, tmp_path / "sided.tex", kind="texture", frame=FRAME.to_dict()))
    assert tex.normal_inputs and "normal inputs" in repr(tex)


def test_a_nested_sequence_of_space_time_levels_needs_its_time_mapping(tmp_path):
    from neural_bake.fields import NestedSequence, time_mapping

    levels = [_net(in_dim=4), _net(in_dim=4)]
    info = [{"delta": 0.05}, {"delta": 0.001}]
    NestedSequence(levels=levels, frame=FRAME, levels_info=info).save(tmp_path / "bare.nested")
    with pytest.raises(ModelFileError, match=r"bare\.nested: levels of 4 inputs \(x, y, z, t\) but no time mapping"):
        load_field(tmp_path / "bare.nested")
    huge = {"spacetime": {"time_range": [0.0, 1.0], "time_extent": 1e308}}
    NestedSequence(levels=levels, frame=FRAME, levels_info=info, metadata=huge).save(tmp_path / "huge.nested")
    with pytest.raises(ModelFileError, match=r"huge\.nested: metadata\.spacetime: time_extent = 1e\+308 is larger "
                                             r"than 1e\+30"):
        load_field(tmp_path / "huge.nested")
    ok = {"spacetime": {"time_range": [2.0, 3.0], "time_extent": 1.0}}
    NestedSequence(levels=levels, frame=FRAME, levels_info=info, metadata=ok).save(tmp_path / "ok.nested")
    assert time_mapping(load_field(tmp_path / "ok.nested"))[0] == (2.0, 3.0)


def test_save_field_errors(tmp_path):
    with pytest.raises(ModelFileError, match=r"a\.sdf: analytic is an analytic field; only fitted networks"):
        save_field(SdfField(lambda p: p[:, 0]), tmp_path / "a.sdf")
    with pytest.raises(ModelFileError, match=r"b\.sdf: siren has no frame; give the frame"):
        save_field(SdfField.from_model(_net()), tmp_path / "b.sdf")
    with pytest.raises(ModelFileError, match=r"c\.sdf: save_field expects an SdfField, TextureField or NestedSequence"):
        save_field(_net(), tmp_path / "c.sdf")
    with pytest.raises(ModelFileError, match=r"folder .*nope does not exist"):
        save_field(_sequence(), tmp_path / "nope" / "s.nested")
    with pytest.raises(ModelFileError, match=r"d\.sdf: metadata is not JSON-serialisable"):
        save_field(SdfField.from_model(_net(), frame=FRAME, metadata={"x": float("nan")}), tmp_path / "d.sdf")
    assert not list(tmp_path.iterdir())  # nothing half-written


def test_kind_of_the_other_type_is_named(tmp_path):
    tex = save_field(TextureField.from_model(_net(out=3), frame=FRAME), tmp_path / "t.tex")
    with pytest.raises(ModelFileError, match=r"t\.tex: a TextureField file, expected an SDF model file"):
        load_sdf_field(tex)
    with pytest.raises(ModelFileError, match=r"a TextureField, expected an SDF"):
        to_sdf_field(load_field(tex))


def test_bake_refuses_a_bare_network_with_the_hint(tmp_path, capsys):
    from neural_bake.samples.generate import sample_path

    path = save_model(_net(), tmp_path / "bare.safetensors")
    code = main(["bake", str(sample_path("sphere")), "--sdf", str(path), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "SdfFit.save(path)" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_fit_records_read_the_fits_from_the_header(tmp_path):
    from neural_bake.fields import fit_records, save_model

    hist = [{"step": 1, "seconds": 0.1, "loss": 2.0}, {"step": 2, "seconds": 0.2, "loss": 1.0}]
    p = save_model(Siren(8, 1), tmp_path / "m.sdf", kind="sdf", frame=FRAME.to_dict(),
                   training={"steps": 2, "seconds": 0.2, "history": hist})
    (rec,) = fit_records(p)
    assert rec["fit"] == "model" and rec["training"]["steps"] == 2 and rec["training"]["history"] == hist
    seq = _sequence()
    seq.metadata = {"fine_training": {"steps": 9, "history": hist}}
    seq.save(tmp_path / "s.nested")
    recs = fit_records(tmp_path / "s.nested")
    assert [r["fit"] for r in recs] == ["fine"] + ["level"] * len(seq.levels)
    assert recs[0]["training"]["steps"] == 9 and [r["level"] for r in recs[1:]] == list(range(len(seq.levels)))
    assert recs[1]["width"] == seq.levels_info[0]["width"]
    (tmp_path / "x.safetensors").write_bytes(b"not a model")
    with pytest.raises(ModelFileError):
        fit_records(tmp_path / "x.safetensors")


def _grid_net(out=3):
    from neural_bake.nets.grid import GridNet

    net = GridNet(levels=3, features=2, log2_table=8, base_resolution=2, max_resolution=16, width=8, depth=1,
                  out_dim=out, generator=torch.Generator().manual_seed(5))
    with torch.no_grad():
        net.table.normal_(generator=torch.Generator().manual_seed(6))
    return net


def test_grid_texture_round_trips_and_reads_colours(tmp_path):
    from neural_bake.nets.grid import GridNet

    net = _grid_net()
    tex = TextureField.from_model(net, frame=FRAME, delta=0.02, name="g", encoding="srgb",
                                  fitted_against={"name": "f", "kind": "sdf", "delta": 0.02, "surface": [[0, 0, 0.9]]})
    path = save_field(tex, tmp_path / "g.tex")
    back = load_field(path)
    assert isinstance(back, TextureField) and isinstance(back.model, GridNet)
    assert back.frame == FRAME and back.delta == 0.02 and back.encoding == "srgb"
    assert back.fitted_against["surface"] == [[0, 0, 0.9]]
    x = torch.rand(64, 3) * 2 - 1
    assert torch.equal(back.color(x), tex.color(x))
    with torch.no_grad():
        np.testing.assert_array_equal(tex.color(x).numpy(), srgb_to_linear(net(x).clamp(0, 1)).numpy())
    # no reduced precision for a grid network: fp32 (auto included), bf16 refused naming the parameter
    same, resolved, why = back.with_precision("auto")
    assert same is back and resolved == "fp32" and "GridNet" in why
    with pytest.raises(Exception, match=r"precision bf16: a GridNet has no reduced-precision path") as err:
        back.with_precision("bf16")
    assert err.value.parameter == "precision"


def test_grid_network_is_not_an_sdf(tmp_path):
    path = save_model(_grid_net(out=1), tmp_path / "g.sdf", kind="sdf", frame=FRAME.to_dict(), delta=0.01)
    with pytest.raises(ModelFileError, match=r"g.sdf: kind 'sdf' is a SIREN or a tiled SDF \(their normals are GEMM gradients\), "
                                             r"this file holds a grid network"):
        load_field(path)
