"""Ray-cast a :class:`ViewMesh` with open3d and shade it with its maps, as a glTF viewer does.

One ray per pixel of a :class:`~neural_bake.render.camera.Camera` (source frame, row 0 on top); open3d's
``RaycastingScene`` gives the first hit's triangle and barycentrics. Attributes are interpolated with the
barycentrics like a rasteriser's varyings: the vertex normal, the tangent (xyz) and the per-vertex
bitangent ``w · cross(n, t)`` (three.js and the Khronos sample viewer build it in the vertex shader), the UV.
The normal map is read bilinearly (glTF sampler: linear, repeat) and decoded ``normalize(x·T + y·B + z·N)``
with ``(x, y, z) = 2c − 1`` (+Y green up). Colours come from the albedo texture, else the vertex colours,
else the material's albedo. Shading is :func:`~neural_bake.render.shading.shade_blinn_phong` with the
lights and material the neural preview uses, so pictures of one view compare pixel by pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..constants import UNDERFLOW_EPS
from ..geometry import import_open3d, raycasting_scene
from ..io.colour import sample_texture
from ..render.camera import Camera
from ..render.shading import Material, default_lights, shade_blinn_phong
from .meshes import ViewMesh

__all__ = ["MeshRender", "render_mesh", "shading_normals", "DEFAULT_BACKGROUND"]

#: Linear RGB of pixels no ray hits (a light grey, so dark and light surfaces both stand out).
DEFAULT_BACKGROUND = (0.8, 0.8, 0.8)


@dataclass(frozen=True)
class MeshRender:
    """One rendered view.

    - ``rgb``: (H, W, 3) float32 linear RGB, background where nothing was hit.
    - ``mask``: (H, W) bool, a ray hit the mesh.
    - ``normals``: (H, W, 3) float32 unit shading normals (after the normal map), zero off the mesh.
    - ``depth``: (H, W) float32 ray distance to the hit, inf off the mesh.
    """

    rgb: np.ndarray
    mask: np.ndarray
    normals: np.ndarray
    depth: np.ndarray


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > UNDERFLOW_EPS)


def _cast(mesh: ViewMesh, origins: np.ndarray, dirs: np.ndarray):
    o3d = import_open3d()

    scene = raycasting_scene(mesh.positions, mesh.faces)
    rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t = ans["t_hit"].numpy().astype(np.float64)
    prim = ans["primitive_ids"].numpy().astype(np.int64)
    buv = ans["primitive_uvs"].numpy().astype(np.float64)
    return t, prim, buv


def shading_normals(mesh: ViewMesh, face: np.ndarray, bary: np.ndarray, *, use_normal_map: bool = True,
                    uv: np.ndarray | None = None) -> np.ndarray:
    """(M, 3) float64 unit normals at points given by ``face`` (M,) and barycentrics ``bary`` (M, 3) (weights
    of the face's corners 0, 1, 2), decoded from the normal map when ``use_normal_map`` and the mesh has one
    (``uv`` (M, 2): the interpolated texture coordinates, v up; computed when None)."""
    corners = mesh.faces[face]
    n = _unit(np.einsum("mk,mkd->md", bary, mesh.vertex_normals[corners]))
    if not (use_normal_map and mesh.normal_map is not None):
        return n
    if uv is None:
        uv = np.einsum("mk,mkd->md", bary, mesh.uv[face])
    tan = mesh.tangents[corners]  # (M, 3, 4)
    w = np.where(tan[..., 3:] < 0, -1.0, 1.0)
    b_vertex = w * np.cross(mesh.vertex_normals[corners], tan[..., :3])
    t = _unit(np.einsum("mk,mkd->md", bary, tan[..., :3]))
    b = _unit(np.einsum("mk,mkd->md", bary, b_vertex))
    x = sample_texture(mesh.normal_map, uv).astype(np.float64) * 2.0 - 1.0
    out = _unit(x[:, :1] * t + x[:, 1:2] * b + x[:, 2:3] * n)
    bad = np.linalg.norm(out, axis=1) == 0  # a zero texel: keep the interpolated normal, never NaN
    out[bad] = n[bad]
    return out


def render_mesh(
    mesh: ViewMesh,
    camera: Camera,
    *,
    lights=None,
    material: Material | None = None,
    use_normal_map: bool = True,
    use_albedo: bool = True,
    background=DEFAULT_BACKGROUND,
    normals_fn=None,
    albedo_fn=None,
) -> MeshRender:
    """Render ``mesh`` from ``camera`` (source frame) with Blinn-Phong shading; see the module docstring.

    - ``lights``: default :func:`~neural_bake.render.shading.default_lights` of the camera; ``material``:
      default :class:`~neural_bake.render.shading.Material`.
    - ``use_normal_map`` / ``use_albedo``: False ignores that map (the geometry's own normals; the vertex
      colours or the material's albedo).
    - ``normals_fn`` / ``albedo_fn``: optional callables on the hit points (M, 3) source frame returning
      (M, 3) unit normals / linear RGB that replace the mesh's (an analytic reference: the ideal neural
      preview of a sample).
    - ``background``: linear RGB of pixels without a hit.
    """
    material = material or Material()
    lights = default_lights(camera) if lights is None else lights
    h, w = camera.height, camera.width
    dirs = camera.pixel_directions().reshape(-1, 3)
    origins = np.broadcast_to(np.asarray(camera.position, dtype=np.float64), dirs.shape)
    t, prim, buv = _cast(mesh, origins, dirs)
    hit = np.isfinite(t)
    face = prim[hit]
    bary = np.stack([1.0 - buv[hit, 0] - buv[hit, 1], buv[hit, 0], buv[hit, 1]], axis=1)
    points = np.einsum("mk,mkd->md", bary, mesh.positions[mesh.faces[face]])
    uv = np.einsum("mk,mkd->md", bary, mesh.uv[face]) if mesh.uv is not None else None
    if normals_fn is not None:
        normals = _unit(np.asarray(normals_fn(points), dtype=np.float64))
    else:
        normals = shading_normals(mesh, face, bary, use_normal_map=use_normal_map, uv=uv)
    if albedo_fn is not None:
        albedo = np.asarray(albedo_fn(points), dtype=np.float64)[:, :3]
    elif use_albedo and mesh.texture is not None:
        albedo = sample_texture(mesh.texture, uv).astype(np.float64)
    elif mesh.vertex_colors is not None:
        albedo = np.einsum("mk,mkd->md", bary, mesh.vertex_colors[mesh.faces[face]])
    else:
        albedo = np.broadcast_to(np.asarray(material.albedo, dtype=np.float64), points.shape)
    rgb_hit = shade_blinn_phong(
        torch.as_tensor(normals), torch.as_tensor(points), torch.as_tensor(dirs[hit]),
        torch.as_tensor(np.ascontiguousarray(albedo)), lights, material,
    ).numpy()
    rgb = np.empty((h * w, 3), dtype=np.float32)
    rgb[:] = np.asarray(background, dtype=np.float32)
    rgb[hit] = rgb_hit
    nrm = np.zeros((h * w, 3), dtype=np.float32)
    nrm[hit] = normals
    return MeshRender(rgb.reshape(h, w, 3), hit.reshape(h, w), nrm.reshape(h, w, 3),
                      np.where(hit, t, np.inf).astype(np.float32).reshape(h, w))
