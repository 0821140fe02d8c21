"""Preview rendering: the camera, lights and shading shared by the neural preview and the mesh turntables."""

from .camera import Camera, CameraError
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

__all__ = [
    "Camera", "CameraError", "DirectionalLight", "PointLight", "Material", "ShadingError", "default_lights",
    "light_samples", "shade_blinn_phong", "shade_matcap",
]
