"""Model files: round trips, and one clear ModelFileError for every kind of bad file."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import save_file

from neural_bake import __version__
from neural_bake.errors import ModelFileError
from neural_bake.fields import save_model
from neural_bake.nets.model_io import MODEL_FORMAT, load_model, read_model_metadata
from neural_bake.nets.siren import Siren
from neural_bake.types import Frame


def _siren(width=8, depth=2, in_dim=3, out_dim=1, seed=0, **kw):
    return Siren(width, depth, in_dim, out_dim, generator=torch.Generator().manual_seed(seed), **kw)


def _write_raw(path, tensors, header=None, fmt=MODEL_FORMAT):
    meta = {"format": fmt}
    if header is not None:
        meta["neural_bake"] = json.dumps(header)
    save_file(tensors, str(path), metadata=meta)
    return path


def _header(model, **changes):
    h = {"format": MODEL_FORMAT, "format_version": 1, "package_version": __version__,
         "architecture": model.architecture, "metadata": {}}
    h.update(changes)
    return h


@pytest.mark.parametrize("in_dim,out_dim,depth", [(3, 1, 0), (4, 1, 3), (3, 3, 1)])
def test_round_trip_exact(tmp_path, in_dim, out_dim, depth):
    model = _siren(12, depth, in_dim, out_dim, omega_0=17.5, hidden_omega=25.0)
    frame = Frame((0.5, -1.0, 2.0), 0.25)
    path = save_model(model, tmp_path / "f.safetensors", kind="sdf", frame=frame, delta=0.02,
                      config={"steps": 10, "lr": 1e-4, "layers": (1, 2)}, arr=np.arange(3), t=torch.tensor(1.5))
    assert path == tmp_path / "f.safetensors" and path.is_file()
    loaded, meta = load_model(path)
    assert loaded.architecture == model.architecture
    assert meta == {"kind": "sdf", "frame": frame.to_dict(), "delta": 0.02,
                    "config": {"steps": 10, "lr": 1e-4, "layers": [1, 2]}, "arr": [0, 1, 2], "t": 1.5}
    assert Frame.from_dict(meta["frame"]) == frame
    for (name, a), (_, b) in zip(model.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(a, b), name
    x = torch.rand(20, in_dim) * 2 - 1
    with torch.no_grad():
        assert torch.equal(model(x), loaded(x))
    assert not loaded.training
    header = read_model_metadata(path)
    assert header["format"] == MODEL_FORMAT and header["format_version"] == 1
    assert header["package_version"] == __version__ and header["architecture"] == model.architecture


def test_load_dtype_and_device(tmp_path):
    model = _siren().double()
    path = save_model(model, tmp_path / "d.safetensors")
    loaded, _ = load_model(path)
    assert loaded.layers[0].weight.dtype == torch.float64  # stored dtype kept by default
    loaded32, _ = load_model(path, dtype=torch.float32, device="cpu")
    assert loaded32.layers[0].weight.dtype == torch.float32
    assert torch.equal(loaded32.layers[1].weight, model.layers[1].weight.float())


def test_save_replaces_atomically_and_keeps_good_file_on_failure(tmp_path):
    path = tmp_path / "m.safetensors"
    save_model(_siren(seed=1), path, kind="sdf")
    good = path.read_bytes()
    with pytest.raises(ModelFileError, match=r"m.safetensors: metadata is not JSON-serialisable"):
        save_model(_siren(seed=2), path, bad=object())
    assert path.read_bytes() == good
    assert [p.name for p in tmp_path.iterdir()] == ["m.safetensors"]  # no temporary left behind
    save_model(_siren(seed=2), path, kind="texture")
    assert load_model(path)[1] == {"kind": "texture"}


def test_save_errors(tmp_path):
    with pytest.raises(ModelFileError, match=r"x.safetensors: metadata is not JSON-serialisable \(a NaN or infinite"):
        save_model(_siren(), tmp_path / "x.safetensors", delta=float("nan"))
    with pytest.raises(ModelFileError, match=r"x.safetensors: save_model expects a Siren, a GridNet or a TiledSdf, got Linear"):
        save_model(torch.nn.Linear(3, 1), tmp_path / "x.safetensors")
    with pytest.raises(ModelFileError, match=r"nope/x.safetensors: folder .*nope does not exist"):
        save_model(_siren(), tmp_path / "nope" / "x.safetensors")


def test_missing_and_directory(tmp_path):
    with pytest.raises(ModelFileError, match=r"absent.safetensors: no such model file"):
        load_model(tmp_path / "absent.safetensors")
    with pytest.raises(ModelFileError, match=r": not a file"):
        load_model(tmp_path)


def test_garbage_and_empty(tmp_path):
    p = tmp_path / "garbage.safetensors"
    p.write_bytes(b"this is not a model" * 10)
    with pytest.raises(ModelFileError, match=r"garbage.safetensors: not a readable model file"):
        load_model(p)
    p.write_bytes(b"")
    with pytest.raises(ModelFileError, match=r"garbage.safetensors: not a readable model file"):
        load_model(p)


@pytest.mark.parametrize("cut", [1, 8, 100, 0.5])
def test_truncated(tmp_path, cut):
    path = save_model(_siren(16, 2), tmp_path / "t.safetensors")
    data = path.read_bytes()
    keep = int(len(data) * cut) if isinstance(cut, float) else len(data) - cut
    path.write_bytes(data[:keep])
    with pytest.raises(ModelFileError, match=r"t.safetensors: (not a readable|corrupt or truncated) model file"):
        load_model(path)


def test_corrupted_tensor_bytes_give_nan_error(tmp_path):
    path = save_model(_siren(8, 1), tmp_path / "c.safetensors")
    data = bytearray(path.read_bytes())
    data[-4:] = np.array([np.nan], dtype=np.float32).tobytes()  # last float of the last tensor
    path.write_bytes(bytes(data))
    with pytest.raises(ModelFileError, match=r"c.safetensors: tensor layers\.\d\.\w+ holds NaN or infinite"):
        load_model(path)


def test_pickle_file_is_refused_without_running_it(tmp_path):
    path = tmp_path / "model.pt"
    torch.save(_siren().state_dict(), path)
    with pytest.raises(ModelFileError, match=r"model.pt: not a readable model file"):
        load_model(path)


def test_plain_safetensors_is_not_a_model(tmp_path):
    p = tmp_path / "plain.safetensors"
    save_file({"a": torch.zeros(3)}, str(p))
    with pytest.raises(ModelFileError, match=r"plain.safetensors: a safetensors file but not a neural_bake model"):
        load_model(p)


def test_mismatched_shapes(tmp_path):
    small, big = _siren(8, 2), _siren(16, 2)
    p = _write_raw(tmp_path / "mm.safetensors", big.state_dict(), _header(small))
    with pytest.raises(ModelFileError, match=r"mm.safetensors: tensor layers.0.weight has shape \(16, 3\), "
                                             r"the architecture needs \(8, 3\)"):
        load_model(p)


def test_missing_and_extra_tensors(tmp_path):
    model = _siren(8, 2)
    sd = dict(model.state_dict())
    del sd["layers.3.bias"]
    sd["extra"] = torch.zeros(2)
    p = _write_raw(tmp_path / "names.safetensors", sd, _header(model))
    with pytest.raises(ModelFileError, match=r"names.safetensors: tensors do not match the architecture "
                                             r"\(missing \['layers.3.bias'\], unexpected \['extra'\]\)"):
        load_model(p)


def test_integer_tensor_refused(tmp_path):
    model = _siren(4, 0)
    sd = {k: v.to(torch.int32) for k, v in model.state_dict().items()}
    p = _write_raw(tmp_path / "int.safetensors", sd, _header(model))
    with pytest.raises(ModelFileError, match=r"int.safetensors: tensor layers.0.weight has dtype torch.int32"):
        load_model(p)


@pytest.mark.parametrize(
    "change,message",
    [
        ({"format_version": 99}, r"model format version 99 is newer than this neural_bake reads \(2\)"),
        ({"format_version": "1"}, r"corrupt model header \(format_version '1'\)"),
        ({"architecture": {"width": 8}}, r"corrupt model header \(architecture"),
        ({"metadata": [1, 2]}, r"corrupt model header \(metadata is not a JSON object\)"),
    ],
)
def test_bad_headers(tmp_path, change, message):
    model = _siren(8, 2)
    p = _write_raw(tmp_path / "h.safetensors", model.state_dict(), _header(model, **change))
    with pytest.raises(ModelFileError, match=r"h.safetensors: " + message):
        load_model(p)


@pytest.mark.parametrize(
    "key,value,message",
    [
        ("width", -8, r"width = -8 is not a size in \[1, 4096\]"),
        ("depth", 1.5, r"depth = 1.5 is not a size in \[0, 32\]"),
        ("in_dim", True, r"in_dim = True is not a size in \[1, 8\]"),
        ("omega_0", -30.0, r"omega_0 = -30.0 is not a finite positive number"),
        ("hidden_omega", "30", r"hidden_omega = '30' is not a finite positive number"),
    ],
)
def test_bad_architecture_values(tmp_path, key, value, message):
    model = _siren(8, 2)
    arch = dict(model.architecture, **{key: value})
    p = _write_raw(tmp_path / "a.safetensors", model.state_dict(), _header(model, architecture=arch))
    with pytest.raises(ModelFileError, match=r"a.safetensors: corrupt model header \(" + message):
        load_model(p)


def test_header_not_json(tmp_path):
    p = tmp_path / "j.safetensors"
    save_file(_siren().state_dict(), str(p), metadata={"format": MODEL_FORMAT, "neural_bake": "{not json"})
    with pytest.raises(ModelFileError, match=r"j.safetensors: corrupt model header"):
        load_model(p)
    save_file(_siren().state_dict(), str(p), metadata={"format": MODEL_FORMAT, "neural_bake": "[1]"})
    with pytest.raises(ModelFileError, match=r"j.safetensors: corrupt model header \(not a JSON object\)"):
        load_model(p)


@dataclasses.dataclass
class _Config:
    steps: int = 3
    lr: float = 1e-4
    out: Path = Path("a/b")


def test_dataclass_and_path_metadata(tmp_path):
    path = save_model(_siren(), tmp_path / "cfg.safetensors", config=_Config(), f32=np.float32(0.5))
    assert load_model(path)[1] == {"config": {"steps": 3, "lr": 1e-4, "out": "a/b"}, "f32": 0.5}


# ------------------------------------------------------------------------------------------ grid networks
def _grid(seed=0, **kw):
    from neural_bake.nets.grid import GridNet

    args = dict(levels=3, features=2, log2_table=8, base_resolution=2, max_resolution=16, width=8, depth=1)
    net = GridNet(**{**args, **kw}, generator=torch.Generator().manual_seed(seed))
    with torch.no_grad():
        net.table.normal_(generator=torch.Generator().manual_seed(seed + 1))
    return net


@pytest.mark.parametrize("activation", ["relu", "sine"])
def test_grid_round_trip_exact_as_version_2(tmp_path, activation):
    from neural_bake.nets.grid import GridNet

    model = _grid(activation=activation, omega=2.5)
    path = save_model(model, tmp_path / "g.safetensors", kind="texture", delta=0.01)
    loaded, meta = load_model(path)
    assert isinstance(loaded, GridNet) and not loaded.training
    assert loaded.architecture == model.architecture and meta == {"kind": "texture", "delta": 0.01}
    assert list(loaded.state_dict()) == list(model.state_dict())
    for (name, a), (_, b) in zip(model.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(a, b), name
    x = torch.rand(50, 3) * 2 - 1
    with torch.no_grad():
        assert torch.equal(model(x), loaded(x))
    header = read_model_metadata(path)
    assert header["format_version"] == 2 and header["architecture"]["network"] == "grid"
    # a SIREN's file stays version 1: readers that know only SIRENs read it
    assert read_model_metadata(save_model(_siren(), tmp_path / "s.safetensors"))["format_version"] == 1
    loaded64, _ = load_model(path, dtype=torch.float64)
    assert loaded64.table.dtype == torch.float64 and torch.equal(loaded64.table, model.table.double())


def test_grid_with_normal_inputs_round_trips_with_its_scale(tmp_path):
    model = _grid(in_dim=6, normal_scale=0.3)
    path = save_model(model, tmp_path / "g.safetensors", kind="texture")
    loaded, _ = load_model(path)
    assert loaded.architecture == model.architecture and loaded.normal_scale == 0.3 and loaded.normal_inputs
    assert read_model_metadata(path)["architecture"]["in_dim"] == 6
    x = torch.cat([torch.rand(50, 3) * 2 - 1, torch.nn.functional.normalize(torch.randn(50, 3), dim=1)], dim=1)
    with torch.no_grad():
        assert torch.equal(model(x), loaded(x))


@pytest.mark.parametrize("change,message", [
    ({"network": "octree"}, r"network = 'octree' is not one of siren, grid"),
    ({"levels": 0}, r"corrupt model header \(levels: must be an integer in 1\.\.32, got 0\)"),
    ({"log2_table": 40}, r"corrupt model header \(log2_table: must be an integer in 4\.\.24, got 40\)"),
    ({"activation": "gelu"}, r"corrupt model header \(activation: must be one of relu, sine"),
    ({"width": 10**9}, r"corrupt model header \(width: must be an integer in 1\.\.4096"),
    ({"levels": True}, r"corrupt model header \(levels = True is not an integer\)"),
    ({"in_dim": 4}, r"a grid network maps R\^3 \(or R\^6 with surface normals\) to R\^1\.\.R\^16, this one R\^4 "
                    r"to R\^3"),
    ({"in_dim": 6}, r"normal_scale = None with in_dim 6: a number in \(0, 100\] with in_dim 6, absent with 3"),
    ({"normal_scale": 0.2}, r"normal_scale = 0\.2 with in_dim 3"),
    ({"in_dim": 6, "normal_scale": float("nan")}, r"normal_scale = nan with in_dim 6"),
    ({"in_dim": 6, "normal_scale": True}, r"normal_scale = True with in_dim 6"),
    ({"extra": 1}, r"corrupt model header \(architecture"),
])
def test_bad_grid_architectures(tmp_path, change, message):
    model = _grid()
    arch = {**model.architecture, **change}
    p = _write_raw(tmp_path / "g.safetensors", model.state_dict(),
                   _header(model, format_version=2, architecture=arch))
    with pytest.raises(ModelFileError, match=message) as err:
        load_model(p)
    assert "\n" not in str(err.value)


def test_grid_tensors_must_match_the_architecture(tmp_path):
    model = _grid()
    state = dict(model.state_dict(), table=torch.zeros(5, 2))
    p = _write_raw(tmp_path / "g.safetensors", state, _header(model, format_version=2))
    with pytest.raises(ModelFileError, match=r"tensor table has shape \(5, 2\), the architecture needs \(\d+, 2\)"):
        load_model(p)


# ------------------------------------------------------------------------------------------ tiled SDFs
def _tiled(seed=0):
    from neural_bake.nets.tiles import TiledSdf, TileGrid, TiledSiren

    gen = torch.Generator().manual_seed(seed)
    grid = TileGrid([-1.0, -1.0, -1.0], 0.5, 4, 0.1, [1, 5, 22, 63])
    return TiledSdf(Siren(8, 1, generator=gen), TiledSiren(grid, 8, 1, zero_output=False, generator=gen)).eval()


def test_tiled_sdf_round_trips_exactly_as_version_2(tmp_path):
    from neural_bake.nets.tiles import TiledSdf

    model = _tiled()
    p = save_model(model, tmp_path / "t.safetensors", kind="sdf")
    header = read_model_metadata(p)
    assert header["format_version"] == 2 and header["architecture"]["network"] == "tiles"
    assert header["architecture"]["tiles"]["grid"]["active"] == [1, 5, 22, 63]
    loaded, meta = load_model(p)
    assert isinstance(loaded, TiledSdf) and meta == {"kind": "sdf"}
    assert loaded.tiles.grid.to_dict() == model.tiles.grid.to_dict()
    x = torch.rand(300, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1
    assert torch.equal(model(x), loaded(x))


@pytest.mark.parametrize("change,message", [
    (lambda a: a["tiles"]["grid"].update(active=[1, 5, 22, 64]), r"tiles active = \[1, 5, 22, 64\]: 1 to 4096 "
                                                                  r"distinct cells in \[0, 64\)"),
    (lambda a: a["tiles"]["grid"].update(active=[1, 1, 5, 22]), r"tiles active"),
    (lambda a: a["tiles"]["grid"].update(grid=65), r"tiles grid = 65 is not a size in \[1, 64\]"),
    (lambda a: a["tiles"]["grid"].update(margin=0.5), r"tiles margin = 0\.5 is not in \(0, 0\.25\] cells"),
    (lambda a: a["tiles"]["grid"].update(cell=-1.0), r"tiles cell = -1\.0 is not a positive length"),
    (lambda a: a["tiles"]["grid"].update(origin=[0.0, float("nan"), 0.0]), r"tiles origin = .* is not 3 finite"),
    (lambda a: a["tiles"].update(width=0), r"tiles width = 0 is not a size in \[1, 4096\]"),
    (lambda a: a["coarse"].update(in_dim=4), r"the coarse level maps R\^4 to R\^1, a tiled SDF's R\^3 to R"),
    (lambda a: a.pop("coarse"), r"corrupt model header \(architecture"),
    (lambda a: a["tiles"].pop("grid"), r"corrupt model header \(tiles \{"),
])
def test_bad_tiled_architectures(tmp_path, change, message):
    model = _tiled()
    arch = json.loads(json.dumps(model.architecture))
    change(arch)
    p = _write_raw(tmp_path / "t.safetensors", model.state_dict(), _header(model, format_version=2, architecture=arch))
    with pytest.raises(ModelFileError, match=rf"t\.safetensors: .*{message}") as err:
        load_model(p)
    assert "\n" not in str(err.value)


def test_tiled_tensors_must_match_the_architecture(tmp_path):
    model = _tiled()
    state = dict(model.state_dict())
    state["tiles.weights.0"] = torch.zeros(3, 8, 3)  # three tiles' weights for four active cells
    p = _write_raw(tmp_path / "t.safetensors", state, _header(model, format_version=2))
    with pytest.raises(ModelFileError, match=r"tensor tiles\.weights\.0 has shape \(3, 8, 3\), the architecture "
                                             r"needs \(4, 8, 3\)"):
        load_model(p)
