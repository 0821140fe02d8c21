"""Tolerances and conventions in one place (trimesh's ``constants.py`` idea)."""

from __future__ import annotations

#: Longest side of the normalised bounding box: meshes are scaled so it measures this, centred at 0,
#: so the unit frame leaves a margin inside the cube [-1, 1]^3 (DESIGN.md, "Frame").
UNIT_FRAME_EXTENT = 1.8

#: A face whose area (in the unit frame) is below this is degenerate: excluded from sampling.
DEGENERATE_AREA = 1e-12

#: |∇f| below this is a zero gradient: the normal is invalid (masked), never NaN.
GRAD_EPS = 1e-8

#: Default ω0 of a SIREN's first layer (Sitzmann et al.).
DEFAULT_OMEGA_0 = 30.0

#: UV policies for coordinates outside [0, 1].
UV_POLICIES = ("wrap", "clamp")

#: Vertices closer than this (unit frame) are welded on load: the splits that OBJ ``v/vt`` pairs and glTF
#: make at UV seams are undone, so the mesh gets its true topology (watertightness, genus).
MERGE_DISTANCE = 1e-9

#: Hybrid bake: a texel whose source-surface point (where the classical bake's ray lands) has |f| above this
#: (unit frame) is one the neural field does not represent; it takes the classical mesh-to-mesh normal.
HYBRID_SDF_TOL = 0.01

#: Hybrid bake: a texel whose ∇f differs from the source mesh's normal there by more than this many degrees
#: takes the classical mesh-to-mesh normal; it bounds how much worse than the source a baked texel can be.
HYBRID_ANGLE_DEG = 20.0

#: A camera whose up vector's cross product with the view direction is shorter than this has up parallel to
#: the view: it has no image basis and is refused.
CAMERA_PARALLEL_EPS = 1e-9

#: A time-budgeted fit that made fewer than this fraction of the steps its preset makes on this machine
#: warns that it was slowed (the machine was busy) and is weaker than the preset's.
BUDGET_WARN_FRACTION = 0.5

#: Pixels peeled off the common mask of two renders before an "interior" comparison: the outline of a coarse
#: mesh differs from its source's by a pixel or two, and those pixels would swamp the shading differences.
INTERIOR_ERODE_PX = 2

#: Interior PSNR (dB, sRGB) a correct bake's render reaches against the analytic reference render of its
#: sample; a normal map with its green channel flipped, or no maps, stays below it.
BAKED_RENDER_MIN_PSNR_DB = 45.0
