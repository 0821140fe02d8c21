"""Tolerances and conventions in one place (trimesh's ``constants.py`` idea)."""

from __future__ import annotations

#: Longest side of the normalised bounding box: meshes are scaled so it measures this, centred at 0,
#: so the unit frame leaves a margin inside the cube [-1, 1]^3 (docs/design.md, "Frame").
UNIT_FRAME_EXTENT = 1.8

#: A face whose area (in the unit frame) is below this is degenerate: excluded from sampling.
DEGENERATE_AREA = 1e-12

#: |∇f| below this is a zero gradient: the normal is invalid (masked), never NaN.
GRAD_EPS = 1e-8

#: A time this close to a space-time field's fitted range [t0, t1] (relative to its length; absolute for a
#: single time) is clamped onto it; farther out is refused (no extrapolation).
TIME_RANGE_TOL = 1e-9

#: Default ω0 of a SIREN's first layer (Sitzmann et al.).
DEFAULT_OMEGA_0 = 30.0

#: UV policies for coordinates outside [0, 1].
UV_POLICIES = ("wrap", "clamp")

#: A vertex coordinate larger than this in magnitude (source frame) is refused on load: squared distances
#: between such points overflow float64 (k-d trees, normals, the unit frame's scale).
MAX_COORDINATE = 1e100

# --- preview renderer (neural_bake.render)
#: Sphere tracing's threshold mode stops a level's iterations where |traced value| is at most this (unit frame).
TRACE_EPSILON = 1e-4

#: After tracing, a ray whose last |traced value| is at most this (unit frame) hit the surface; else it missed.
TRACE_HIT_TOLERANCE = 1e-3

#: In the fixed-iteration mode a ray whose step is shorter than this (unit frame) no longer moves at float32
#: resolution of unit-frame coordinates: it leaves the batch (its remaining iterations would not change it).
TRACE_STILL_STEP = 1e-6

#: Half-side of the cube (unit frame) rays are clipped to: the domain the networks were fitted on.
TRACE_BOUND = 1.0

#: Shadow and ambient-occlusion rays start this far (unit frame) off the surface, along its normal.
SHADOW_BIAS = 4e-3

#: The guaranteed caster's tolerance δ of Spelunking's Procedure 2 (unit frame): it reports a hit within δ.
GUARANTEED_TOLERANCE = 1e-3

#: Vertices closer than this (unit frame) are welded on load: the splits that OBJ ``v/vt`` pairs and glTF
#: make at UV seams are undone, so the mesh gets its true topology (watertightness, genus).
MERGE_DISTANCE = 1e-9

# --- model files: what a header may ask for before anything is allocated (neural_bake.fields) --------------
#: Widest hidden layer a model file may declare (the papers' fine networks are 256 wide).
MAX_NET_WIDTH = 4096

#: Most hidden W×W matrices a model file may declare (the papers' fine networks have 3).
MAX_NET_DEPTH = 32

#: Largest input dimension a model file may declare (3 for space, 4 for space-time).
MAX_NET_IN_DIM = 8

#: Largest output dimension a model file may declare (1 for an SDF, 3 or 4 for colour).
MAX_NET_OUT_DIM = 16

#: Largest number of tiles (:class:`~neural_bake.nets.tiles.TiledSiren`) and cells per axis of their grid a
#: model file may declare (a 64³ grid of 64-wide tiles would be 260,000 networks; fits use ~50–120 on 6³).
MAX_TILES = 4096
MAX_TILE_GRID = 64

#: Most levels a feature-grid network may declare (:class:`~neural_bake.nets.grid.GridNet`).
MAX_GRID_LEVELS = 32

#: Most features per grid vertex a feature-grid network may declare.
MAX_GRID_FEATURES = 16

#: Largest log2 of a feature-grid level's table size (entries per level) a network may declare.
MAX_GRID_LOG2_TABLE = 24

#: Finest grid resolution (cells per side of the unit frame) a feature-grid network may declare.
MAX_GRID_RESOLUTION = 1 << 16

#: Most levels a nested-sequence file may declare.
MAX_NESTED_LEVELS = 16

#: Deepest JSON nesting ([ and {) a model file's header may have; deeper is refused before parsing.
MAX_HEADER_DEPTH = 32

#: Largest magnitude a space-time header's time range ends and time extent may have, and a time may have: the
#: network's time input τ (in [-time_extent, time_extent]) and every time stay finite float32 numbers.
MAX_TIME_MAGNITUDE = 1e30

