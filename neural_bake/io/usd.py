"""USD and USDZ files of a baked asset, written with Pixar's usd-core (the optional extra ``usd``).

:func:`write_usd` writes one mesh with UVs, normals and a ``UsdPreviewSurface`` material (base-colour and
tangent-space normal map) as a ``.usd``/``.usda``/``.usdc`` stage that references the map files beside it, or
as a ``.usdz`` package that holds them. :func:`write_usd_frames` writes frames of per-vertex bakes as one
stage with time samples. Both take a :class:`StageOptions` (the stage's unit, up axis and prim name) and write
atomically (:mod:`neural_bake.io.atomic`): a failed write replaces nothing. Without usd-core they raise
:class:`~neural_bake.errors.MissingExtraError` saying how to install it.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ..errors import MissingExtraError, NeuralBakeError, OutputError
from .atomic import atomic_path

__all__ = ["USD_SUFFIXES", "USD_INSTALL", "import_pxr", "usd_available", "StageOptions", "write_usd", "write_usd_frames",
           "NORMAL_MAP_SCALE", "NORMAL_MAP_BIAS"]

#: File suffixes :func:`write_usd` writes: a stage (crate, text, crate) or a package.
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")

#: How to install what these writers need.
USD_INSTALL = "pip install 'neural-bake[usd]' (Pixar's usd-core)"

#: UsdUVTexture scale and bias that decode a normal map stored as (n + 1) / 2 into n (UsdPreviewSurface spec).
NORMAL_MAP_SCALE = (2.0, 2.0, 2.0, 1.0)
NORMAL_MAP_BIAS = (-1.0, -1.0, -1.0, 0.0)


@dataclass(frozen=True)
class StageOptions:
    """What a stage states besides its geometry; checked by the writers (one-line NeuralBakeError naming the
    field)."""

    meters_per_unit: float = 1.0
    """The stage's linear unit: metres per unit of the points (positive)."""
    up_axis: str = "Y"
    """The stage's up axis: "Y" or "Z"."""
    name: str = "neural_bake"
    """The root prim (the stage's default prim), and the name of the material; the mesh is ``/<name>/mesh``."""


def import_pxr() -> SimpleNamespace:
    """The pxr modules the writers use (Usd, UsdGeom, UsdShade, UsdUtils, Sdf, Gf, Vt, Kind).

    Raises :class:`~neural_bake.errors.MissingExtraError` (one line, how to install it) without usd-core.
    """
    try:
        from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdShade, UsdUtils, Vt
    except ImportError:
        raise MissingExtraError(f"USD output needs usd-core: {USD_INSTALL}") from None
    return SimpleNamespace(Gf=Gf, Kind=Kind, Sdf=Sdf, Usd=Usd, UsdGeom=UsdGeom, UsdShade=UsdShade,
                           UsdUtils=UsdUtils, Vt=Vt)


def usd_available() -> bool:
    """Whether usd-core is installed (the writers here can run)."""
    try:
        import_pxr()
    except MissingExtraError:
        return False
    return True


def _array(name: str, a, cols: int, rows: int | None = None, dtype=np.float64) -> np.ndarray:
    """``a`` as a finite (rows, cols) array; NeuralBakeError naming ``name`` otherwise."""
    arr = np.asarray(a, dtype=dtype)
    if arr.ndim != 2 or arr.shape[1] != cols or (rows is not None and arr.shape[0] != rows):
        want = f"({rows if rows is not None else 'N'}, {cols})"
        raise NeuralBakeError(f"{name}: must have shape {want}, got {arr.shape}", parameter=name)
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise NeuralBakeError(f"{name}: holds NaN or infinite values", parameter=name)
    return arr


def _check_mesh(points, faces, what: str = "") -> tuple[np.ndarray, np.ndarray]:
    pts = _array("points", points, 3)
    tri = _array("faces", faces, 3, dtype=np.int64)
    if tri.shape[0] == 0:
        raise NeuralBakeError(f"faces: {what}no faces to write", parameter="faces")
    if tri.min() < 0 or tri.max() >= len(pts):
        raise NeuralBakeError(f"faces: {what}an index outside the {len(pts)} points", parameter="faces")
    return pts, tri


def _check_destination(path: Path, suffixes: tuple[str, ...]) -> None:
    if path.suffix.lower() not in suffixes:
        raise NeuralBakeError(f"path {path}: expected a file ending in {', '.join(suffixes)}", parameter="path")
    if str(path.parent) and not path.parent.is_dir():
        raise OutputError(f"{path}: folder {path.parent} does not exist")


