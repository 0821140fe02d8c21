"""Scenes: camera, objects, lights, material, background, effects and output channels, as dataclasses and TOML.

A scene file holds the same content as :class:`Scene` (keys are the dataclass fields)::

    background = [1.0, 1.0, 1.0]
    effects = ["shading", "normal_mapping", "texture", "shadows", "ambient_occlusion"]
    channels = ["color", "depth", "normal", "hit", "iterations"]

    [camera]                      # source frame; omitted: a camera that frames the object
    position = [0.0, 0.5, 3.0]
    look_at = [0.0, 0.0, 0.0]
    fov_deg = 40
    width = 256
    height = 256

    [trace]
    mode = "fixed"                # or "threshold"
    iterations = [30, 30]         # per level, coarse to fine (0 skips a level)

    [[objects]]
    model = "bunny.nested"        # relative paths are relative to the scene file
    texture = "bunny.tex"
    deltas = [0.02, 0.006]        # optional: override the file's δ per level
    transform = { translate = [0, 0, 0], rotate_deg = [0, 30, 0], scale = 1.0 }

    [[lights]]
    kind = "directional"          # or "point" (with position)
    direction = [-0.4, -0.6, -0.7]

    [material]
    kind = "blinn-phong"          # or "matcap"

Unknown keys and bad values raise :class:`SceneError` naming the file and the key.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from ..constants import MAX_SCENE_LIGHTS, MAX_SCENE_OBJECTS, SHADOW_BIAS
from ..errors import NeuralBakeError
from .camera import Camera
from .checks import finite_numbers
from .shading import DirectionalLight, Material, PointLight
from .trace import TraceSettings

__all__ = [
    "SceneError", "Scene", "SceneObject", "Transform", "AmbientOcclusion", "EFFECTS", "CHANNELS",
    "load_scene", "parse_list", "scene_table",
]

#: Effects a scene can call for.
EFFECTS = ("shading", "normal_mapping", "texture", "shadows", "ambient_occlusion", "hole_map")

#: Output channels: colour (linear RGB, sRGB in PNG), depth (distance from the eye along the ray, source
#: units), normal (source frame), hit mask, iterations per pixel, holes (the hole map), lod (continuous level).
CHANNELS = ("color", "depth", "normal", "hit", "iterations", "holes", "lod")


class SceneError(NeuralBakeError):
    """A scene file or scene value that is unreadable, has an unknown key or a bad value."""


def _floats(where: str, value, n: int) -> tuple[float, ...]:
    return finite_numbers(where, value, n, SceneError)


@dataclass(frozen=True)
class Transform:
    """Placement of an object's source frame in the scene: ``x_scene = R (scale · x) + translate``, R the
    rotation by ``rotate_deg`` about X, then Y, then Z (degrees)."""

    translate: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Translation, scene units."""
    rotate_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Rotation angles about X, Y, Z in degrees, applied in that order."""
    scale: float = 1.0
    """Uniform scale (> 0)."""

    def __post_init__(self):
        object.__setattr__(self, "translate", _floats("transform translate", self.translate, 3))
        object.__setattr__(self, "rotate_deg", _floats("transform rotate_deg", self.rotate_deg, 3))
        s = self.scale
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not math.isfinite(s) or s <= 0:
            raise SceneError(f"transform scale: expected a finite number > 0, got {s!r}")
        object.__setattr__(self, "scale", float(s))

    def rotation(self) -> np.ndarray:
        """(3, 3) float64 rotation matrix R."""
        ax, ay, az = (math.radians(a) for a in self.rotate_deg)
        rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
        ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
        rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
        return rz @ ry @ rx

    def is_identity(self) -> bool:
        return self.translate == (0.0, 0.0, 0.0) and self.rotate_deg == (0.0, 0.0, 0.0) and self.scale == 1.0


@dataclass(frozen=True)
class SceneObject:
    """One object: a model file (SDF or nested sequence), an optional texture file, δ overrides, a transform.

    In Python the renderer also takes assets directly (``render(asset, scene)``); ``model`` is for files."""

    model: str | None = None
    """Model file (SDF field or nested sequence); relative to the scene file."""
    texture: str | None = None
    """Texture field file, or None."""
    deltas: tuple[float, ...] | None = None
    """δ per level (coarse to fine) to trace with instead of the file's; the last (f's) is ignored."""
    transform: Transform = field(default_factory=Transform)
    """Placement in the scene."""

    def __post_init__(self):
        if self.deltas is not None:
            try:
                ds = tuple(float(d) for d in self.deltas)
            except (TypeError, ValueError):
                raise SceneError(f"object deltas: expected numbers, got {self.deltas!r}") from None
            if not ds or not all(math.isfinite(d) and d >= 0 for d in ds):
                raise SceneError(f"object deltas: expected finite numbers ≥ 0, got {self.deltas!r}")
            object.__setattr__(self, "deltas", ds)
        if isinstance(self.transform, dict):
            object.__setattr__(self, "transform", _build(Transform, self.transform, "transform"))


@dataclass(frozen=True)
class AmbientOcclusion:
    """SDF ambient occlusion: ``1 − strength Σ_i 2^-i (d_i − f(p + d_i n)) / d_i`` over ``samples`` points at
    distances ``d_i = distance · i / samples`` along the normal (unit frame)."""

    samples: int = 5
    """Points along the normal."""
    distance: float = 0.1
    """Farthest sample, unit frame."""
    strength: float = 1.0
    """Scale of the occlusion."""

    def __post_init__(self):
        if isinstance(self.samples, bool) or int(self.samples) != self.samples or not 1 <= self.samples <= 64:
            raise SceneError(f"ambient_occlusion samples: expected a whole number in 1..64, got {self.samples!r}")
        for name in ("distance", "strength"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise SceneError(f"ambient_occlusion {name}: expected a finite number > 0, got {v!r}")


@dataclass(frozen=True)
class Scene:
    """Everything a render needs besides the assets."""

    camera: Camera | None = None
    """Source-frame pinhole camera; None: one that frames the objects (:func:`default_camera`)."""
    objects: tuple[SceneObject, ...] = ()
    """Objects from files (the CLI's MODEL is the first object when the scene has none)."""
    lights: tuple = ()
    """Directional and point lights; empty: one key light placed from the camera."""
    material: Material = field(default_factory=Material)
    """Blinn-Phong or matcap."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Linear RGB of pixels that miss."""
    effects: tuple[str, ...] = ("shading",)
    """Effects from :data:`EFFECTS`; only these are computed."""
    normal_level: int = -1
    """Level whose GEMM normals normal mapping uses (Python index: −1 is the fine f)."""
    channels: tuple[str, ...] = ("color",)
    """Outputs from :data:`CHANNELS`."""
    trace: TraceSettings = field(default_factory=TraceSettings)
    """Sphere-tracing settings."""
    guaranteed: bool = False
    """Cast primary rays with range analysis (Procedure 2) on f instead of sphere tracing."""
    skip: bool = True
    """Empty-space skipping by the coarsest level's range-analysis octree (where it has a range bound)."""
    skip_depth: int = 5
    """Octree depth of the skipping grid."""
    far: float | None = None
    """Far plane: distance from the eye (source units) beyond which nothing is hit; None: no far plane."""
    ambient_occlusion: AmbientOcclusion = field(default_factory=AmbientOcclusion)
    """Ambient-occlusion settings (used with the ``ambient_occlusion`` effect)."""
    shadow_bias: float = SHADOW_BIAS
    """Shadow rays start this far off the surface (unit frame)."""

    def __post_init__(self):
        effects = parse_list(self.effects, "effects", EFFECTS)
        channels = parse_list(self.channels, "channels", CHANNELS)
        if not channels:
            raise SceneError("channels: ask for at least one channel")
        object.__setattr__(self, "effects", effects)
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "background", _floats("background", self.background, 3))
        if isinstance(self.normal_level, bool) or not isinstance(self.normal_level, (int, np.integer)):
            raise SceneError(f"normal_level: expected a whole number (level index), got {self.normal_level!r}")
        if self.far is not None:
            f = self.far
            if isinstance(f, bool) or not isinstance(f, (int, float)) or not math.isfinite(f) or f <= 0:
                raise SceneError(f"far: expected a finite number > 0, got {f!r}")
        for name in ("guaranteed", "skip"):
            if not isinstance(getattr(self, name), bool):
                raise SceneError(f"{name}: expected true or false, got {getattr(self, name)!r}")
        d = self.skip_depth
        if isinstance(d, bool) or int(d) != d or not 1 <= d <= 8:
            raise SceneError(f"skip_depth: expected a whole number in 1..8, got {d!r}")
        b = self.shadow_bias
        if isinstance(b, bool) or not isinstance(b, (int, float)) or not math.isfinite(b) or b < 0:
            raise SceneError(f"shadow_bias: expected a finite number ≥ 0, got {b!r}")
        for name, items, cap in (("lights", self.lights, MAX_SCENE_LIGHTS), ("objects", self.objects, MAX_SCENE_OBJECTS)):
            if len(items) > cap:
                raise SceneError(f"{name}: at most {cap}, got {len(items)}")
        for light in self.lights:
            if not isinstance(light, (DirectionalLight, PointLight)):
                raise SceneError(f"lights: expected DirectionalLight or PointLight, got {type(light).__name__}")
        object.__setattr__(self, "objects", tuple(self.objects))
        object.__setattr__(self, "lights", tuple(self.lights))

    def with_(self, **changes) -> "Scene":
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)