#: Most surface points a texture model file may record of the mesh it was fitted on.
MAX_TEXTURE_SURFACE_POINTS = 4096

# --- sizes a user can ask for: refused in one line before anything is allocated ------------------------------
#: Widest or tallest image (pixels) a render may ask for.
MAX_IMAGE_SIDE = 16384

#: Most pixels (width × height) a render may ask for: its per-pixel ray and output buffers stay within memory.
MAX_IMAGE_PIXELS = 1 << 24

#: Widest view (pixels a side) and most views a bake's visual check (`view`) may ask for.
MAX_VIEW_SIDE = 4096
MAX_VIEWS = 720

#: Most frames (frame times) a space-time render, a per-frame bake or a sequence fit may ask for.
MAX_FRAMES = 10_000

#: Largest map side × supersampling (samples per side) a bake may ask for: the texel samples of the map.
MAX_MAP_SAMPLES_SIDE = 16384

#: Most marching-cubes cells per axis a per-frame bake may ask for.
MAX_MARCH_RESOLUTION = 1024

#: Most iterations per level a scene's sphere tracing may ask for.
MAX_TRACE_ITERATIONS = 100_000

#: Most rays per batch a scene's sphere tracing may ask for (each batch's buffers are allocated at once).
MAX_TRACE_CHUNK = 1 << 22

#: Most lights a scene may hold (every light shades, and shadows cast a ray, per pixel).
MAX_SCENE_LIGHTS = 64

#: Most objects a scene may hold.
MAX_SCENE_OBJECTS = 256

#: Most batch workers (assets at once) a batch may ask for.
MAX_BATCH_WORKERS = 1024

#: Most torch threads per batch worker a batch may ask for.
MAX_BATCH_THREADS = 1024

# --- bake: does the SDF describe the mesh? ---------------------------------------------------------------------
#: Frames (centre and scale) of an SDF and the mesh it bakes onto may differ by this much, relative to the
#: unit frame (centre offset × scale, |scale ratio − 1|), before the bake refuses the SDF.
FRAME_MISMATCH_TOL = 1e-3

#: Median |f| (unit frame) at the fine mesh's surface samples above which the bake refuses the SDF: a fitted
#: SDF of that mesh reads well under this (its sampled distance error), another shape's reads far above.
SDF_MISMATCH_MEDIAN = 0.02

#: Surface samples of the fine mesh at which the bake measures the SDF's median |f|.
SDF_CHECK_SAMPLES = 4096

#: Surface points of its mesh (unit frame) a texture fit records in the texture model file: a later SDF whose
#: median |f| there exceeds ``SDF_MISMATCH_MEDIAN`` describes another surface than the texture's.
TEXTURE_SURFACE_SAMPLES = 256

#: Hybrid bake: a texel whose source-surface point (where the classical bake's ray lands) has |f| above this
#: (unit frame) is one the neural field does not represent; it takes the classical mesh-to-mesh normal.
HYBRID_SDF_TOL = 0.01

#: Hybrid bake: a texel whose ∇f differs from the source mesh's normal there by more than this many degrees
#: takes the classical mesh-to-mesh normal; it bounds how much worse than the source a baked texel can be. At 5°
#: (against 20°) the scans' and CAD parts' maps keep their medians and lose up to half of their p95 (ogre 9.6° →
#: 4.6°, nefertiti 4.4° → 3.1°) for 0.4–9 % more classical texels and no measurable bake time (docs/findings.md).
HYBRID_ANGLE_DEG = 5.0

#: Heap a texel bake uses per sample position (H·W·s²) beyond what the process holds before it (imports, model):
#: the peak resident sets of the bake command on Spot were 0.9 GB at 1024² and 1.6 GB at 2048², against 0.5 GB
#: before its first stage: 370 and 270 bytes a sample. The command reserves this much heap ahead of its first
#: stage (:func:`neural_bake.bake.job.reserve_heap`), at most half the machine's free memory.
BAKE_HEAP_PER_SAMPLE = 280

#: xatlas packs the charts of a larger map on a grid of this side, its padding scaled down with it, and the map
#: scales the layout up: packing time grows with the grid's area (Spot decimated to 2,000 faces: 0.09 s at 1024,
#: 0.27–0.31 s at 2048, 0.85–1.5 s at 4096), while the charts and their gaps in texels of the map stay (the gaps
#: are rounded up to whole grid texels).
UNWRAP_PACK_SIDE = 1024