def _check_options(options: StageOptions | None) -> StageOptions:
    """``options`` (default :class:`StageOptions`) with every field checked."""
    options = StageOptions() if options is None else options
    mpu, up_axis, name = options.meters_per_unit, options.up_axis, options.name
    if not (np.isfinite(mpu) and mpu > 0):
        raise NeuralBakeError(f"meters_per_unit {mpu!r}: must be a positive length", parameter="meters_per_unit")
    if up_axis not in ("Y", "Z"):
        raise NeuralBakeError(f"up_axis {up_axis!r}: must be Y or Z", parameter="up_axis")
    if not name.isidentifier():
        raise NeuralBakeError(f"name {name!r}: must be a prim name (letters, digits, _)", parameter="name")
    return options


def _new_stage(px, options: StageOptions):
    """An in-memory stage stating ``options``, with its root prim (the default prim, a component) and an empty
    polygon mesh ``/<name>/mesh`` (no subdivision: its normals are used as given; right-handed): ``(stage,
    mesh)``."""
    stage = px.Usd.Stage.CreateInMemory()
    root = px.UsdGeom.Xform.Define(stage, f"/{options.name}").GetPrim()
    px.UsdGeom.SetStageMetersPerUnit(stage, float(options.meters_per_unit))
    px.UsdGeom.SetStageUpAxis(stage, px.UsdGeom.Tokens.y if options.up_axis == "Y" else px.UsdGeom.Tokens.z)
    stage.SetDefaultPrim(root)
    px.Usd.ModelAPI(root).SetKind(px.Kind.Tokens.component)
    mesh = px.UsdGeom.Mesh.Define(stage, f"/{options.name}/mesh")
    mesh.CreateSubdivisionSchemeAttr(px.UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(px.UsdGeom.Tokens.rightHanded)
    return stage, mesh


def _export_stage(stage, path: Path) -> None:
    """Write ``stage``'s root layer to ``path`` atomically, in the format its suffix names."""
    with atomic_path(path) as tmp:
        if not stage.GetRootLayer().Export(str(tmp), args=_format_args(path)):
            raise OSError(f"{path}: usd-core could not write the stage")


def _vec3f(px, a: np.ndarray):
    return px.Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32))


def _extent(px, pts: np.ndarray):
    return px.Vt.Vec3fArray([px.Gf.Vec3f(*map(float, pts.min(axis=0))), px.Gf.Vec3f(*map(float, pts.max(axis=0)))])


def write_usd(
    path,
    points,
    faces,
    *,
    uv=None,
    normals=None,
    base_colour=None,
    normal_map=None,
    options: StageOptions | None = None,
) -> Path:
    """Write a baked mesh and its maps as a USD stage or a USDZ package at ``path`` (atomically); return it.

    Args:
        path: ``.usd``/``.usdc`` (binary crate), ``.usda`` (text) or ``.usdz`` (a package holding the stage
            and the map files, made by ``UsdUtils.CreateNewARKitUsdzPackage``).
        points: (V, 3) positions in the source frame (the units ``meters_per_unit`` states).
        faces: (F, 3) vertex indices, counter-clockwise seen from outside (USD's right-handed orientation).
        uv: (V, 2) per-vertex UVs (the mesh split at UV seams), v = 0 at the image's bottom row, written as
            ``primvars:st`` with vertex interpolation; needed by the maps.
        normals: (V, 3) unit vertex normals (vertex interpolation); None: none written.
        base_colour: path of the base-colour PNG (sRGB-encoded), read by a ``UsdUVTexture`` with
            ``sourceColorSpace = sRGB`` into ``diffuseColor`` (its alpha, if any, into ``opacity``).
        normal_map: path of the tangent-space normal map PNG, OpenGL convention (+Y green up), stored as
            (n + 1) / 2 linear data: read with ``sourceColorSpace = raw``, scale :data:`NORMAL_MAP_SCALE` and
            bias :data:`NORMAL_MAP_BIAS` into ``normal``. USD has no tangent attribute: a renderer rebuilds
            the tangent frame from ``st`` and the normals.
        options: the stage's unit, up axis and prim name (default :class:`StageOptions`).

    A stage references each map by its path relative to ``path`` (keep them beside it); a package copies
    them in. Raises :class:`~neural_bake.errors.MissingExtraError` without usd-core,
    :class:`NeuralBakeError` (naming the parameter) for arrays of the wrong shape, maps without ``uv``, a map
    file that does not exist, another suffix or a bad option; :class:`~neural_bake.errors.OutputError` for a
    missing folder.
    """
    path = Path(path)
    _check_destination(path, USD_SUFFIXES)
    pts, tri = _check_mesh(points, faces)
    uv_a = None if uv is None else _array("uv", uv, 2, len(pts))
    nrm = None if normals is None else _array("normals", normals, 3, len(pts))
    maps = {k: Path(v) for k, v in (("base_colour", base_colour), ("normal_map", normal_map)) if v is not None}
    for key, file in maps.items():
        if not file.is_file():
            raise NeuralBakeError(f"{key} {file}: no such image file", parameter=key)
        if uv_a is None:
            raise NeuralBakeError(f"{key}: a texture map needs uv", parameter=key)
    options = _check_options(options)
    px = import_pxr()
    try:
        _write_usd(px, path, pts, tri, uv_a, nrm, maps, options)
    except OSError as exc:  # name the user's file, never a temporary one
        if exc.filename is not None and Path(exc.filename) != path:
            raise OSError(exc.errno, exc.strerror, str(path)) from None
        raise
    return path