def parse_list(value, name: str, known: tuple[str, ...]) -> tuple[str, ...]:
    """A comma-separated string or a sequence of names → a tuple of known names (dashes read as
    underscores; "none" or "" is empty). SceneError names the first unknown one."""
    if isinstance(value, str):
        items = [s.strip() for s in value.split(",") if s.strip()]
    else:
        try:
            items = [str(s).strip() for s in value]
        except TypeError:
            raise SceneError(f"{name}: expected a list of names, got {value!r}") from None
    out = []
    for item in items:
        key = item.lower().replace("-", "_")
        if key == "none":
            continue
        if key == "colour":
            key = "color"
        if key not in known:
            raise SceneError(f"{name}: unknown {name.rstrip('s')} {item!r} (known: {', '.join(known)})")
        if key not in out:
            out.append(key)
    return tuple(out)


# ------------------------------------------------------------------------------------------------ TOML
def _read_toml(path: Path) -> dict:
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise SceneError(f"{path}: no such scene file") from None
    except OSError as exc:
        raise SceneError(f"{path}: cannot read scene file ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML ({exc})") from None


def _build(cls, data, where: str):
    """``cls(**data)`` with unknown keys and constructor errors turned into SceneErrors naming ``where``."""
    if not isinstance(data, dict):
        raise SceneError(f"{where}: expected a table of keys, got {data!r}")
    known = [f.name for f in fields(cls)]
    for key in data:
        if key not in known:
            raise SceneError(f"{where}: unknown key {key!r} (known: {', '.join(known)})")
    try:
        return cls(**data)
    except NeuralBakeError as exc:
        raise type(exc)(f"{where}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{where}: {exc}") from None


