"""Item 3: a header is validated before anything is allocated or computed: one line naming the file and the
field, exit 2 from the CLI, never a TypeError, KeyError, RecursionError or MemoryError traceback."""

import json

import pytest
import torch
from safetensors.torch import save_file

from neural_bake.cli.main import main
from neural_bake.errors import ModelFileError
from neural_bake.fields import load_field, save_field
from neural_bake.fields.nested import NESTED_FORMAT, NestedSequence
from neural_bake.nets.model_io import MODEL_FORMAT, json_depth
from neural_bake.nets.siren import Siren
from neural_bake.types import Frame


def _write(path, *, arch=None, meta=None, raw_header=None):
    """A model file whose header is a valid SDF's with ``arch`` / ``meta`` entries replaced (tensors of the
    valid (8, 1) network: a bad header must be refused before they are looked at)."""
    model = Siren(8, 1, generator=torch.Generator().manual_seed(0))
    header = {"format": MODEL_FORMAT, "format_version": 1, "package_version": "0.1.0",
              "architecture": {**model.architecture, **(arch or {})},
              "metadata": {"kind": "sdf", "frame": {"center": [0.0, 0.0, 0.0], "scale": 1.0}, "delta": 0.01,
                           **(meta or {})}}
    text = raw_header if raw_header is not None else json.dumps(header)  # allow_nan: NaN/Infinity tokens
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(path),
              metadata={"format": MODEL_FORMAT, "neural_bake": text})
    return path


CASES = [
    # (id, arch, meta, message)
    ("depth 1e7", {"depth": 10_000_000}, None, r"depth = 10000000 is not a size in \[0, 32\]"),
    ("width 1e9", {"width": 1_000_000_000}, None, r"width = 1000000000 is not a size in \[1, 4096\]"),
    ("centre as an int", None, {"frame": {"center": 5, "scale": 1.0}}, r"frame\.center = 5 is not a finite 3-vector"),
    ("delta as a string", None, {"delta": "0.1"}, r"delta = '0\.1' is not a finite number >= 0"),
    ("scale 0", None, {"frame": {"center": [0, 0, 0], "scale": 0}}, r"frame\.scale = 0 is not a finite positive number"),
    ("scale -1", None, {"frame": {"center": [0, 0, 0], "scale": -1}},
     r"frame\.scale = -1 is not a finite positive number"),
    ("scale NaN", None, {"frame": {"center": [0, 0, 0], "scale": float("nan")}},
     r"frame\.scale = nan is not a finite positive number"),
    ("centre inf", None, {"frame": {"center": [0, float("inf"), 0], "scale": 1.0}},
     r"frame\.center = \[0, inf, 0\] is not a finite 3-vector"),
    ("omega_0 0", {"omega_0": 0.0}, None, r"omega_0 = 0\.0 is not a finite positive number"),
    ("negative delta", None, {"delta": -0.5}, r"delta = -0\.5 is not a finite number >= 0"),
    ("centre of 2", None, {"frame": {"center": [0, 0], "scale": 1.0}}, r"frame\.center = \[0, 0\] is not a finite"),
    ("unknown kind", None, {"kind": "volume"}, r"unknown kind 'volume'"),
    ("kind not a string", None, {"kind": [1]}, r"unknown kind \[1\]"),
]


@pytest.mark.parametrize("arch,meta,message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_header_is_one_line_naming_file_and_field(tmp_path, arch, meta, message):
    path = _write(tmp_path / "bad.sdf", arch=arch, meta=meta)
    with pytest.raises(ModelFileError, match=r"^" + str(tmp_path).replace(".", r"\.") + r"/bad\.sdf: .*" + message):
        load_field(path)


def test_deep_json_header_is_refused_before_parsing(tmp_path):
    deep = '{"a": ' * 100_000 + "1" + "}" * 100_000
    assert json_depth(deep) == 100_000
    assert json_depth('{"a": "[[[[{{{{", "b": [1, {"c": "\\"[["}]}') == 3  # brackets in strings do not count
    path = _write(tmp_path / "deep.sdf", raw_header=deep)
    with pytest.raises(ModelFileError, match=r"deep\.sdf: corrupt model header \(JSON nested 100000 deep, at most 32\)"):
        load_field(path)
    # in the metadata of a valid header too
    model_header = {"format": MODEL_FORMAT, "format_version": 1, "package_version": "0.1.0",
                    "architecture": Siren(8, 1).architecture, "metadata": {"kind": "sdf"}}
    text = json.dumps(model_header)[:-1] + ', "x": ' + "[" * 50_000 + "]" * 50_000 + "}"
    with pytest.raises(ModelFileError, match=r"deep2\.sdf: corrupt model header \(JSON nested 50001 deep"):
        load_field(_write(tmp_path / "deep2.sdf", raw_header=text))


def test_nested_headers_are_checked_too(tmp_path):
    levels = [Siren(8, 0), Siren(8, 1)]
    seq = NestedSequence(levels=levels, frame=Frame(), levels_info=[{"delta": 0.02}, {"delta": 0.001}])
    good = seq.header()
    tensors = {f"levels.{i}.{k}": v.contiguous() for i, m in enumerate(levels) for k, v in m.state_dict().items()}

    def write(**change):
        p = tmp_path / "s.nested"
        save_file(tensors, str(p), metadata={"format": NESTED_FORMAT, "neural_bake": json.dumps({**good, **change})})
        return p

    cases = [
        ({"frame": {"center": [0, 0, 0], "scale": -1}}, r"frame\.scale = -1 is not a finite positive number"),
        ({"architectures": [{**levels[0].architecture, "width": 10**9}, levels[1].architecture]},
         r"level 0 width = 1000000000 is not a size"),
        ({"architectures": [levels[0].architecture] * 17}, r"architectures is not a list of 1 to 16 levels"),
        ({"levels_info": [{"delta": "big"}, {"delta": 0.001}]}, r"levels_info\[0\]\.delta = 'big' is not a finite"),
        ({"levels_info": [{"delta": 0.02}]}, r"levels_info is not one object per level \(2\)"),
        ({"band": float("nan")}, r"band = nan is not a finite positive number"),
        ({"format_version": 7}, r"version 7 is newer"),
        ({"kind": "sdf"}, r"unknown kind 'sdf'"),
    ]
    for change, message in cases:
        with pytest.raises(ModelFileError, match=r"s\.nested: .*" + message):
            load_field(write(**change))
    assert isinstance(load_field(write()), NestedSequence)


@pytest.mark.parametrize("arch,meta,message", [CASES[i][1:] for i in (0, 2, 4, 6)],
                         ids=[CASES[i][0] for i in (0, 2, 4, 6)])
def test_cli_exit_code_2_and_one_line(tmp_path, capsys, arch, meta, message):
    from neural_bake.samples.generate import sample_path

    path = _write(tmp_path / "bad.sdf", arch=arch, meta=meta)
    for argv in (["bake", str(sample_path("sphere")), "--sdf", str(path), "-o", str(tmp_path / "out")],
                 ["fit", "texture", str(sample_path("sphere")), "--sdf", str(path), "-o", str(tmp_path / "t.tex"),
                  "--steps", "1", "--no-progress", "--no-metrics"]):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2, err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        assert "bad.sdf" in err
    assert not (tmp_path / "out").exists() and not (tmp_path / "t.tex").exists()


def test_a_valid_header_still_loads(tmp_path):
    f = load_field(_write(tmp_path / "ok.sdf"))
    assert f.delta == 0.01 and f.frame == Frame() and f.model.width == 8
    assert load_field(save_field(f, tmp_path / "again.sdf")).delta == 0.01