def _write_usd(px, path: Path, pts, tri, uv_a, nrm, maps: dict, options: StageOptions) -> None:
    package = path.suffix.lower() == ".usdz"
    folder = path.parent if str(path.parent) else Path(".")
    with tempfile.TemporaryDirectory(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=folder) as d:
        if package:  # the stage and the maps side by side in a folder of their own, then packaged
            refs = {}
            for key, file in maps.items():
                shutil.copyfile(file, Path(d) / file.name)
                refs[key] = f"./{file.name}"
        else:
            refs = {k: "./" + Path(os.path.relpath(v, folder)).as_posix() for k, v in maps.items()}
        stage, mesh = _new_stage(px, options)
        mesh.CreatePointsAttr(_vec3f(px, pts))
        mesh.CreateExtentAttr(_extent(px, pts))
        mesh.CreateFaceVertexCountsAttr(px.Vt.IntArray.FromNumpy(np.full(len(tri), 3, dtype=np.int32)))
        mesh.CreateFaceVertexIndicesAttr(px.Vt.IntArray.FromNumpy(tri.reshape(-1).astype(np.int32)))
        if nrm is not None:
            mesh.CreateNormalsAttr(_vec3f(px, nrm))
            mesh.SetNormalsInterpolation(px.UsdGeom.Tokens.vertex)
        if uv_a is not None:
            st = px.UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", px.Sdf.ValueTypeNames.TexCoord2fArray,
                                                          px.UsdGeom.Tokens.vertex)
            st.Set(px.Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(uv_a, dtype=np.float32)))
        if refs:
            _material(px, stage, mesh, options.name, refs)
        if package:
            inner = Path(d) / f"{options.name}.usdc"
            if not stage.GetRootLayer().Export(str(inner)):
                raise OSError(f"{path}: usd-core could not write the stage")
            with atomic_path(path) as tmp:
                if not px.UsdUtils.CreateNewARKitUsdzPackage(str(inner), str(tmp)):
                    raise OSError(f"{path}: usd-core could not write the package")
        else:
            _export_stage(stage, path)


def _format_args(path: Path) -> dict:
    """Export arguments: a ``.usd`` file is written as binary crate; ``.usda``/``.usdc`` by their suffix."""
    return {"format": "usdc"} if path.suffix.lower() == ".usd" else {}


def _material(px, stage, mesh, name: str, refs: dict[str, str]) -> None:
    """A UsdPreviewSurface reading the maps ``refs`` (key → asset path) through ``st``, bound to ``mesh``."""
    Sdf, UsdShade = px.Sdf, px.UsdShade
    px.UsdGeom.Scope.Define(stage, f"/{name}/Looks")
    material = UsdShade.Material.Define(stage, f"/{name}/Looks/{name}")
    surface = UsdShade.Shader.Define(stage, f"/{name}/Looks/{name}/PreviewSurface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    reader = UsdShade.Shader.Define(stage, f"/{name}/Looks/{name}/stReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    for key, asset in refs.items():
        tex = UsdShade.Shader.Define(stage, f"/{name}/Looks/{name}/{'baseColor' if key == 'base_colour' else 'normal'}Texture")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(asset))
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
        rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        if key == "base_colour":
            tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
            surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
        else:
            tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
            tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(px.Gf.Vec4f(*NORMAL_MAP_SCALE))
            tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(px.Gf.Vec4f(*NORMAL_MAP_BIAS))
            surface.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(rgb)
    px.UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)