#: A bake report compares a map larger than this (side, texels) with the truth and the classical baseline on a
#: lattice of its texels, every k-th of each row and column (k = ceil(side / this)), and draws its error maps
#: at that lattice: the figures are then a systematic subsample stated with their confidence intervals. At 512
#: the error maps are at least as fine as the report shows them (256 px, and as the coarse mesh's texture in
#: its views), and the command baking a 2048² normal map ends 0.44 s sooner than at 1024 (its median's interval
#: about ±0.003°).
REPORT_LATTICE_SIDE = 512

#: Hybrid bake with a texture: a texel whose neural colour differs from the source texture's at the same source
#: point by more than this CIEDE2000 ΔE (about 1 to 2 is just noticeable, 10 a clearly different colour) takes the
#: source's colour.
HYBRID_COLOR_DELTA_E = 2.0

#: Hybrid bake with a texture: the dB of PSNR the colours may lose against a classical transfer into the same map
#: (:func:`neural_bake.bake.hybrid.colour_budget`). 0: a neural colour stays only where the map stores the same
#: value as the transfer's. A budget above 0 is a share of the map's quantisation noise, which a transfer's error
#: reaches on most textures but not on one whose values land on the map's (a bake onto the source's own layout):
#: there any kept difference costs more than the budget's dB.
HYBRID_COLOR_WITHIN_DB = 0.0

#: Hybrid bake decided on the adaptive lattice: this share of the interpolated samples it leaves undecided
#: (a seeded uniform choice, per band at least HYBRID_CHECK_MIN) is decided in full, to count what it missed.
HYBRID_CHECK_FRACTION = 1.0 / 1024

#: Least number of undecided samples per band that a lattice-decided hybrid bake checks in full.
HYBRID_CHECK_MIN = 256

#: Hybrid bake decided on the adaptive lattice: of the samples the bake evaluated, those of texels whose row and
#: column are multiples of this are decided first; the others are decided when one found unfaithful lies within
#: this many positions (1: every evaluated sample first).
HYBRID_STRIDE = 2

#: Hybrid bake on the adaptive lattice: a cell that fails its bilinear test and has at least this many of its 9 nodes
#: found unfaithful is given up to the classical bake (all its texels take the classical normal; their colours go
#: through the colour rules) instead of refined. On the ogre's 2048² map (`quick` SDF) 7 saves 157k of 905k
#: evaluations for 14k more classical texels (0.5 %); 9 would save 79k (docs/findings.md, "cells given up to the
#: classical bake").
HYBRID_GIVE_UP_NODES = 7

#: Hybrid bake on the adaptive lattice: a cell of at most this side (sample-grid positions) that fails its
#: interpolation test, all of whose 9 nodes' classical rays hit the source, is given up to the classical bake
#: (reason "detail"): the fields vary faster than the lattice holds there, every texel would be evaluated one by
#: one, and the classical normal costs a fifth of a (256, 3) network's evaluation and is the source's own.
#: In a bake of normals alone the same side bounds two more rules: a cell whose nodes' rays all hit a source whose
#: normals fail the interpolation test is given up before ∇f is evaluated at its nodes (the source's detail), and
#: the samples no cell holds within half this side of a given-up one take the classical normal where their rays hit
#: (the detail rim). 0: never. docs/findings.md, "Detail cells to the classical bake" and "The source's detail".
HYBRID_DETAIL_SIDE = 8

# --- bake: adaptive texel evaluation (neural_bake.bake.adaptive) ------------------------------------------------
#: Default tolerance (degrees) of adaptive texel evaluation: a cell of the lattice is interpolated only when
#: the normals at its edge midpoints and centre lie within ADAPTIVE_SAFETY times this of what its corners
#: predict. Measured on a fitted (256, 3) Spot at 2048² (BENCHMARKS.md), the interpolated normals then stay
#: within 0.012° median, 0.05° p95 and 0.22° max of a full evaluation: under half the angle one step of an
#: 8-bit normal map spans (about 0.45°), so the map cannot show it.
ADAPTIVE_TOLERANCE_DEG = 0.5

#: Coarse lattice step (sample-grid positions, a power of two) at which adaptive evaluation starts in each chart.
ADAPTIVE_LATTICE = 16

