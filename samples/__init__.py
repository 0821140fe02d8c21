"""Generator of small UV-textured meshes with analytic ground truth (installed as ``neural_bake.samples``).

>>> from neural_bake.samples import SAMPLES, sample_path, generate
>>> mesh = neural_bake.load_mesh(sample_path("bumpy_sphere"))   # bundled OBJ + MTL + PNG
>>> s = SAMPLES["bumpy_sphere"]; s.normal(mesh.frame.to_source(mesh.vertices))   # analytic normals

See :mod:`neural_bake.samples.shapes` for the shapes and their analytic functions, and
:mod:`neural_bake.samples.generate` for the files.
"""

from .animated import ANIMATED, SplittingSphere, TravellingBumps, TwistingTorus, get_animation
from .generate import DATA_DIR, FRAMES_FILE, generate, sample_path, write_animation
from .shapes import SAMPLES, BumpySphere, Dots, Jack, SampleMesh, Sphere, Torus, get_sample, unit_frame_normals

__all__ = ["SAMPLES", "SampleMesh", "Sphere", "Torus", "BumpySphere", "Jack", "Dots", "get_sample", "generate",
           "sample_path", "DATA_DIR", "unit_frame_normals", "ANIMATED", "TravellingBumps", "TwistingTorus",
           "SplittingSphere", "get_animation", "write_animation", "FRAMES_FILE"]
