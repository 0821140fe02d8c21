"""USD/USDZ writers: Pixar's validators pass on what they write, the stage reads back as written (points,
faces, UVs, normals, the texture bindings and the bytes of the maps), time samples per frame, one-line errors,
the missing extra, and atomic replacement."""

import errno
import sys
import zipfile

import numpy as np
import pytest

from neural_bake.errors import MissingExtraError, NeuralBakeError, OutputError
from neural_bake.io import usd as usd_io
from neural_bake.io.images import write_image
from neural_bake.io.usd import NORMAL_MAP_BIAS, NORMAL_MAP_SCALE, StageOptions, write_usd, write_usd_frames

pxr = pytest.importorskip("pxr", reason="usd-core (the extra usd) is in the test extras")
from pxr import Sdf, Usd, UsdGeom, UsdShade, UsdValidation  # noqa: E402

#: The shader nodes ARKit's USDZ rules allow.
ARKIT_SHADERS = {"UsdPreviewSurface", "UsdUVTexture", "UsdPrimvarReader_float2"}


def validation_errors(path) -> list[str]:
    """Every error of every validator usd-core registers (the checks behind ``usdchecker``) on ``path``."""
    registry = UsdValidation.ValidationRegistry()
    context = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    return [f"{e.GetName()}: {e.GetMessage()}" for e in context.Validate(Usd.Stage.Open(str(path)))]


def arkit_problems(path) -> list[str]:
    """ARKit's USDZ rules: only preview-surface shader nodes, PNG/JPEG textures, everything inside the package,
    the stage first, entries stored uncompressed at 64-byte aligned offsets."""
    out = []
    stage = Usd.Stage.Open(str(path))
    for prim in stage.Traverse():
        if prim.IsA(UsdShade.Shader):
            sid = UsdShade.Shader(prim).GetIdAttr().Get()
            if sid not in ARKIT_SHADERS:
                out.append(f"{prim.GetPath()}: shader {sid}")
    with zipfile.ZipFile(path) as z:
        infos = z.infolist()
        if not infos[0].filename.endswith((".usdc", ".usda")):
            out.append(f"first entry {infos[0].filename}")
        for info in infos:
            data_start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
            if info.compress_type != zipfile.ZIP_STORED or data_start % 64:
                out.append(f"{info.filename}: compressed or unaligned")
            if not info.filename.endswith((".usdc", ".usda", ".png", ".jpg", ".jpeg")):
                out.append(f"{info.filename}: not an allowed file type")
    return out