def _light(data, where: str):
    if not isinstance(data, dict):
        raise SceneError(f"{where}: expected a table, got {data!r}")
    data = dict(data)
    kind = data.pop("kind", "directional")
    if kind == "directional":
        return _build(DirectionalLight, data, where)
    if kind == "point":
        return _build(PointLight, data, where)
    raise SceneError(f"{where}.kind: expected 'directional' or 'point', got {kind!r}")


def load_scene(path) -> Scene:
    """Read a TOML scene file (module docstring); relative model paths become relative to its folder."""
    path = Path(path)
    data = _read_toml(path)
    known = [f.name for f in fields(Scene)]
    for key in data:
        if key not in known:
            raise SceneError(f"{path}: unknown key {key!r} (known: {', '.join(known)})")
    kw = dict(data)
    if "camera" in kw:
        kw["camera"] = _build(Camera, kw["camera"], f"{path}: camera")
    if "material" in kw:
        kw["material"] = _build(Material, kw["material"], f"{path}: material")
    if "trace" in kw:
        t = dict(kw["trace"]) if isinstance(kw["trace"], dict) else kw["trace"]
        if isinstance(t, dict) and "iterations" in t and isinstance(t["iterations"], list):
            t["iterations"] = tuple(t["iterations"])
        if isinstance(t, dict) and isinstance(t.get("lod"), list):
            t["lod"] = tuple(t["lod"])
        kw["trace"] = _build(TraceSettings, t, f"{path}: trace")
    if "ambient_occlusion" in kw:
        kw["ambient_occlusion"] = _build(AmbientOcclusion, kw["ambient_occlusion"], f"{path}: ambient_occlusion")
    if "lights" in kw:
        if not isinstance(kw["lights"], list):
            raise SceneError(f"{path}: lights: expected an array of tables ([[lights]])")
        kw["lights"] = tuple(_light(d, f"{path}: lights[{i}]") for i, d in enumerate(kw["lights"]))
    if "objects" in kw:
        if not isinstance(kw["objects"], list):
            raise SceneError(f"{path}: objects: expected an array of tables ([[objects]])")
        objs = []
        for i, d in enumerate(kw["objects"]):
            obj = _build(SceneObject, d, f"{path}: objects[{i}]")
            for key in ("model", "texture"):
                v = getattr(obj, key)
                if v is not None:
                    if not isinstance(v, str):
                        raise SceneError(f"{path}: objects[{i}].{key}: expected a file path, got {v!r}")
                    obj = replace(obj, **{key: str((path.parent / v) if not Path(v).is_absolute() else Path(v))})
            objs.append(obj)
        kw["objects"] = tuple(objs)
    return _build(Scene, kw, str(path))


def scene_table(scene: Scene) -> dict:
    """The TOML table of ``scene`` (module docstring) that :func:`load_scene` reads back to an equal scene:
    every field, None values left out (None is each one's default), lights with their ``kind``."""
    from dataclasses import asdict

    from .shading import PointLight

    def drop_none(v):
        if isinstance(v, dict):
            return {k: drop_none(x) for k, x in v.items() if x is not None}
        if isinstance(v, (list, tuple)):
            return [drop_none(x) for x in v]
        return v

    table = drop_none(asdict(scene))
    table["lights"] = [{"kind": "point" if isinstance(light, PointLight) else "directional",
                        **drop_none(asdict(light))} for light in scene.lights]
    return table