#: Adaptive evaluation: a cell whose colours (linear RGB(A)) differ from its corners' interpolation by more than
#: this is refined (half an 8-bit step): the albedo map keeps the same refinement as the normal map.
ADAPTIVE_COLOR_TOL = 0.5 / 255

#: Adaptive evaluation: a cell whose f (unit frame) differs from its corners' interpolation by more than this is
#: refined; f at texels only flags misses (|f| > δ), so this is a fraction of the narrowest bands.
ADAPTIVE_VALUE_TOL = 5e-3

#: Adaptive evaluation accepts a cell when its surplus (the midpoints' deviation from the corners' prediction) is
#: at most this fraction of each tolerance: the margin for what an estimate from five points can miss.
ADAPTIVE_SAFETY = 0.5

#: Adaptive evaluation: a cell wider than this (sample-grid positions) is refined when a feature of the coarse mesh
#: lies inside it (an edge bending more than ``ADAPTIVE_EDGE_DEG``, with its end vertices), where interpolation
#: errs most.
ADAPTIVE_VERTEX_SIDE = 4

#: Adaptive evaluation: an edge of the coarse mesh whose faces' normals differ by more than this (degrees) is a
#: feature: cells wider than ``ADAPTIVE_VERTEX_SIDE`` it crosses are refined. At 2048² on a
#: 2,000-face Spot, 10° refined a third of the evaluations for nothing the check against a full evaluation
#: could see; at 40° the ogre's largest checked error rose from 0.18° to 0.91° (docs/findings.md).
ADAPTIVE_EDGE_DEG = 20.0

#: A texel sample lies on the sample grid when its UV position is within this (sample-grid units) of a grid
#: position; the others (border samples at a triangle's closest point) are evaluated, never interpolated.
ADAPTIVE_GRID_SNAP = 1e-3

#: Texel samples (about; a seeded uniform choice) at which an adaptive or reduced-precision bake evaluates the
#: fields fully in float32 to measure its error against a full evaluation (the bake report's ``error_control``).
ADAPTIVE_CHECK_SAMPLES = 4096

#: precision "auto": bfloat16 hidden GEMMs are used only where a (4096, W) × (W, W) product with its conversions
#: measured at least this many times faster than in float32 on the device (the rest of the work stays float32).
BF16_MIN_SPEEDUP = 1.3

#: precision "auto" in a bake also keeps float32 when bfloat16 normals measured a median angle above this (degrees)
#: off float32 ones at a probe of the bake's own points: half the bake's budget against a full float32 evaluation.
BF16_MAX_MEDIAN_DEG = 0.05

#: Points of a bake at which precision "auto" compares bfloat16 with float32 before choosing.
PRECISION_PROBE_POINTS = 1024

#: Float32 CPU GEMMs go to oneDNN instead of the BLAS (nets.cpu_gemm) only where a (4096, W) × (W, W) product
#: measured at least this many times faster there: below it the choice is within timing noise.
ONEDNN_MIN_SPEEDUP = 1.1

#: ... and only where that product's error relative to float64 stayed within this: float32 GEMMs of widths up
#: to 512 read ~1e-6; one with its operands rounded to bfloat16 ~1e-3.
FP32_GEMM_REL_TOL = 1e-5

#: A camera whose up vector's cross product with the view direction is shorter than this has up parallel to
#: the view: it has no image basis and is refused.
CAMERA_PARALLEL_EPS = 1e-9

#: A time-budgeted fit that made fewer than this fraction of the steps its preset makes on this machine (its
#: asset's own sampling work included) warns that it was slowed (the machine was busy) and is weaker than the
#: preset's.
BUDGET_WARN_FRACTION = 0.5

#: A time-budgeted fit's account notes (no warning: its expected steps count that work) when drawing its
#: training samples, work that grows with its mesh (an open mesh's winding numbers, mining), took at least
#: this share of its time.
BUDGET_SAMPLING_SHARE = 0.5

#: A time-budgeted SDF fit rebuilds its sample pools (every ``refresh_every`` steps) only while the rebuilds,
#: the next one included, stay within this share of its time; a mesh whose pools are slow to draw (an open
#: scan's winding numbers: 40 s for the 124k-face ogre) keeps its pools longer instead of losing its steps.
POOL_REFRESH_MAX_SHARE = 0.2