def bumpy_grid(n=6):
    """A (n×n)-vertex height field over [0, 1]² with per-vertex UVs = (x, y) and its analytic unit normals."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="xy")
    z = 0.1 * np.sin(3 * x) * np.cos(2 * y)
    pts = np.stack([x, y, z], -1).reshape(-1, 3)
    nrm = np.stack([-0.3 * np.cos(3 * x) * np.cos(2 * y), 0.2 * np.sin(3 * x) * np.sin(2 * y), np.ones_like(x)], -1)
    nrm = (nrm / np.linalg.norm(nrm, axis=-1, keepdims=True)).reshape(-1, 3)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return pts, faces, pts[:, :2].copy(), nrm


@pytest.fixture
def maps(tmp_path):
    rng = np.random.default_rng(0)
    albedo, normal = tmp_path / "albedo.png", tmp_path / "normal.png"
    write_image(albedo, rng.random((8, 8, 3)).astype(np.float32), colour="srgb", bits=8)
    write_image(normal, rng.random((8, 8, 3)).astype(np.float32), colour="data", bits=8)
    return albedo, normal


def read_mesh(stage, time=Usd.TimeCode.Default()):
    mesh = UsdGeom.Mesh(stage.GetDefaultPrim().GetChild("mesh"))
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(time))
    faces = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(time)).reshape(-1, 3)
    return mesh, np.asarray(mesh.GetPointsAttr().Get(time)), counts, faces


def bound_textures(mesh) -> dict:
    """{surface input: (UsdUVTexture shader, its file's resolved path)} of the mesh's bound preview surface."""
    material, _ = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()
    surface = material.ComputeSurfaceSource()[0]
    assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
    out = {}
    for name in ("diffuseColor", "normal"):
        inp = surface.GetInput(name)
        if inp and inp.HasConnectedSource():
            tex = UsdShade.Shader(inp.GetConnectedSources()[0][0].source.GetPrim())
            out[name] = (tex, tex.GetInput("file").Get().resolvedPath)
    return out


@pytest.mark.parametrize("suffix", [".usd", ".usda", ".usdz"])
def test_stage_passes_the_validators_and_reads_back_as_written(tmp_path, maps, suffix):
    pts, faces, uv, nrm = bumpy_grid()
    pts = pts * 3.0 + [10.0, -2.0, 0.5]  # source units, off the origin
    albedo, normal = maps
    path = write_usd(tmp_path / f"asset{suffix}", pts, faces, uv=uv, normals=nrm, base_colour=albedo,
                     normal_map=normal)
    assert validation_errors(path) == []
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    mesh, p, counts, f = read_mesh(stage)
    np.testing.assert_allclose(p, pts, rtol=1e-6)
    assert (counts == 3).all() and np.array_equal(f, faces)
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.vertex and st.GetTypeName() == Sdf.ValueTypeNames.TexCoord2fArray
    np.testing.assert_allclose(np.asarray(st.Get()), uv, atol=1e-7)
    assert mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    np.testing.assert_allclose(np.asarray(mesh.GetNormalsAttr().Get()), nrm, atol=1e-6)
    assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    tex = bound_textures(mesh)
    base, base_file = tex["diffuseColor"]
    norm, norm_file = tex["normal"]
    assert base.GetInput("sourceColorSpace").Get() == "sRGB" and norm.GetInput("sourceColorSpace").Get() == "raw"
    assert tuple(norm.GetInput("scale").Get()) == NORMAL_MAP_SCALE == (2, 2, 2, 1)
    assert tuple(norm.GetInput("bias").Get()) == NORMAL_MAP_BIAS == (-1, -1, -1, 0)
    if suffix == ".usdz":  # the package holds the very files baked
        assert arkit_problems(path) == []
        with zipfile.ZipFile(path) as z:
            assert z.read("albedo.png") == albedo.read_bytes() and z.read("normal.png") == normal.read_bytes()
        assert base_file.endswith("[albedo.png]") and norm_file.endswith("[normal.png]")
    else:  # the stage references the files beside it
        assert base_file == str(albedo) and norm_file == str(normal)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["albedo.png", "normal.png", f"asset{suffix}"])


def test_the_validators_can_fail(tmp_path, maps):
    """A normal map read as sRGB, and a stage without its units, are caught by the validators the tests run."""
    pts, faces, uv, nrm = bumpy_grid()
    path = write_usd(tmp_path / "asset.usda", pts, faces, uv=uv, normals=nrm, normal_map=maps[1])
    stage = Usd.Stage.Open(str(path))
    tex = bound_textures(UsdGeom.Mesh(stage.GetDefaultPrim().GetChild("mesh")))["normal"][0]
    tex.GetInput("sourceColorSpace").Set("sRGB")
    stage.GetRootLayer().pseudoRoot.ClearInfo("metersPerUnit")
    stage.Save()
    errors = " ".join(validation_errors(path))
    assert "MissingMetersPerUnitMetadata" in errors and "sourceColorSpace" in errors


def test_frames_are_time_samples_of_points_topology_normals_and_colours(tmp_path):
    rng = np.random.default_rng(1)
    frames = []
    for n in (4, 6, 5):  # the topology differs from frame to frame
        pts, faces, _, nrm = bumpy_grid(n)
        frames.append({"points": pts + rng.normal(size=3), "faces": faces, "normals": nrm,
                       "colours": rng.random((len(pts), 3))})
    path = write_usd_frames(tmp_path / "frames.usd", frames, fps=12.5, times=[0.0, 0.5, 1.0])
    assert validation_errors(path) == []
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == 12.5 == stage.GetFramesPerSecond()
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 2)
    assert list(stage.GetRootLayer().customLayerData["neural_bake:times"]) == [0.0, 0.5, 1.0]
    for i, fr in enumerate(frames):
        mesh, p, counts, f = read_mesh(stage, Usd.TimeCode(i))
        np.testing.assert_allclose(p, fr["points"], rtol=1e-6, atol=1e-6)
        assert (counts == 3).all() and np.array_equal(f, fr["faces"])
        np.testing.assert_allclose(np.asarray(mesh.GetNormalsAttr().Get(i)), fr["normals"], atol=1e-6)
        colour = mesh.GetDisplayColorPrimvar()
        assert colour.GetInterpolation() == UsdGeom.Tokens.vertex
        np.testing.assert_allclose(np.asarray(colour.Get(i)), fr["colours"], atol=1e-6)


def test_missing_usd_core_is_one_line_and_writes_nothing(tmp_path, maps, monkeypatch):
    monkeypatch.setitem(sys.modules, "pxr", None)  # `from pxr import …` raises ImportError, as without usd-core
    pts, faces, uv, nrm = bumpy_grid()
    with pytest.raises(MissingExtraError, match=r"^USD output needs usd-core: pip install 'neural-bake\[usd\]'"):
        write_usd(tmp_path / "a.usd", pts, faces, uv=uv)
    with pytest.raises(MissingExtraError):
        write_usd_frames(tmp_path / "f.usd", [{"points": pts, "faces": faces}])
    assert MissingExtraError.exit_code == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["albedo.png", "normal.png"]


@pytest.mark.parametrize("suffix", [".usd", ".usdz"])
def test_a_failed_write_keeps_the_good_file_and_leaves_nothing(tmp_path, maps, monkeypatch, suffix):
    pts, faces, uv, nrm = bumpy_grid()
    path = write_usd(tmp_path / f"a{suffix}", pts, faces, uv=uv, normals=nrm, base_colour=maps[0])
    good = path.read_bytes()

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(usd_io, "_material", disk_full)
    with pytest.raises(OSError, match="No space left"):
        write_usd(path, pts * 2, faces, uv=uv, normals=nrm, base_colour=maps[0])
    assert path.read_bytes() == good
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["albedo.png", "normal.png", f"a{suffix}"])


def test_bad_input_is_one_line_naming_the_parameter(tmp_path, maps):
    pts, faces, uv, nrm = bumpy_grid()
    cases = [
        (dict(path=tmp_path / "a.obj"), "path .*: expected a file ending in .usd, .usda, .usdc, .usdz", "path"),
        (dict(points=pts[:, :2]), r"points: must have shape \(N, 3\), got \(36, 2\)", "points"),
        (dict(faces=faces + 100), "faces: an index outside the 36 points", "faces"),
        (dict(normals=nrm[:3]), r"normals: must have shape \(36, 3\)", "normals"),
        (dict(uv=uv * np.nan), "uv: holds NaN", "uv"),
        (dict(base_colour=tmp_path / "none.png"), "base_colour .*none.png: no such image file", "base_colour"),
        (dict(uv=None, normal_map=maps[1]), "normal_map: a texture map needs uv", "normal_map"),
        (dict(options=StageOptions(up_axis="X")), "up_axis 'X': must be Y or Z", "up_axis"),
        (dict(options=StageOptions(meters_per_unit=0.0)), "meters_per_unit 0.0: must be a positive length", "meters_per_unit"),
        (dict(options=StageOptions(name="a b")), "name 'a b': must be a prim name", "name"),
    ]
    for change, message, parameter in cases:
        args = dict(path=tmp_path / "a.usd", points=pts, faces=faces, uv=uv, normals=nrm) | change
        with pytest.raises(NeuralBakeError, match=message) as info:
            write_usd(args.pop("path"), args.pop("points"), args.pop("faces"), **args)
        assert info.value.parameter == parameter and "\n" not in str(info.value)
    with pytest.raises(OutputError, match="does not exist"):
        write_usd(tmp_path / "missing" / "a.usd", pts, faces)
    with pytest.raises(NeuralBakeError, match="fps 0: must be a positive number"):
        write_usd_frames(tmp_path / "f.usd", [{"points": pts, "faces": faces}], fps=0)
    with pytest.raises(NeuralBakeError, match="frames: give at least one frame"):
        write_usd_frames(tmp_path / "f.usd", [])
    with pytest.raises(NeuralBakeError, match="name 'a b': must be a prim name"):
        write_usd_frames(tmp_path / "f.usd", [{"points": pts, "faces": faces}], options=StageOptions(name="a b"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["albedo.png", "normal.png"]
