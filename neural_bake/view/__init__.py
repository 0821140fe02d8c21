"""Visual checks of bakes: a mesh renderer with the baked maps, turntables, difference images, reports."""

from .compare import DIFF_SCALE, difference_image, image_metrics
from .analytic import analytic_bake, analytic_render_asset
from .index import asset_summary, write_batch_index
from .meshes import ViewError, ViewMesh, load_view_mesh, view_mesh_from_glb, view_mesh_from_mesh
from .raycast import DEFAULT_BACKGROUND, MeshRender, render_mesh, shading_normals
from .turntable import render_turntable, to_srgb8, turntable_cameras, view_camera, write_gif, write_turntable

__all__ = [
    "write_batch_index", "asset_summary", "analytic_bake", "analytic_render_asset",
    "ViewError", "ViewMesh", "load_view_mesh", "view_mesh_from_glb", "view_mesh_from_mesh",
    "MeshRender", "render_mesh", "shading_normals", "DEFAULT_BACKGROUND",
    "image_metrics", "difference_image", "DIFF_SCALE",
    "view_camera", "turntable_cameras", "render_turntable", "to_srgb8", "write_gif", "write_turntable",
]