#: Pixels peeled off the common mask of two renders before an "interior" comparison: the outline of a coarse
#: mesh differs from its source's by a pixel or two, and those pixels would swamp the shading differences.
INTERIOR_ERODE_PX = 2

#: Interior PSNR (dB, sRGB) a correct bake's render reaches against the analytic reference render of its
#: sample; a normal map with its green channel flipped, or no maps, stays below it.
BAKED_RENDER_MIN_PSNR_DB = 45.0

#: Silhouette agreement (intersection over union) of model-viewer's picture of a bake in headless Chromium
#: and our render of the same view: the camera mapping (orbit, target, field of view) is right.
BROWSER_MASK_MIN_IOU = 0.97

#: Interior PSNR (dB, sRGB) between model-viewer's picture (PBR, sun HDR, neutral tone mapping) and our
#: Blinn-Phong render of the same view: the two shaders differ, so this checks agreement, not equality.
BROWSER_MATCH_MIN_PSNR_DB = 21.0

#: Correlation of the fine detail (image minus its Gaussian blur, σ = 4 px) of model-viewer's picture with
#: our render's: the normal map's bumps sit where ours do (a flipped green channel moves them).
BROWSER_DETAIL_MIN_CORR = 0.9

#: A float64 vector no longer than this has no direction: normalising it gives the caller's fallback (+Z, the
#: face normal, zero), never NaN.
DIRECTION_EPS = 1e-12

#: A float64 length no larger than this counts as zero in a division (an underflow guard: any other length
#: still normalises).
UNDERFLOW_EPS = 1e-300

#: A length or range (max − min) no larger than this is treated as this, so that dividing by it stays finite
#: (a zero-size mesh, a flat depth range).
MIN_SPAN = 1e-12

#: The smallest positive value a float32 step takes before a logarithm or a division (float32's own
#: smallest normal is ~1.2e-38; 1e-300 would round to zero).
FLOAT32_FLOOR = 1e-30

#: Radiance below this is black in an RGBE (Radiance .hdr) pixel: its shared exponent would underflow.
RGBE_MIN = 1e-32

#: Two copies of a mesh's faces are the same where their corners agree within this fraction of the mesh's
#: extent (a file's own corners against the loaded, welded mesh).
FACE_MATCH_REL_TOL = 1e-6

#: Corner normals closer than this (per component) are one normal: the corners share a vertex; farther
#: apart they are a hard edge and the vertex is split.
CORNER_NORMAL_MATCH_TOL = 1e-6

#: How many triangle sets keep their open3d ray-casting scene (BVH) in memory, so that the stages that query
#: one mesh (sampling, metrics, baseline bake, hybrid bake, report, viewer) build it once.
RAYCAST_SCENE_CACHE = 4

#: |du1 dv2 - du2 dv1| below this (twice the UV area) marks a face with degenerate UVs: it adds no tangent.
UV_DET_EPS = 1e-14

#: A tangent shorter than this after Gram-Schmidt is replaced by the fallback tangent.
TANGENT_EPS = 1e-12

#: UV coordinates that differ by at most this are the same point (one vertex UV; an edge that is no seam).
UV_MATCH_TOL = 1e-9

#: Barycentric tolerance for "texel centre inside the triangle" (in units of barycentric coordinates).
TEXEL_INSIDE_EPS = 1e-9

#: A texel centre whose barycentrics all exceed this is strictly inside one triangle (not on a shared edge).
TEXEL_STRICT_EPS = 1e-7

#: Twice the UV-pixel area below which a UV triangle is degenerate and covers no sample.
UV_AREA_EPS = 1e-12

#: Slack (in pixels) of the scanline spans; samples found are then tested with barycentrics.
TEXEL_SPAN_TOL = 1e-6

#: A UV edge whose height in pixels is below this is horizontal: it crosses no scanline.
UV_FLAT_EDGE_EPS = 1e-12

#: A texel square overlaps a triangle when the largest edge function over the square exceeds this (pixels²).
TEXEL_OVERLAP_EPS = 1e-12

#: A TBN frame whose determinant is below this fraction of its scale is degenerate: no tangent-space normal.
TBN_DET_REL_EPS = 1e-8

#: Floor of |∇f| in the training loss's normal term (cosine of ∇f and n): a vanishing gradient gives a bounded
#: term, never NaN.
LOSS_GRAD_FLOOR = 1e-6

