"""An analytic bake of the bumpy sphere (exact normals and colours baked onto a decimated mesh), shared."""

from types import SimpleNamespace

import pytest
import torch

from neural_bake.bake.baker import Baker
from neural_bake.bake.export import export_glb
from neural_bake.bake.fields import ColorField, SdfField
from neural_bake.io.mesh_io import mesh_from_arrays
from neural_bake.mesh.decimate import decimate
from neural_bake.samples.shapes import get_sample


def analytic_bake(folder, name="bumpy_sphere", faces=1500, size=256):
    """Bake sample ``name``'s analytic normals and colours onto a decimated copy; write ``asset.glb``."""
    sample = get_sample(name)
    arrays = sample.mesh()
    fine = mesh_from_arrays(arrays.vertices, arrays.faces, arrays.uv, arrays.texture, source=f"{name}.obj")
    frame = fine.frame

    def to_src(p):
        return frame.to_source(p.detach().cpu().numpy())

    sdf = SdfField(lambda p: torch.as_tensor(sample.sdf(to_src(p)) * frame.scale, dtype=p.dtype),
                   lambda p: torch.as_tensor(sample.normal(to_src(p)), dtype=p.dtype))
    colours = ColorField(lambda p: torch.as_tensor(sample.albedo(to_src(p)), dtype=p.dtype))
    baker = Baker(decimate(fine, faces=faces), size)
    result = baker.bake(sdf, colours)
    glb = export_glb(folder / "asset.glb", baker.mesh, normal_map=result.normal_map, albedo=result.albedo,
                     tangents=baker.tangents)
    return SimpleNamespace(sample=sample, fine=fine, baker=baker, result=result, glb=glb)


@pytest.fixture(scope="session")
def bumpy_bake(tmp_path_factory):
    return analytic_bake(tmp_path_factory.mktemp("bumpy"))
