"""A bake of a bundled sample's analytic fields: what a perfect fit would bake (tests, benchmarks, docs).

The sample's exact normals and colours (:mod:`neural_bake.samples.shapes`) stand in for the SDF and texture
networks: the maps hold only the bake's own errors (coarse geometry, 8-bit quantisation, filtering), so a
render of them can be held to the analytic render of the sample, or to the neural preview of the same
analytic fields (:func:`analytic_render_asset`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

__all__ = ["AnalyticBake", "analytic_bake", "analytic_render_asset"]


@dataclass
class AnalyticBake:
    """What :func:`analytic_bake` made: the sample, its fine mesh (unit frame), the Baker, the result, the GLB."""

    sample: object
    fine: object
    baker: object
    result: object
    glb: Path


def _torch_fields(sample, frame):
    """(sdf, normal, albedo): torch callables on unit-frame points (N, 3) of the sample's analytic functions
    (the SDF scaled to unit-frame distances); outputs follow the points' dtype and device."""
    import torch

    def lift(fn, scale=None):
        def f(p):
            out = fn(frame.to_source(p.detach().cpu().numpy()))
            return torch.as_tensor(out * scale if scale else out, dtype=p.dtype, device=p.device)
        return f

    return lift(sample.sdf, frame.scale), lift(sample.normal), lift(sample.albedo)


def analytic_bake(folder, name: str = "bumpy_sphere", *, faces: int = 1500, size: int = 256) -> AnalyticBake:
    """Bake sample ``name``'s analytic normals and colours onto its mesh decimated to ``faces`` faces, in
    ``size``² maps, and write ``folder/asset.glb``."""
    from ..bake.baker import Baker
    from ..bake.export import export_glb
    from ..bake.fields import ColorField, SdfField
    from ..io.mesh_io import mesh_from_arrays
    from ..mesh.decimate import decimate
    from ..samples.shapes import get_sample

    sample = get_sample(name)
    arrays = sample.mesh()
    fine = mesh_from_arrays(arrays.vertices, arrays.faces, arrays.uv, arrays.texture, source=f"{name}.obj")
    sdf, normal, albedo = _torch_fields(sample, fine.frame)
    baker = Baker(decimate(fine, faces=faces), size)
    result = baker.bake(SdfField(sdf, normal), ColorField(albedo))
    glb = export_glb(Path(folder) / "asset.glb", baker.mesh, normal_map=result.normal_map, albedo=result.albedo,
                     tangents=baker.tangents)
    return AnalyticBake(sample, fine, baker, result, glb)


def analytic_render_asset(bake: AnalyticBake):
    """The sample's analytic fields as a :class:`~neural_bake.render.RenderAsset` in its fine mesh's unit frame:
    what the neural preview of a perfect fit draws (no range bound: traced without skipping)."""
    from ..render import RenderAsset, analytic_level, analytic_texture

    sdf, normal, albedo = _torch_fields(bake.sample, bake.fine.frame)
    level = analytic_level(sdf, normal, name=f"{bake.sample.name} (analytic)", lipschitz=None)
    return RenderAsset([level], bake.fine.frame).with_texture(analytic_texture(albedo, name="albedo (analytic)"))