#: ε of the training loss's angle term √(2(1 − cos θ) + ε²) − ε (radians, about 0.06°): below it
#: the term is quadratic, so its gradient stays bounded (1 / ε) where ∇f meets the target normal.
NORMAL_ANGLE_EPS = 1e-3

#: A uniform pool point counts as one of the network's sign errors (``SdfFitConfig.sign_fraction``) only when
#: its true distance is at least this far from the surface (unit frame): closer, a wrong sign is the
#: surface's own fitting error, which the surface and near terms train.
SIGN_MINING_TOL = 0.01

#: A point's inside test is *sure* when the mesh is watertight (ray parity) or its generalised winding number
#: lies at least this far from 1/2 (0 outside, 1 inside a closed part): near an open sheet (a tray, a leaf, a
#: cup's rim) both sides read about 1/2, and a sign the mesh does not define must not be mined or audited,
#: or the fit pushes both sides of the sheet out and loses its surface.
SIGN_SURE_MARGIN = 0.25

#: The band audit of a residual construction (``SdfFitConfig.audit_candidates``): Gauss–Newton steps on h² that
#: move each uniform candidate towards the coarse level's small values, the damping added to |∇h|² (so a
#: candidate in a valley of h that stops short of zero settles on its floor instead of being thrown out), and
#: the longest step (unit frame).
AUDIT_STEPS = 8
AUDIT_DAMPING = 1e-2
AUDIT_MAX_STEP = 0.25

#: A mined point of the network's zero set is kept when its |f| after the Newton projection is at most this.
MINED_ZERO_SET_TOL = 1e-3

#: A point projected onto a space-time field's zero set is used as a surface sample only where |∇f| is above
#: this (its normal ∇f/|∇f| is defined).
MIN_SURFACE_GRAD = 1e-3

#: The least time budget (minutes) left to a space-time fit's training loop after its set-up.
MIN_BUDGET_MINUTES = 1e-3

#: The Newton projection onto f = 0 leaves a point whose |∇f|² is at most this where it is (no NaN).
NEWTON_MIN_GRAD_SQ = 1e-12

#: The divergence test compares a step's loss with a multiple of the first loss, the first loss floored at this.
BLOWUP_LOSS_FLOOR = 1e-6

#: Relative margin on the input-rounding radius of a range-analysis box (covers the rounding of the radius
#: computation itself, so the bound stays sound).
RANGE_ROUNDING_MARGIN = 1e-6

#: Distance floor (unit frame) of a winding-number dipole term: a query at a cluster's centre stays finite.
DIPOLE_MIN_DISTANCE = 1e-30

#: A duration (seconds) below this is taken as this when a rate divides by it.
MIN_SECONDS = 1e-9

#: The certificate of a nesting bound refines boxes until their bound is below the target, never a target
#: below this (unit frame).
CERTIFY_MIN_TARGET = 1e-9

# --- CPU threads (neural_bake.nets.threads) -------------------------------------------------------------------
#: A thread probe keeps a larger count unless a smaller one is faster by more than this factor.
THREAD_MARGIN = 1.10

#: A one-off thread choice stops timing after a round in which the fastest count beat every other by this factor
#: (far beyond a quiet machine's jitter of about ±15 %), instead of timing its remaining rounds.
THREAD_DECISIVE = 1.4

#: Steps a loop runs on all its threads before its first thread probe (its one-time costs: pools, compiles).
THREAD_WARMUP_STEPS = 5

#: Steps a thread probe times per candidate count (after one warm-up step that is not counted).
THREAD_TRIAL_STEPS = 3

#: Step times whose median a loop watches for drift after a thread choice.
THREAD_WINDOW = 20

#: A median step time this many times slower (or faster) than at the last choice starts a new probe.
THREAD_DRIFT = 1.5

#: Least seconds between two drift-started probes (a probe runs slower counts too: it has a cost).
THREAD_PROBE_INTERVAL_S = 10.0

#: Seconds after which a loop running fewer threads than cores probes again (a neighbour may have stopped).
THREAD_REPROBE_S = 60.0

#: A candidate count whose first (warm-up) step in a probe is this many times slower than the best count so
#: far is not tried further.
THREAD_ABORT_FACTOR = 3.0

#: Largest share of a loop's time its periodic thread probes may cost (a costly probe waits longer).
THREAD_PROBE_SHARE = 0.05
