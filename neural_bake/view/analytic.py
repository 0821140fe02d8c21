"""A bake of a bundled sample's analytic fields: what a perfect fit would bake (tests, benchmarks, docs).

The sample's exact normals and colours (:mod:`neural_bake.samples.shapes`) stand in for the SDF and texture
networks: the maps hold only the bake's own errors (coarse geometry, 8-bit quantisation, filtering), so a
render of them can be held to the analytic render of the sample.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

__all__ = ["AnalyticBake", "analytic_bake"]


@dataclass
class AnalyticBake:
    """What :func:`analytic_bake` made: the sample, its fine mesh (unit frame), the Baker, the result, the GLB."""

    sample: object
    fine: object
    baker: object
    result: object
    glb: Path


def analytic_bake(folder, name: str = "bumpy_sphere", *, faces: int = 1500, size: int = 256) -> AnalyticBake:
    """Bake sample ``name``'s analytic normals and colours onto its mesh decimated to ``faces`` faces, in
    ``size``² maps, and write ``folder/asset.glb``."""
    import torch

    from ..bake.baker import Baker
    from ..bake.export import export_glb
    from ..fields import ColorField, SdfField
    from ..io.mesh_io import mesh_from_arrays
    from ..mesh.decimate import decimate
    from ..samples.shapes import get_sample

    sample = get_sample(name)
    arrays = sample.mesh()
    fine = mesh_from_arrays(arrays.vertices, arrays.faces, arrays.uv, arrays.texture, source=f"{name}.obj")
    frame = fine.frame

    def to_src(p):
        return frame.to_source(p.detach().cpu().numpy())

    sdf = SdfField(lambda p: torch.as_tensor(sample.sdf(to_src(p)) * frame.scale, dtype=p.dtype, device=p.device),
                   lambda p: torch.as_tensor(sample.normal(to_src(p)), dtype=p.dtype, device=p.device))
    colours = ColorField(lambda p: torch.as_tensor(sample.albedo(to_src(p)), dtype=p.dtype, device=p.device))
    baker = Baker(decimate(fine, faces=faces), size)
    result = baker.bake(sdf, colours)
    glb = export_glb(Path(folder) / "asset.glb", baker.mesh, normal_map=result.normal_map, albedo=result.albedo,
                     tangents=baker.tangents)
    return AnalyticBake(sample, fine, baker, result, glb)
