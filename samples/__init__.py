"""Generator of small UV-textured meshes with analytic ground truth (installed as ``neural_bake.samples``)."""
