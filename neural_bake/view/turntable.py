"""Turntables: one framing camera orbited in equal steps about its up axis, rendered and written as frames + GIF."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..constants import MIN_SPAN
from ..io.atomic import atomic_path
from ..io.colour import linear_to_srgb
from ..render.camera import Camera
from .meshes import ViewError, ViewMesh
from .raycast import MeshRender, render_mesh

__all__ = ["view_camera", "turntable_cameras", "render_turntable", "to_srgb8", "write_gif", "write_turntable",
           "VIEW_DIRECTION"]

#: Direction from the target towards the eye of the first turntable view: in front, a little to the right
#: and above, so the top and one side show too.
VIEW_DIRECTION = (0.35, 0.45, 1.0)


def view_camera(mesh: ViewMesh, *, width: int = 256, height: int = 256, fov_deg: float = 35.0) -> Camera:
    """The first turntable camera: looks at the centre of ``mesh``'s bounding box from :data:`VIEW_DIRECTION`,
    far enough that the sphere about that centre through the farthest vertex fits the view (every turntable
    view frames the mesh alike)."""
    lo, hi = mesh.bounds
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(mesh.positions - centre, axis=1).max())
    half = np.full(3, max(radius, MIN_SPAN) / np.sqrt(3.0))  # a box whose bounding sphere is that sphere
    return Camera.framing(centre - half, centre + half, direction=VIEW_DIRECTION, fov_deg=fov_deg, width=width,
                          height=height, margin=1.05)


def turntable_cameras(camera: Camera, views: int) -> list[Camera]:
    """``views`` cameras: ``camera`` orbited by 360°·k / views, k = 0 … views − 1."""
    if isinstance(views, bool) or int(views) != views or views < 1:
        raise ViewError(f"turntable views must be a whole number ≥ 1, got {views!r}")
    return [camera.orbit(360.0 * k / int(views)) for k in range(int(views))]


def render_turntable(mesh: ViewMesh, camera: Camera, views: int, **kwargs) -> list[MeshRender]:
    """:func:`render_mesh` of ``mesh`` from each of :func:`turntable_cameras`; ``kwargs`` go to render_mesh
    (the lights default to each camera's own key light, so the light turns with the camera)."""
    return [render_mesh(mesh, cam, **kwargs) for cam in turntable_cameras(camera, views)]


def to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) linear RGB → (H, W, 3) uint8 sRGB-encoded (clipped)."""
    return np.round(linear_to_srgb(np.clip(np.asarray(rgb, dtype=np.float32), 0, 1)) * 255).astype(np.uint8)


def write_gif(path, frames: list[np.ndarray], *, seconds_per_frame: float = 0.12) -> Path:
    """Write uint8 sRGB frames (H, W, 3) as a looping GIF (atomically); return the path."""
    import imageio.v3 as iio

    if not frames:
        raise ViewError(f"{path}: a GIF needs at least one frame")
    path = Path(path)
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, np.stack(frames), extension=".gif", duration=int(round(seconds_per_frame * 1000)), loop=0)
    return path


def write_turntable(mesh: ViewMesh, out_dir, *, views: int = 8, size: int = 320) -> Path:
    """Render ``views`` turntable frames of ``mesh`` (``size``² pixels, :func:`view_camera`) into ``out_dir``
    as ``frame_000.png`` … and ``turntable.gif``; return the GIF's path. The folder is created if needed
    (its parent must exist); a symlink is followed and stays a link."""
    from ..io.atomic import link_target
    from ..io.images import write_image

    out = Path(out_dir)
    if not out.parent.is_dir():
        raise ViewError(f"{out}: folder {out.parent} does not exist")
    target = link_target(out)  # a dangling link's folder is made where it points
    frames = render_turntable(mesh, view_camera(mesh, width=size, height=size), views)
    target.mkdir(exist_ok=True)
    pixels = [to_srgb8(f.rgb) for f in frames]
    for k, img in enumerate(pixels):
        write_image(out / f"frame_{k:03d}.png", img.astype(np.float32) / 255, colour="data")
    return write_gif(out / "turntable.gif", pixels)