def write_usd_frames(
    path,
    frames,
    *,
    fps: float = 24.0,
    times=None,
    options: StageOptions | None = None,
) -> Path:
    """Write frames of per-vertex bakes as one USD stage with time samples at ``path`` (atomically); return it.

    Args:
        path: ``.usd``/``.usdc`` (binary crate) or ``.usda`` (text).
        frames: a sequence of dicts, one per frame in time order: ``points`` (V, 3) source frame, ``faces``
            (F, 3), ``normals`` (V, 3) unit or None, ``colours`` (V, 3) linear RGB in [0, 1] or None. Frames may
            differ in vertex and face counts: points, face counts and indices, normals, ``extent`` and
            ``primvars:displayColor`` (vertex interpolation) are all time-sampled.
        fps: frames per second: frame i is time code i, and ``timeCodesPerSecond`` = ``framesPerSecond`` =
            fps; start and end time codes are 0 and len(frames) − 1.
        times: the field's time of each frame (any units), recorded in the layer's custom data
            (``neural_bake:times``); None: none recorded.
        options: the stage's unit, up axis and prim name (default :class:`StageOptions`).

    Raises :class:`~neural_bake.errors.MissingExtraError` without usd-core, :class:`NeuralBakeError`
    (naming the parameter) for no frames, arrays of the wrong shape, a bad ``fps`` or a bad option,
    :class:`~neural_bake.errors.OutputError` for a missing folder.
    """
    path = Path(path)
    _check_destination(path, (".usd", ".usda", ".usdc"))
    frames = list(frames)
    if not frames:
        raise NeuralBakeError("frames: give at least one frame", parameter="frames")
    if isinstance(fps, bool) or not (np.isfinite(fps) and fps > 0):
        raise NeuralBakeError(f"fps {fps!r}: must be a positive number of frames per second", parameter="fps")
    if times is not None and len(times) != len(frames):
        raise NeuralBakeError(f"times: {len(times)} times for {len(frames)} frames", parameter="times")
    checked = []
    for i, fr in enumerate(frames):
        pts, tri = _check_mesh(fr["points"], fr["faces"], what=f"frame {i}: ")
        nrm = None if fr.get("normals") is None else _array("normals", fr["normals"], 3, len(pts))
        col = None if fr.get("colours") is None else np.clip(_array("colours", np.asarray(fr["colours"])[:, :3], 3,
                                                                    len(pts)), 0, 1)
        checked.append((pts, tri, nrm, col))
    options = _check_options(options)
    px = import_pxr()
    stage, mesh = _new_stage(px, options)
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(len(frames) - 1)
    if times is not None:
        stage.GetRootLayer().customLayerData = {"neural_bake:times": px.Vt.DoubleArray([float(t) for t in times])}
    attrs = {"points": mesh.CreatePointsAttr(), "extent": mesh.CreateExtentAttr(),
             "counts": mesh.CreateFaceVertexCountsAttr(), "indices": mesh.CreateFaceVertexIndicesAttr()}
    if any(c[2] is not None for c in checked):
        attrs["normals"] = mesh.CreateNormalsAttr()
        mesh.SetNormalsInterpolation(px.UsdGeom.Tokens.vertex)
    if any(c[3] is not None for c in checked):
        attrs["colours"] = mesh.CreateDisplayColorPrimvar(px.UsdGeom.Tokens.vertex).GetAttr()
    for i, (pts, tri, nrm, col) in enumerate(checked):
        tc = px.Usd.TimeCode(i)
        attrs["points"].Set(_vec3f(px, pts), tc)
        attrs["extent"].Set(_extent(px, pts), tc)
        attrs["counts"].Set(px.Vt.IntArray.FromNumpy(np.full(len(tri), 3, dtype=np.int32)), tc)
        attrs["indices"].Set(px.Vt.IntArray.FromNumpy(tri.reshape(-1).astype(np.int32)), tc)
        if "normals" in attrs:  # a frame without normals holds an empty sample (none at that time)
            attrs["normals"].Set(_vec3f(px, nrm if nrm is not None else np.zeros((0, 3))), tc)
        if "colours" in attrs:
            attrs["colours"].Set(_vec3f(px, col if col is not None else np.zeros((0, 3))), tc)
    _export_stage(stage, path)
    return path
