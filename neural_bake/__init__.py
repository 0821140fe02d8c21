"""neural_bake: neural normal and texture baking.

Fit a fine SIREN SDF and a texture MLP (optionally gradient-orthogonal) to a UV-textured mesh, make a coarse
mesh, and bake the neural normals and colours onto it per vertex or per texel (normals in closed form with
GEMMs, colours read at the closest points of f = 0).

The public API is flat: ``neural_bake.load_mesh``, ``neural_bake.Siren``, ``neural_bake.gemm_gradient``, …
Names are imported on first use, so ``import neural_bake`` stays fast and a CLI verb loads only what it needs.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> module that defines it (relative to this package)
_EXPORTS = {
    # plain data, errors
    "Frame": ".types",
    "Mesh": ".types",
    "NeuralBakeError": ".errors",
    "MeshError": ".errors",
    "ImageError": ".errors",
    "ModelFileError": ".errors",
    "FitError": ".errors",
    "TrainingDivergedError": ".errors",
    "TimeRangeError": ".errors",
    "NeuralBakeWarning": ".errors",
    # io
    "atomic_path": ".io.atomic",
    "atomic_write_bytes": ".io.atomic",
    "atomic_write_text": ".io.atomic",
    "load_mesh": ".io.mesh_io",
    "mesh_from_arrays": ".io.mesh_io",
    "save_mesh": ".io.mesh_io",
    "inspect_mesh": ".io.inspect",
    "read_image": ".io.images",
    "write_image": ".io.images",
    "srgb_to_linear": ".io.colour",
    "linear_to_srgb": ".io.colour",
    "sample_texture": ".io.colour",
    # nets
    "Siren": ".nets.siren",
    "gemm_gradient": ".nets.gemm",
    "normalized_gradient": ".nets.gemm",
    "load_model": ".nets.model_io",
    "range_bound": ".nets.range_analysis",
    "difference_bound": ".nets.range_analysis",
    # fields: what a fitted asset is; one load/save
    "SdfField": ".fields",
    "TextureField": ".fields",
    "ColorField": ".fields",
    "NestedSequence": ".fields",
    "SpaceTimeField": ".fields",
    "load_field": ".fields",
    "save_field": ".fields",
    "save_model": ".fields",
    "load_sdf_field": ".fields",
    "to_sdf_field": ".fields",
    "import_siren": ".fields",
    # fit
    "SurfaceSamples": ".fit.sampling",
    "VolumeSamples": ".fit.sampling",
    "sample_surface": ".fit.sampling",
    "sample_near": ".fit.sampling",
    "sample_uniform": ".fit.sampling",
    "signed_distance": ".fit.sampling",
    "SdfFitConfig": ".fit.sdf",
    "fit_sdf": ".fit.sdf",
    "fit_nested": ".fit.nested",
    "sdf_metrics": ".fit.metrics",
    "TextureFitConfig": ".fit.texture",
    "fit_texture": ".fit.texture",
    "SpaceTimeFitConfig": ".fit.spacetime",
    "SpaceTimeFit": ".fit.spacetime",
    "fit_morph": ".fit.spacetime",
    "fit_sequence": ".fit.spacetime",
    "nest_spacetime": ".fit.spacetime",
    "texture_metrics": ".fit.texture",
    # mesh
    "decimate": ".mesh.decimate",
    "march": ".mesh.marching",
    "unwrap": ".mesh.unwrap",
    "TexelSet": ".mesh.texels",
    "rasterize_texels": ".mesh.texels",
    "tangent_frames": ".mesh.tangents",
    "clean_mesh": ".mesh.cleanup",
    "coarse_mesh": ".mesh.coarse",
    "iter_texels": ".mesh.texels",
    "vertex_uv": ".mesh.tangents",
    # bake
    "Baker": ".bake.baker",
    "bake_vertices": ".bake.baker",
    "bake_texels": ".bake.baker",
    "pad_charts": ".bake.padding",
    "baseline_bake": ".bake.baseline",
    "export_glb": ".bake.export",
    "BakeResult": ".bake.baker",
    "TexelSample": ".bake.baker",
    "bake_report": ".bake.report",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'neural_bake' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__
