"""Preview rendering: sphere tracing of nested neural SDFs (Algorithm 1, LOD, guaranteed casting), neural
normal and texture mapping, only the effects a scene calls for; the camera, lights and shading are shared
with the mesh turntables."""

from .asset import (
    RenderAsset, RenderError, SpaceTimeAsset, TextureSource, TraceLevel, analytic_level, analytic_texture,
    as_render_asset, siren_level, siren_texture,
)
from .camera import Camera, CameraError
from .guaranteed import cast_guaranteed
from .load import load_asset
from .output import write_render
from .renderer import RenderResult, default_camera, render
from .scene import CHANNELS, EFFECTS, AmbientOcclusion, Scene, SceneError, SceneObject, Transform, load_scene
from .sequence import SequenceResult, render_sequence, render_time
from .shading import (
    DirectionalLight,
    Material,
    PointLight,
    ShadingError,
    default_lights,
    light_samples,
    shade_blinn_phong,
    shade_matcap,
)
from .stats import EvalCounter
from .trace import TRACE_MODES, TraceSettings, trace_rays

__all__ = [
    "Camera", "CameraError", "DirectionalLight", "PointLight", "Material", "ShadingError", "default_lights",
    "light_samples", "shade_blinn_phong", "shade_matcap",
    "RenderAsset", "RenderError", "SpaceTimeAsset", "TextureSource", "TraceLevel", "analytic_level",
    "analytic_texture", "as_render_asset", "siren_level", "siren_texture", "cast_guaranteed", "load_asset",
    "write_render", "RenderResult", "default_camera", "render", "CHANNELS", "EFFECTS", "AmbientOcclusion", "Scene",
    "SceneError", "SceneObject", "Transform", "load_scene", "SequenceResult", "render_sequence", "render_time",
    "EvalCounter",
    "TRACE_MODES", "TraceSettings", "trace_rays",
]
