"""Neural texture fitting with an optional gradient-orthogonality term (§4.2 of the nested-neighbourhoods paper).

A colour SIREN ``g: R^3 -> RGB`` (unit frame) is trained with

    L(φ) = mean_surface (g − ĝ)²  +  λ · mean_band Σ_c ⟨∇g_c, n⟩²,

where ĝ is the mesh's texture (bilinear lookup through the UVs, in linear RGB, then sRGB-encoded when the
network holds sRGB colours: ``encoding``, below), the band is ``|f| ≤ δ`` around
the zero set of a frozen SDF ``f`` and ``n = ∇f / |∇f|`` (GEMM normals, computed once under no_grad since f
does not train). ``∇g`` is the differentiable GEMM Jacobian (3 × 3, out × in) of the colour network (default;
``orth_method="directional"`` computes the same ⟨∇g_c, n⟩ as one forward-mode GEMM stream along n, a
cheaper term), so the second term makes the colours constant along the normal lines: a coarse surface up to
δ away from the fine one reads the right colour.

Choosing λ: the default is 0. Bakes and the renderer's normal mapping read g at the closest point of f = 0,
p − f(p)·∇f(p) (the point the paper's attribute mapping carries to p), so the band's constancy comes from
where g is read, not from training. On real textures the term costs what it buys: a detailed texture has a
large ∇g along the surface, and a ∇f tilted by a degree turns part of it into ⟨∇g, n⟩, which the term fights
(the tea set, 90 s of the default preset: λ = 1e-3 22.4 dB surface PSNR, λ = 0 30.3 dB; baked onto three
coarse meshes 4.3–6.9 dB higher with λ = 0 read at the closest point; docs/findings.md). λ = 1e-3 is the
paper's regulariser, for colour fields read off the surface where nothing projects (another renderer).

Encoding: by default g holds sRGB-encoded colours (:func:`~neural_bake.fields.texture.decode_colors` turns
them back to linear wherever the field is read), so the loss spreads the error as an 8-bit colour map does;
in linear RGB the same error budget is spent on the bright texels and the dark ones read several dB worse
once encoded (the cabinet, 90 s of the default preset, baked: 27.3 dB against 25.9 dB; docs/findings.md).
HDR textures (values above 1) are fitted in linear RGB.

Band samples: surface samples moved along their (mesh) normals by offsets uniform in [−δ, δ], plus uniform
points of the unit cube kept where ``|f| ≤ δ`` (``band_uniform_fraction`` of each band batch).

Policies for the hard cases:
- textures with alpha: RGB is fitted and alpha is ignored (straight alpha: the RGB is the colour; a
  :class:`NeuralBakeWarning` says so when some alpha is below 1). Nothing is premultiplied.
- 8/16-bit textures given as integer arrays are taken as sRGB and decoded to linear; float textures are
  linear data, fitted as they are (HDR values above 1 are kept; PSNR then uses peak 1).
- UVs outside [0, 1] follow ``mesh.uv_policy`` ("wrap" or "clamp"), as :func:`sample_texture` does.
- meshes without UVs or without a texture: :class:`MeshError`; non-finite texels: :class:`ImageError`.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..constants import FRAME_MISMATCH_TOL
from ..errors import FitError, ImageError, MeshError, NeuralBakeWarning
from ..fields import (ENCODINGS, NestedSequence, SdfField, TextureField, closest_surface_points, load_sdf_field,
                      save_model, to_sdf_field, unit_normals)
from ..geometry import frame_mismatch, interpolate_corners
from ..io.colour import linear_to_srgb, sample_texture, srgb_to_linear
from ..mesh.texels import face_uv_areas, texel_centres
from ..mesh.views import render_views
from ..nets.gemm import sin_cos
from ..nets.grid import GridNet, check_grid_settings
from ..nets.siren import Siren
from ..types import Frame, Mesh
from .record import FitRecord
from .training import PresetLoopSettings

__all__ = [
    "TextureFitConfig",
    "TextureFit",
    "PRESETS",
    "DEFAULT_DELTA",
    "fit_texture",
    "pool_size",
    "texture_metrics",
    "texture_targets",
    "texel_face_weights",
    "band_orthogonality",
    "make_texture_network",
    "NETWORKS",
    "PRESET_SIRENS",
]

#: Most surface samples the band pool (λ > 0) offsets, and its uniform candidates: each costs f and ∇f.
BAND_POOL = 1_000_000

#: δ (unit frame) used when neither the config nor the SDF model file gives one: 1/60 of the unit-frame
#: extent (1.8), about the band half-width of the paper's coarse levels.
DEFAULT_DELTA = 0.03

#: An SDF as a callable: (N, 3) points -> ((N,) values, (N, 3) gradients), tensors on the points' device.
SdfCallable = Callable[[torch.Tensor], "tuple[torch.Tensor, torch.Tensor]"]


@dataclass
class TextureFitConfig(PresetLoopSettings):
    """Settings of :func:`fit_texture` (the loop's first: :class:`~neural_bake.fit.training.PresetLoopSettings`);
    one line per field (the CLI help comes from these)."""

    steps: int = 2000  # the loop's settings with this fit's defaults
    progress: bool = False

    network: str = "siren"
    """The colour network: "siren" (a sine MLP of the point) or "grid" (a multiresolution feature grid, the
    grid_* settings, in front of a small MLP whose width and depth are width and depth)."""
    width: int = 256
    """W: width of the colour network's hidden layers."""
    depth: int = 3
    """D: number of hidden W×W matrices (D + 1 hidden layers); (256, 3) is the paper's fine net."""
    grid_levels: int = 16
    """network "grid": number of grid levels, coarse to fine."""
    grid_features: int = 2
    """network "grid": features per grid vertex."""
    grid_log2_table: int = 16
    """network "grid": log2 of a level's most table entries (finer levels share them through a spatial hash)."""
    grid_base_resolution: int = 16
    """network "grid": cells per side of the unit frame's cube at the coarsest level."""
    grid_max_resolution: int = 1024
    """network "grid": cells per side at the finest level (about the texture's texels across the asset)."""
    grid_activation: str = "relu"
    """network "grid": the MLP's hidden activation, "relu" or "sine" (sin(ω x), ω = hidden_omega)."""
    normal_inputs: str = "off"
    """network "grid": "on", the MLP also reads the surface normal (the mesh's face normal in training; bakes
    onto the mesh itself read it, others and the renderer the SDF's ∇f), so faces meeting at an edge or lying
    back to back keep their own colours; "off"; "auto": on for an open mesh (boards, panels), off for a closed
    one, whose smooth textures it costs (BENCHMARKS.md)."""
    normal_jitter_deg: float = 15.0
    """normal_inputs: each step tilts every sample's normal by a random angle up to this (degrees), in a random
    direction, so the colours do not hang on small changes of the normal: a bake reads ∇f or another mesh's
    normals, a few degrees from the source's faces (0: the exact face normals)."""
    omega_0: float = 30.0
    """ω0 of the SIREN's first layer (frequency of the colour field over the unit frame)."""
    hidden_omega: float = 30.0
    """ω of the later hidden layers."""
    batch: int = 4096
    """Surface samples per step (colour term)."""
    band_batch: int | None = None
    """Band samples per step (orthogonality term); None: ``batch // 4`` (measured: as constant as ``batch``)."""
    lam: float = 0.0
    """λ: weight of the orthogonality term Σ_c ⟨∇g_c, n⟩² (0: off, bakes read g on f = 0; 1e-3: paper)."""
    delta: float | None = None
    """δ: band half-width in the unit frame; None: the SDF model file's "delta", else DEFAULT_DELTA."""
    orth_method: str = "jacobian"
    """How ⟨∇g_c, n⟩ is computed: "jacobian" (differentiable GEMM Jacobian) or "directional" (same values, one directional derivative instead of the Jacobian)."""
    band_uniform_fraction: float = 0.25
    """Share of each band batch drawn from uniform points with |f| ≤ δ (the rest: offset surface points)."""
    pool: int = 1_000_000
    """Surface samples drawn once and batched from (at most steps × batch; and the band pool's, up to a
    million); a grid network passing over one million many times learns the samples, not the texture between
    them (BENCHMARKS.md)."""
    texel_share: float = 0.5
    """Part of the surface samples drawn by UV area (as densely as the texture's texels lie on the surface)
    instead of surface area: a bake is scored per texel, and small parts with detailed texture (hardware,
    edges) get many texels on little surface (0: all by area)."""
    edge_share: float = 0.0
    """Part of the surface samples placed along the texture's edges: in texels drawn with probability
    proportional to the texture's colour step around each (:func:`edge_strength`), at a random place in the
    texel, so the loss weighs the edges more. Flat-colour textures change at sharp borders, where a network
    blurs and rings; 0: none."""
    encoding: str = "auto"
    """Colours the network holds: "srgb" (encoded as an 8-bit colour map is), "linear", or "auto": sRGB
    unless the texture has values above 1 (HDR, fitted linear). Recorded in the model file."""
    max_restarts: int = 4
    """Divergence recoveries (restore the last snapshot, halve lr) before giving up with FitError."""
    device: str = "cpu"
    """Torch device for training."""
    dtype: str = "float32"
    """Torch dtype for training ("float32" or "float64")."""


#: The colour networks :class:`TextureFitConfig` builds (``network``).
NETWORKS = ("siren", "grid")

#: The settings of a grid network (``network="grid"``) beside width and depth.
GRID_FIELDS = ("grid_levels", "grid_features", "grid_log2_table", "grid_base_resolution", "grid_max_resolution",
               "grid_activation")

#: Named presets (fields overridden on top of the defaults). Times are wall-time budgets; the step caps are
#: safety nets far above what a budget reaches, so a preset runs its whole budget. What they reach:
#: BENCHMARKS.md. Names: :mod:`neural_bake.fit.presets` (fast, medium and fine are aliases of quick, default
#: and high).
PRESETS: dict[str, dict] = {
    "quick": {"network": "grid", "width": 64, "depth": 1, "minutes": 1.0, "steps": 200_000, "batch": 2048,
              "lr": 1e-2, "edge_share": 0.5, "normal_inputs": "auto", "pool": 4_000_000},
    "default": {"network": "grid", "width": 64, "depth": 2, "minutes": 4.0, "steps": 200_000, "batch": 4096,
                "lr": 1e-2, "edge_share": 0.5, "normal_inputs": "auto", "pool": 8_000_000},
    "high": {"width": 256, "depth": 3, "minutes": 10.0, "steps": 200_000, "batch": 2048, "lr": 2e-4},
}


#: The SIREN settings of a preset whose network is a grid, applied when ``network="siren"`` is asked for with it.
PRESET_SIRENS: dict[str, dict] = {"quick": {"width": 64, "depth": 1, "lr": 5e-4, "edge_share": 0.0,
                                            "normal_inputs": "off"},
                                  "default": {"width": 192, "depth": 3, "omega_0": 60.0, "lr": 5e-4, "edge_share": 0.0,
                                              "normal_inputs": "off"}}


@dataclass
class TextureFit(FitRecord):
    """The result of :func:`fit_texture` (:class:`~neural_bake.fit.record.FitRecord`).

    - ``model``: the colour network (in 3, out 3; a :class:`Siren`, or a :class:`~neural_bake.nets.grid.GridNet`
      with ``network="grid"``), unit-frame points -> RGB in ``encoding``.
    - ``encoding``: "srgb" or "linear", what the network's outputs hold (:meth:`field` decodes them).
    - ``frame``: the mesh's frame (unit <-> source); the model works in the unit frame.
    - ``delta``, ``lam``: the band half-width and λ used.
    - ``config``: the full :class:`TextureFitConfig`.
    - ``fitted_against``: the SDF the band came from: ``{"name", "kind" ("sdf", "nested", "analytic"),
      "delta", "surface"}`` (``surface``: seeded points of the mesh's surface, unit frame).
    - ``history``: one dict per logged step: step, seconds, lr, loss, colour (MSE), orth (mean Σ_c ⟨∇g_c,n⟩²;
      absent when λ = 0).
    - ``steps``, ``seconds``: steps done and wall time; ``stopped_reason``: "steps" or "time budget";
      ``restarts``: divergence recoveries (each halved the learning rate).
    - ``budget``: a time-budgeted fit's account (:func:`neural_bake.fit.budget.fit_budget`: steps made
      beside the steps its preset makes on this machine, why it stopped, the warning if any), a
      ``budget="steps"`` fit's (:func:`neural_bake.fit.budget.steps_budget`: the preset's reference steps and
      their estimated seconds here); else None.
    - ``threads``: the CPU threads the steps ran with (:meth:`~neural_bake.nets.threads.ThreadTuner.summary`).
    """

    config: TextureFitConfig = field(default_factory=TextureFitConfig)
    delta: float = DEFAULT_DELTA
    lam: float = 0.0
    budget: dict | None = None
    fitted_against: dict | None = None
    encoding: str = "linear"

    def metadata(self) -> dict:
        """The JSON metadata stored with the model file (with ``budget`` when the fit had a time budget)."""
        meta = _metadata(self.frame, self.delta, self.lam, self.config, self.steps, self.fitted_against,
                         self.encoding)
        if self.budget is not None:
            meta["budget"] = self.budget
        # the loss curve (finite rows: JSON has no NaN) for reports' accuracy-vs-time plots
        training = self.training()
        rows = [h for h in training["history"] if all(math.isfinite(v) for v in h.values() if isinstance(v, float))]
        training.update(history=rows, final=rows[-1] if rows else {})
        meta["training"] = training
        return meta

    def field(self) -> TextureField:
        """The fitted colour network as a :class:`~neural_bake.fields.TextureField`."""
        return TextureField.from_model(self.model, frame=self.frame, delta=self.delta, name="texture fit",
                                       fitted_against=self.fitted_against, metadata=self.metadata(),
                                       encoding=self.encoding)

    def save(self, path) -> Path:
        """Write the model file (safetensors + metadata kind="texture", frame, delta, lam, config, the SDF it
        was fitted against)."""
        save_model(self.model, path, **self.metadata())
        return Path(path)


def _metadata(frame: Frame, delta: float, lam: float, config: TextureFitConfig, steps: int,
              fitted_against: dict | None = None, encoding: str = "linear") -> dict:
    cfg = asdict(config)
    out = {"kind": "texture", "frame": frame.to_dict(), "delta": float(delta), "lam": float(lam),
           "encoding": encoding, "config": cfg, "steps": int(steps)}
    if fitted_against is not None:
        out["fitted_against"] = fitted_against
    return out


# ----------------------------------------------------------------------------------------------------------
# inputs: texture, SDF


def _texture_rgb(mesh: Mesh, texture: np.ndarray | None) -> np.ndarray:
    """The RGB texture to fit, float32/64 linear (H, W, 3); applies the alpha and bit-depth policies."""
    if mesh.uv is None:
        raise MeshError(f"{mesh.name}: mesh has no UV coordinates; texture fitting needs UVs and a texture")
    tex = mesh.texture if texture is None else texture
    if tex is None:
        raise MeshError(f"{mesh.name}: mesh has no texture image; pass one (texture) to fit a texture")
    tex = np.asarray(tex)
    if tex.ndim == 2:
        tex = tex[:, :, None]
    if tex.ndim != 3 or tex.shape[2] not in (1, 2, 3, 4) or tex.shape[0] < 1 or tex.shape[1] < 1:
        raise ImageError(f"{mesh.name}: texture must be (H, W, C) with C in 1..4, got shape {tex.shape}")
    if np.issubdtype(tex.dtype, np.integer):
        peak = float(np.iinfo(tex.dtype).max)
        tex = srgb_to_linear(tex.astype(np.float32) / peak)
    elif not np.issubdtype(tex.dtype, np.floating):
        raise ImageError(f"{mesh.name}: texture has unsupported dtype {tex.dtype}")
    c = tex.shape[2]
    if c in (2, 4):
        alpha = tex[:, :, -1]
        if np.isfinite(alpha).all() and float(alpha.min()) < 1.0:
            warnings.warn(f"{mesh.name}: texture has alpha below 1; fitting RGB only (alpha ignored, "
                          "not premultiplied)", NeuralBakeWarning, stacklevel=3)
        tex = tex[:, :, :-1]
    if tex.shape[2] == 1:
        tex = np.repeat(tex, 3, axis=2)
    if not np.isfinite(tex).all():
        bad = int((~np.isfinite(tex)).any(axis=2).sum())
        raise ImageError(f"{mesh.name}: texture has {bad} texels with NaN or infinite values")
    return tex


def _resolve_encoding(encoding: str, rgb: np.ndarray) -> str:
    """The colour encoding a fit's network holds: ``encoding`` ("auto": sRGB unless ``rgb`` holds HDR values)."""
    if encoding == "auto":
        return "linear" if float(np.max(rgb, initial=0.0)) > 1.0 else "srgb"
    return encoding


def _as_sdf_field(sdf_model) -> SdfField:
    """The frozen SDF as an :class:`SdfField`: a field file (an SDF, or a nested sequence's f with its widest
    band δ), a field, a scalar :class:`Siren` or a callable ``points -> (values, gradients)``."""
    if isinstance(sdf_model, (str, Path)):
        return load_sdf_field(sdf_model)
    if isinstance(sdf_model, (SdfField, NestedSequence)):
        return to_sdf_field(sdf_model)
    if isinstance(sdf_model, torch.nn.Module):
        if getattr(sdf_model, "out_dim", 1) != 1 or getattr(sdf_model, "in_dim", 3) != 3:
            raise FitError(f"sdf model: expected a scalar field of 3-D points, got in={sdf_model.in_dim}, "
                           f"out={sdf_model.out_dim}")
        return SdfField.from_model(sdf_model, name="sdf model")
    if callable(sdf_model):
        return SdfField.from_value_and_gradient(sdf_model, name="sdf callable")
    raise FitError(f"sdf model: expected a Siren, a field, a model file path or a callable, got "
                   f"{type(sdf_model).__name__}")


@torch.no_grad()
def _sdf_eval(sdf: SdfField, points: torch.Tensor, chunk: int = 65536) -> tuple[torch.Tensor, torch.Tensor]:
    """(N, 3) points -> ((N,) values, (N, 3) gradients) in the points' dtype and device (a network is
    evaluated in its own dtype and device)."""
    p = next(sdf.model.parameters(), None) if sdf.model is not None else None
    outs_v, outs_g = [], []
    for i in range(0, points.shape[0], chunk):
        x = points[i:i + chunk]
        v, g = sdf.value_and_gradient(x.to(p.device, p.dtype) if p is not None else x)
        outs_v.append(v.reshape(-1).to(points.device, points.dtype))
        outs_g.append(g.reshape(-1, 3).to(points.device, points.dtype))
    if not outs_v:
        return points.new_zeros(0), points.new_zeros(0, 3)
    return torch.cat(outs_v), torch.cat(outs_g)


def _gemm_gradient(model, points, *, differentiable=False):
    from ..nets.gemm import gemm_gradient

    return gemm_gradient(model, points, differentiable=differentiable)


# ----------------------------------------------------------------------------------------------------------
# samples


def texel_face_weights(mesh: Mesh, share: float) -> np.ndarray | None:
    """(F,) probabilities of drawing each face: ``1 − share`` of them by surface area, ``share`` by UV area
    (the texels a face covers in the texture); None for ``share`` 0 or a mesh without UVs or without UV area."""
    if share <= 0 or mesh.uv is None:
        return None
    uv_area = face_uv_areas(mesh.uv)
    area = np.nan_to_num(np.asarray(mesh.face_areas, dtype=np.float64), nan=0.0, posinf=0.0)
    if uv_area.sum() <= 0 or area.sum() <= 0:
        return None
    return (1.0 - share) * area / area.sum() + share * uv_area / uv_area.sum()


def edge_strength(rgb: np.ndarray) -> np.ndarray:
    """(H, W) float32: the largest colour step (any channel, linear RGB) between a texel and its 4-neighbours,
    spread to the texels around it (3×3 maximum), so both sides of a border and the texels a bilinear lookup
    blends across it count."""
    from scipy import ndimage

    img = np.asarray(rgb, dtype=np.float32)[..., :3]
    step = np.zeros(img.shape[:2], dtype=np.float32)
    dy = np.abs(np.diff(img, axis=0)).max(axis=2)
    dx = np.abs(np.diff(img, axis=1)).max(axis=2)
    np.maximum(step[1:], dy, out=step[1:])
    np.maximum(step[:-1], dy, out=step[:-1])
    np.maximum(step[:, 1:], dx, out=step[:, 1:])
    np.maximum(step[:, :-1], dx, out=step[:, :-1])
    return ndimage.maximum_filter(step, size=3, mode="nearest")


#: How far (texels, each way in u and v) an edge sample moves from its texel's centre: anywhere in the texel.
EDGE_JITTER = 0.5

#: Draws of a moved edge sample's place before it keeps its own (a draw can fall off its face).
EDGE_TRIES = 4


def pool_size(config: TextureFitConfig, preset: str | None = None) -> int:
    """The surface samples a fit draws: ``config.pool``, or the samples its steps can read (steps × batch)
    where they are fewer, so a short fit does not pay for a pool it never reads. ``preset``: the preset whose
    step cost the config has (:data:`PRESETS`' key); a time-budgeted fit of it counts the steps its minutes
    make on the reference machine (:data:`~neural_bake.fit.presets.REFERENCE_STEPS`, in proportion)."""
    from .budget import reference_steps

    steps = int(config.steps)
    ref = reference_steps(f"texture:{preset}") if preset is not None else None
    if ref and config.budget == "time" and config.minutes:
        steps = min(steps, math.ceil(ref * float(config.minutes) / float(PRESETS[preset]["minutes"])))
    return max(1, min(int(config.pool), steps * int(config.batch)))


def _jittered(mesh: Mesh, shape: tuple[int, int], bary: np.ndarray, uv: np.ndarray, faces: np.ndarray,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Samples (barycentrics ``bary`` (n, 3) on ``faces``, texture coordinates ``uv`` (n, 2)) moved to a uniform
    random point within :data:`EDGE_JITTER` texels (in UV) of where they are, on their own face (up to
    :data:`EDGE_TRIES` draws; a sample whose every draw falls off its face keeps its place): fresh places along
    the same edges, not repeats. Returns the new (bary, uv), float64."""
    h, w = shape
    fuv = np.asarray(mesh.uv, dtype=np.float64)  # (F, 3, 2), per face: a draw gathers from these
    o, e1, e2 = fuv[:, 0], fuv[:, 1] - fuv[:, 0], fuv[:, 2] - fuv[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    bary, uv = np.array(bary, dtype=np.float64), np.array(uv, dtype=np.float64)
    todo = np.flatnonzero(np.abs(det[faces]) > 1e-12)  # a face of no UV area has no place to move to
    for _ in range(EDGE_TRIES):
        if todo.size == 0:
            break
        target = uv[todo] + rng.uniform(-EDGE_JITTER, EDGE_JITTER, size=(todo.size, 2)) / np.array([w, h])
        f = faces[todo]
        d = target - o[f]
        b1 = (d[:, 0] * e2[f, 1] - d[:, 1] * e2[f, 0]) / det[f]
        b2 = (e1[f, 0] * d[:, 1] - e1[f, 1] * d[:, 0]) / det[f]
        b0 = 1.0 - b1 - b2
        ok = (b0 >= 0) & (b1 >= 0) & (b2 >= 0)
        at = todo[ok]
        bary[at] = np.stack([b0[ok], b1[ok], b2[ok]], axis=1)
        uv[at] = target[ok]
        todo = todo[~ok]
    return bary, uv


def _edge_samples(mesh: Mesh, rgb: np.ndarray, n: int, rng: np.random.Generator) -> tuple:
    """``n`` surface samples (points, normals, uv, faces) at the texture's edges: texels drawn with probability
    proportional to :func:`edge_strength` among those a face covers (:func:`~neural_bake.mesh.texels.
    texel_centres`; a multinomial draw, so the samples come grouped by texel), each sample at a uniform random
    place in its texel on that face (:func:`_jittered`); texels drawn uniformly where the texture has no edge."""
    with warnings.catch_warnings():  # UVs outside [0, 1]: the bake says so where it matters
        warnings.simplefilter("ignore", NeuralBakeWarning)
        face, rows, cols, bary = texel_centres(mesh, rgb.shape[:2])
    if len(face) == 0:  # no texel centre on a face (UVs of no area): anywhere on the surface
        from .sampling import sample_surface

        s = sample_surface(mesh, n, seed=int(rng.integers(1 << 31)), colors=False)
        return np.asarray(s.points), np.asarray(s.normals), np.asarray(s.uv, dtype=np.float64), np.asarray(s.face_index)
    strength = edge_strength(rgb)[rows, cols].astype(np.float64)
    total = strength.sum()
    p = strength / total if total > 0 and np.isfinite(total) else np.full(len(face), 1.0 / len(face))
    pick = np.repeat(np.arange(len(face)), rng.multinomial(n, p))
    face, bary = face[pick], np.asarray(bary, dtype=np.float64)[pick]
    bary, uv = _jittered(mesh, rgb.shape[:2], bary, interpolate_corners(mesh.uv, face, bary), face, rng)
    points = interpolate_corners(np.asarray(mesh.vertices)[mesh.faces], face, bary)
    return points, np.asarray(mesh.face_normals)[face], uv, face


def texture_targets(mesh: Mesh, n: int, *, seed: int = 0, texture: np.ndarray | None = None,
                    texel_share: float = 0.0, edge_share: float = 0.0) -> dict:
    """Surface samples of ``mesh`` with their texture colours: uniform by area, or with ``texel_share`` of
    them by UV area (:func:`texel_face_weights`: as densely as the texture's texels lie; 1: texel-uniform),
    and ``edge_share`` of them placed along the texture's edges (:attr:`TextureFitConfig.edge_share`;
    anywhere where the texture has no edge).

    Returns float32 numpy arrays, unit frame: ``points`` (n, 3), ``normals`` (n, 3) unit outward mesh
    normals, ``uv`` (n, 2), ``colors`` (n, 3) linear RGB (bilinear lookup, ``mesh.uv_policy`` for UVs outside
    [0, 1], alpha ignored), ``face_index`` (n,) int64.
    """
    rgb = _texture_rgb(mesh, texture)
    from .sampling import sample_surface

    n_edge = int(round(int(n) * float(edge_share)))
    s = sample_surface(mesh, int(n) - n_edge, seed=seed, face_weights=texel_face_weights(mesh, texel_share),
                       colors=False)  # looked up below, in the texture given
    parts = [(np.asarray(s.points), np.asarray(s.normals), np.asarray(s.uv, dtype=np.float64),
              np.asarray(s.face_index))]
    if n_edge > 0:
        parts.append(_edge_samples(mesh, rgb, n_edge, np.random.default_rng(seed + 1)))
    points, normals, uvs, faces = (np.concatenate(a) for a in zip(*parts))
    colors = sample_texture(rgb, uvs, mesh.uv_policy).astype(np.float32)
    return {
        "points": points.astype(np.float32),
        "normals": normals.astype(np.float32),
        "uv": uvs.astype(np.float32),
        "colors": colors,
        "face_index": faces.astype(np.int64),
    }


def _band_pool(points, normals, sdf: SdfField, delta: float, n_uniform: int, gen: torch.Generator):
    """Band points (surface ± U[−δ, δ]·normal, and uniform points with |f| ≤ δ) with their unit ∇f."""
    t = (torch.rand(points.shape[0], 1, generator=gen, dtype=points.dtype) * 2 - 1) * delta
    offset = points + t * normals
    uni = torch.rand(n_uniform, 3, generator=gen, dtype=points.dtype) * 2 - 1
    fu, _ = _sdf_eval(sdf, uni)
    uni = uni[fu.abs() <= delta]
    _, g_off = _sdf_eval(sdf, offset)
    n_off, v_off = unit_normals(g_off)
    if uni.shape[0]:
        _, g_uni = _sdf_eval(sdf, uni)
        n_uni, v_uni = unit_normals(g_uni)
    else:
        n_uni, v_uni = uni.new_zeros(0, 3), torch.zeros(0, dtype=torch.bool)
    return offset[v_off], n_off[v_off], uni[v_uni], n_uni[v_uni]


# ----------------------------------------------------------------------------------------------------------
# loss


def band_orthogonality(model: Siren | GridNet, points: torch.Tensor, normals: torch.Tensor,
                       *, differentiable: bool = True, method: str = "jacobian") -> torch.Tensor:
    """Per-point Σ_c ⟨∇g_c(p), n(p)⟩² of the colour net ``model`` (out_dim 3) at ``points``.

    - ``points``: (N, 3) unit frame; ``normals``: (N, 3) the unit ∇f there (zero rows count as 0).
    - A :class:`Siren`: ``method="jacobian"``: ∇g is the GEMM Jacobian (N, 3, 3) (out, in) of
      :func:`gemm_gradient`, then contracted with n. ``"directional"``: the same numbers as one forward-mode
      tangent stream along n (``t_0 = n``, ``t_i = cos A_i ⊙ (W_i t_{i-1})``, ``J n = W_out t_D``): one GEMM
      stream instead of three.
    - A :class:`~neural_bake.nets.grid.GridNet`: ``"jacobian"``: ∇g by autograd (one reverse pass per output,
      the graph kept for the double backward when ``differentiable``); ``"directional"``: the same numbers from
      :meth:`~neural_bake.nets.grid.GridNet.directional` (closed form, one ordinary backward).
    - ``differentiable=True`` keeps the graph to the weights.

    Returns (N,) in the points' dtype.
    """
    if isinstance(model, GridNet):
        d = _grid_normal_derivative(model, points, normals, differentiable=differentiable, method=method)
        return (d * d).sum(dim=1)
    if method == "jacobian":
        _, jac = _gemm_gradient(model, points, differentiable=differentiable)
        d = torch.einsum("noi,ni->no", jac.reshape(points.shape[0], -1, 3), normals)
    elif method == "directional":
        with torch.set_grad_enabled(differentiable and torch.is_grad_enabled()):
            layers = [(w.to(points.dtype), b.to(points.dtype)) for w, b in model.affine_layers()]
            if not differentiable:
                layers = [(w.detach(), b.detach()) for w, b in layers]
            h, t = points, normals
            for w, b in layers[:-1]:
                h, c = sin_cos(torch.addmm(b, h, w.t()))
                t = c * (t @ w.t())
            d = t @ layers[-1][0].t()
    else:
        raise FitError(f"orth_method: must be 'jacobian' or 'directional', got {method!r}")
    return (d * d).sum(dim=1)


def _grid_normal_derivative(model: GridNet, points: torch.Tensor, normals: torch.Tensor, *, differentiable: bool,
                            method: str) -> torch.Tensor:
    """J_g(p) n (N, out_dim) of a grid network, by autograd ("jacobian") or in closed form ("directional"); a
    network with normal inputs reads ``normals`` as the surface's (its derivative is the point's alone)."""
    sided = model.normal_inputs
    with torch.set_grad_enabled(differentiable and torch.is_grad_enabled() or method == "jacobian"):
        if method == "directional":
            d = model.directional(torch.cat([points, normals], dim=1) if sided else points, normals)[1]
        elif method == "jacobian":
            x = points.detach().requires_grad_(True)
            out = model(torch.cat([x, normals], dim=1) if sided else x)
            create = differentiable and torch.is_grad_enabled()
            rows = [torch.autograd.grad(out[:, c].sum(), x, create_graph=create, retain_graph=True)[0]
                    for c in range(out.shape[1])]
            d = torch.stack([(r * normals).sum(dim=1) for r in rows], dim=1)
        else:
            raise FitError(f"orth_method: must be 'jacobian' or 'directional', got {method!r}")
    return d if differentiable else d.detach()


def tilt_normals(normals: torch.Tensor, max_angle: float, generator: torch.Generator | None = None) -> torch.Tensor:
    """Unit ``normals`` (N, 3) each turned by an angle drawn uniformly in [0, ``max_angle``] (radians) towards a
    uniformly random perpendicular direction; ``max_angle`` 0 returns them as they are. Zero rows stay zero."""
    if max_angle <= 0:
        return normals
    r = torch.randn(normals.shape, generator=generator, dtype=normals.dtype, device=normals.device)
    r = r - (r * normals).sum(dim=1, keepdim=True) * normals
    r = r / r.norm(dim=1, keepdim=True).clamp_min(1e-12)
    a = torch.rand((normals.shape[0], 1), generator=generator, dtype=normals.dtype, device=normals.device) * max_angle
    has = (normals.abs().sum(dim=1, keepdim=True) > 0).to(normals.dtype)
    return normals * torch.cos(a) + has * r * torch.sin(a)


#: The values of :attr:`TextureFitConfig.normal_inputs`.
NORMAL_INPUTS = ("off", "on", "auto")


def reads_normals(config: TextureFitConfig, open_mesh: bool) -> bool:
    """Whether ``config``'s colour network reads surface normals, for a mesh that is open (``open_mesh``) or
    closed: ``normal_inputs`` "on", or "auto" for a grid network on an open mesh."""
    return config.normal_inputs == "on" or (config.normal_inputs == "auto" and bool(open_mesh)
                                            and config.network == "grid")


def make_texture_network(config: TextureFitConfig, generator: torch.Generator | None = None, *,
                         open_mesh: bool = False) -> Siren | GridNet:
    """The untrained colour network of ``config`` (3 outputs): a :class:`Siren` (3 inputs; width, depth, ω0,
    hidden ω) or, with ``network="grid"``, a :class:`~neural_bake.nets.grid.GridNet` (the grid settings, its MLP
    of width and depth; 6 inputs where it reads normals: :func:`reads_normals`)."""
    sided = reads_normals(config, open_mesh)
    if config.network == "grid":
        return GridNet(config.grid_levels, config.grid_features, config.grid_log2_table,
                       config.grid_base_resolution, config.grid_max_resolution, config.width, config.depth, 3,
                       config.grid_activation, config.hidden_omega, 6 if sided else 3, generator=generator)
    if sided:
        raise FitError('normal_inputs: needs network "grid" (a SIREN colour network reads points only)',
                       parameter="normal_inputs")
    return Siren(config.width, config.depth, 3, 3, config.omega_0, config.hidden_omega, generator=generator)


# ----------------------------------------------------------------------------------------------------------
# fitting


def _resolve_config(config: TextureFitConfig | None, overrides: dict) -> TextureFitConfig:
    config = config or TextureFitConfig()
    preset = overrides.pop("preset", None)
    if preset is not None:
        from .presets import TEXTURE_ALIASES, resolve_preset

        key = resolve_preset(preset, TEXTURE_ALIASES, PRESETS)
        if key is None:
            raise FitError(f"preset: unknown preset {preset!r} (choose from {', '.join(PRESETS)}; "
                           f"{', '.join(TEXTURE_ALIASES)} are aliases)")
        config = replace(config, **PRESETS[key])
        if overrides.get("network") == "siren" and key in PRESET_SIRENS:
            config = replace(config, **PRESET_SIRENS[key])
    names = {f.name for f in fields(TextureFitConfig)}
    bad = sorted(set(overrides) - names)
    if bad:
        raise FitError(f"fit_texture: unknown option {bad[0]!r}")
    config = replace(config, **overrides)
    _validate(config)
    return config


def _validate(c: TextureFitConfig) -> None:
    def positive_int(name):
        v = getattr(c, name)
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise FitError(f"{name}: must be a positive integer, got {v!r}")

    for name in ("width", "steps", "batch", "pool", "checkpoint_every", "log_every"):
        positive_int(name)
    if c.band_batch is not None:
        positive_int("band_batch")
    if isinstance(c.depth, bool) or int(c.depth) != c.depth or c.depth < 0:
        raise FitError(f"depth: must be a non-negative integer, got {c.depth!r}")
    for name in ("omega_0", "hidden_omega", "lr"):
        v = getattr(c, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise FitError(f"{name}: must be a positive number, got {v!r}")
    if not (isinstance(c.lam, (int, float)) and math.isfinite(c.lam) and c.lam >= 0):
        raise FitError(f"lam: must be a finite number >= 0, got {c.lam!r}")
    if c.delta is not None and not (math.isfinite(c.delta) and 0 < c.delta <= 1):
        raise FitError(f"delta: must be in (0, 1] (unit frame), got {c.delta!r}")
    if c.minutes is not None and not (math.isfinite(c.minutes) and c.minutes > 0):
        raise FitError(f"minutes: must be a positive number, got {c.minutes!r}")
    for name in ("texel_share", "edge_share"):
        v = getattr(c, name)
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and 0 <= v <= 1):
            raise FitError(f"{name}: must be in [0, 1], got {v!r}")
    if not 0 <= c.band_uniform_fraction <= 1:
        raise FitError(f"band_uniform_fraction: must be in [0, 1], got {c.band_uniform_fraction!r}")
    if c.dtype not in ("float32", "float64"):
        raise FitError(f"dtype: must be 'float32' or 'float64', got {c.dtype!r}")
    if isinstance(c.max_restarts, bool) or int(c.max_restarts) != c.max_restarts or c.max_restarts < 0:
        raise FitError(f"max_restarts: must be a non-negative integer, got {c.max_restarts!r}")
    if c.orth_method not in ("jacobian", "directional"):
        raise FitError(f"orth_method: must be 'jacobian' or 'directional', got {c.orth_method!r}")
    j = c.normal_jitter_deg
    if isinstance(j, bool) or not isinstance(j, (int, float)) or not 0 <= j <= 90:
        raise FitError(f"normal_jitter_deg: must be a number of degrees in [0, 90], got {j!r}",
                       parameter="normal_jitter_deg")
    if c.normal_inputs not in NORMAL_INPUTS:
        raise FitError(f"normal_inputs: must be one of {', '.join(NORMAL_INPUTS)}, got {c.normal_inputs!r}",
                       parameter="normal_inputs")
    if c.normal_inputs == "on" and c.network != "grid":
        raise FitError(f'normal_inputs: needs network "grid" (a SIREN colour network reads points only), got '
                       f'network {c.network!r}', parameter="normal_inputs")
    if c.lr_schedule not in ("constant", "cosine"):
        raise FitError(f"lr_schedule: must be 'constant' or 'cosine', got {c.lr_schedule!r}")
    if c.budget not in ("time", "steps"):
        raise FitError(f"budget: must be 'time' or 'steps', got {c.budget!r}")
    if c.encoding not in ("auto", *ENCODINGS):
        raise FitError(f"encoding: must be 'auto', 'srgb' or 'linear', got {c.encoding!r}")
    if c.network not in NETWORKS:
        raise FitError(f"network: must be one of {', '.join(NETWORKS)}, got {c.network!r}", parameter="network")
    check_grid_settings(levels=c.grid_levels, features=c.grid_features, log2_table=c.grid_log2_table,
                        base_resolution=c.grid_base_resolution, max_resolution=c.grid_max_resolution,
                        activation=c.grid_activation, error=FitError, prefix="grid_")


def _resolve_delta(config: TextureFitConfig, sdf: SdfField) -> float:
    """The config's δ, else the SDF's (a nested sequence's widest band, a fitted SDF's sampled distance
    error), else DEFAULT_DELTA."""
    if config.delta is not None:
        return float(config.delta)
    d = sdf.delta
    if d is not None and math.isfinite(d) and d > 0:
        return float(d)
    return DEFAULT_DELTA


def _check_frames(mesh: Mesh, sdf: SdfField) -> None:
    if sdf.frame is None:
        return
    f = sdf.frame
    if frame_mismatch(f, mesh.frame) > FRAME_MISMATCH_TOL:
        raise FitError(f"{sdf.name}: the SDF was fitted in another frame than {mesh.name} "
                       f"(scale {f.scale:g} vs {mesh.frame.scale:g}, centre {list(f.center)} vs "
                       f"{list(mesh.frame.center)}); fit the SDF on this mesh")


def _fitted_against(sdf: SdfField, delta: float, mesh: Mesh) -> dict:
    """What a texture fit records about its SDF (stored with the texture file): its name, kind and δ, and
    TEXTURE_SURFACE_SAMPLES seeded surface points of ``mesh`` (unit frame), where a later SDF is checked to
    describe the same surface (:func:`~neural_bake.fields.texture.check_texture_matches_sdf`)."""
    from ..constants import TEXTURE_SURFACE_SAMPLES
    from .sampling import sample_surface

    surface = np.round(np.asarray(sample_surface(mesh, TEXTURE_SURFACE_SAMPLES, seed=0).points, np.float64), 6)
    return {"name": sdf.name, "kind": sdf.metadata.get("kind", "analytic" if sdf.model is None else "sdf"),
            "delta": float(delta), "surface": surface.tolist()}


def fit_texture(mesh: Mesh, sdf_model, config: TextureFitConfig | None = None, *,
                texture: np.ndarray | None = None, callback: Callable[[dict], None] | None = None,
                clock: Callable[[], float] | None = None, **overrides) -> TextureFit:
    """Fit a colour SIREN to ``mesh``'s texture (with λ > 0, gradient-orthogonal in the δ-band of ``sdf_model``).

    - ``mesh``: a :class:`Mesh` (unit frame) with ``uv`` and ``texture`` (else :class:`MeshError`).
    - ``sdf_model``: the frozen fine SDF f, unit frame: a field file path (``fit sdf``'s: its δ, the sampled
      distance error, is the default band; ``fit nested``'s: normals from its fine level, the default band
      is its coarsest level's δ; the file's frame must be the mesh's), an :class:`SdfField` or
      :class:`NestedSequence`, a scalar :class:`Siren`, or a callable
      ``points (N, 3) -> (values (N,), grads (N, 3))`` (analytic SDFs, tests).
    - ``config`` / ``**overrides``: a :class:`TextureFitConfig`, fields overridden by keyword;
      ``preset="quick" | "default" | "high"`` (or the aliases fast, medium, fine) applies :data:`PRESETS`
      first (then the other overrides).
    - ``texture``: an (H, W, C) image used instead of ``mesh.texture`` (integer arrays are sRGB, float linear).
    - ``callback``: called with each logged history row (progress reporting).
    - ``clock``: the seconds the time budget measures (default ``time.perf_counter``; tests simulate a slow
      machine with their own).

    The loop is :func:`neural_bake.fit.training.train` (time budget, per-step seeds, checkpoints and
    resume, divergence recovery with learning-rate halving). Returns a :class:`TextureFit`; raises
    :class:`FitError` when training diverges for good or there are no band samples.
    """
    from .training import train

    from .budget import fit_budget, reference_steps, steps_budget
    from .presets import TEXTURE_ALIASES, resolve_preset

    overrides = dict(overrides)
    preset = overrides.get("preset")
    config = _resolve_config(config, overrides)
    key = None if preset is None else resolve_preset(preset, TEXTURE_ALIASES, PRESETS)
    grid = GRID_FIELDS if config.network == "grid" else ()
    arch = {k: getattr(config, k) for k in ("network", "width", "depth", "batch", *grid)}
    default = TextureFitConfig()
    same = key is not None and all(PRESETS[key].get(k, getattr(default, k)) == v
                                   for k, v in arch.items())  # the preset's step cost
    cost_key = f"texture:{key}" if same else None
    if config.budget == "steps":  # the preset's steps on the quiet reference machine, no time stop
        n_steps = reference_steps(cost_key)
        if n_steps is None:
            raise FitError(f"budget: 'steps' needs preset (one of {', '.join(PRESETS)}) with the preset's width, "
                           f"depth and batch, got preset {preset!r}")
        config = replace(config, steps=n_steps, minutes=None)
    rgb = _texture_rgb(mesh, texture)
    sdf = _as_sdf_field(sdf_model)
    _check_frames(mesh, sdf)
    delta = _resolve_delta(config, sdf)
    device, dtype = torch.device(config.device), getattr(torch, config.dtype)

    init_gen = torch.Generator().manual_seed(int(config.seed))
    model = make_texture_network(config, init_gen, open_mesh=not mesh.watertight).to(device, dtype)

    n_pool = pool_size(config, key if cost_key is not None else None)
    samples = texture_targets(mesh, n_pool, seed=int(config.seed), texture=rgb, texel_share=config.texel_share,
                              edge_share=config.edge_share)
    pts = torch.as_tensor(samples["points"])
    nrm = torch.as_tensor(samples["normals"])
    encoding = _resolve_encoding(config.encoding, rgb)
    colors = samples["colors"] if encoding == "linear" else linear_to_srgb(samples["colors"])
    col = torch.as_tensor(colors).to(device, dtype)
    pool_gen = torch.Generator().manual_seed(int(config.seed) + 1)
    if config.lam > 0:
        band: slice | torch.Tensor = slice(None)
        if pts.shape[0] > BAND_POOL:  # a seeded subset of a large pool: each band point costs f and ∇f
            band = torch.randperm(pts.shape[0], generator=pool_gen)[:BAND_POOL]
        band_off, band_off_n, band_uni, band_uni_n = _band_pool(pts[band].double(), nrm[band].double(), sdf, delta,
                                                                min(n_pool, BAND_POOL), pool_gen)
    else:  # no orthogonality term: no band samples to draw
        band_off = band_off_n = band_uni = band_uni_n = pts.new_zeros(0, 3)
    if config.lam > 0 and band_off.shape[0] == 0:
        raise FitError(f"{mesh.name}: no band samples with a valid SDF gradient (is the SDF fitted to this mesh?)")
    pts = pts.to(device, dtype)
    band_off, band_off_n = band_off.to(device, dtype), band_off_n.to(device, dtype)
    band_uni, band_uni_n = band_uni.to(device, dtype), band_uni_n.to(device, dtype)

    bb = config.band_batch or max(1, config.batch // 4)
    n_uni = int(round(bb * config.band_uniform_fraction)) if band_uni.shape[0] else 0
    n_off = bb - n_uni
    lam = float(config.lam)

    # a network with normal inputs reads each sample's face normal (tilted at random) beside its point
    sided = bool(getattr(model, "normal_inputs", False))
    face_normals = nrm.to(device, dtype) if sided else None
    jitter = math.radians(float(config.normal_jitter_deg))

    def step_fn(step: int, gen: torch.Generator) -> dict:
        i = torch.randint(0, pts.shape[0], (config.batch,), generator=gen, device=device)
        x = pts[i] if face_normals is None else torch.cat([pts[i], tilt_normals(face_normals[i], jitter, gen)], dim=1)
        colour = ((model(x) - col[i]) ** 2).mean()
        if lam == 0:
            return {"loss": colour, "colour": colour}
        j = torch.randint(0, band_off.shape[0], (n_off,), generator=gen, device=device)
        bp, bn = band_off[j], band_off_n[j]
        if n_uni:
            k = torch.randint(0, band_uni.shape[0], (n_uni,), generator=gen, device=device)
            bp, bn = torch.cat([bp, band_uni[k]]), torch.cat([bn, band_uni_n[k]])
        orth = band_orthogonality(model, bp, bn, method=config.orth_method).mean()
        return {"loss": colour + lam * orth, "colour": colour, "orth": orth}

    loop = config.loop_config(f"fit texture {mesh.name}", max_restarts=int(config.max_restarts))
    fingerprint = json.dumps({"kind": "texture", "mesh": mesh.name, "faces": mesh.n_faces,
                              "arch": model.architecture, "delta": delta, "lam": lam, "batch": config.batch,
                              "pool": n_pool, "seed": config.seed, "encoding": encoding,
                              "texel_share": config.texel_share}, sort_keys=True)
    result = train(model, step_fn, loop, fingerprint=fingerprint,
                   metadata=_metadata(mesh.frame, delta, lam, config, 0, encoding=encoding), on_log=callback,
                   **({} if clock is None else {"clock": clock}))
    model.eval()
    # every sample is drawn before the loop: a step's work does not grow with the mesh
    if config.budget == "steps" and cost_key is not None:
        budget = steps_budget(cost_key, steps=result.steps, seconds=result.seconds)
    else:
        budget = fit_budget(cost_key, steps=result.steps, seconds=result.seconds, minutes=config.minutes,
                            step_cap=int(config.steps), stopped_reason=result.stopped_reason)
    return TextureFit(model=model, frame=mesh.frame, delta=delta, lam=lam, config=config,
                      history=result.history, steps=result.steps, seconds=result.seconds,
                      stopped_reason=result.stopped_reason, restarts=result.restarts, budget=budget,
                      fitted_against=_fitted_against(sdf, delta, mesh), encoding=encoding, threads=result.threads)


# ----------------------------------------------------------------------------------------------------------
# metrics


@torch.no_grad()
def _eval(model, points: np.ndarray, normals: np.ndarray | None = None, chunk: int = 65536) -> np.ndarray:
    """(N, 3) float64 linear colours of a Siren or GridNet (its dtype and device), a :class:`TextureField` (sRGB
    outputs decoded) or a callable (float64 CPU tensors); a network with normal inputs reads ``normals`` (N, 3),
    the surface's unit normals at the points."""
    if isinstance(model, TextureField):
        net, fn = model.model, model.color
    else:
        net, fn = model, model
    p = next(net.parameters()) if isinstance(net, torch.nn.Module) else None
    dtype, device = (p.dtype, p.device) if p is not None else (torch.float64, torch.device("cpu"))
    sided = bool(getattr(net, "normal_inputs", False))
    if sided and normals is None:
        raise FitError("this colour network reads surface normals beside the points; none were given")
    out = []
    for i in range(0, len(points), chunk):
        x = torch.as_tensor(np.asarray(points[i:i + chunk]), dtype=dtype, device=device)
        if sided:
            n = torch.as_tensor(np.asarray(normals[i:i + chunk]), dtype=dtype, device=device)
            y = fn(x, n) if isinstance(model, TextureField) else fn(torch.cat([x, n], dim=1))
        else:
            y = fn(x)
        out.append(torch.as_tensor(y)[:, :3].reshape(-1, 3).to(torch.float64).cpu().numpy())
    return np.concatenate(out) if out else np.zeros((0, 3))


def _psnr(mse: float) -> float:
    return float("inf") if mse <= 0 else float(10.0 * math.log10(1.0 / mse))


def texture_metrics(texture_model, mesh: Mesh, sdf_model, *, delta: float | None = None,
                    n: int = 20000, seed: int = 0, n_views: int = 6, resolution: int = 128,
                    texture: np.ndarray | None = None) -> dict:
    """Quality of a colour net ``texture_model`` (unit frame -> linear RGB) against ``mesh``'s texture.

    - ``texture_model``: a :class:`TextureField` (:meth:`TextureFit.field`: its encoding is decoded), a colour
      :class:`Siren` (in 3, out 3) holding linear RGB, or a callable (N, 3) float64 tensor -> (N, 3).
    - ``sdf_model``: the SDF whose unit ∇f gives the normal lines (Siren, model path or callable, as in
      :func:`fit_texture`); ``delta``: band half-width (default: the SDF file's, else DEFAULT_DELTA).

    Returns floats:
    - ``surface_mse``, ``surface_psnr``: against the texture at ``n`` surface samples (linear RGB, peak 1).
    - ``texel_mse``, ``texel_psnr``: the same at ``n`` samples drawn by UV area (each texel of the texture
      counts once, as in a bake onto the mesh's own UVs); ``texel_psnr_srgb``: that PSNR with both sides
      sRGB-encoded, what an 8-bit colour map shows.
    - ``band_change``: mean |g(p ± t·n) − g(p)| (mean over channels) for t in {δ/4, δ/2, 3δ/4, δ}, both
      signs, n = ∇f/|∇f| at p; ``band_change_at_delta``: the same for t = δ only; ``band_change_read``: the
      same with g read where a bake reads it (``texture_at="surface"``), at the closest point of f = 0 of each
      p ± t·n (|f| clamped to δ): what a coarse surface in the band shows.
    - ``render_mse``: mean over ``n_views`` ray-cast views of the ground-truth mesh of the per-view MSE
      between the texture colour at the hit points (hit triangle + barycentrics -> UV -> bilinear lookup)
      and g there, over hit pixels; ``render_mse_views``: the per-view list; ``render_mse_band``: the same
      with g read at the hit points pushed ±δ along n (what a coarse surface in the band shows).
    - ``delta``, ``n``: what was used.
    Entries that cannot be computed (no valid ∇f, no view hitting the mesh) are None, never NaN.
    """
    rgb = _texture_rgb(mesh, texture)
    sdf = _as_sdf_field(sdf_model)
    if delta is None:
        delta = _resolve_delta(TextureFitConfig(), sdf)
    s = texture_targets(mesh, n, seed=seed, texture=rgb)
    g0 = _eval(texture_model, s["points"], s["normals"])
    mse = float(np.mean((g0 - s["colors"]) ** 2))
    st = texture_targets(mesh, n, seed=seed + 1, texture=rgb, texel_share=1.0)
    gt_texel = _eval(texture_model, st["points"], st["normals"])
    texel_mse = float(np.mean((gt_texel - st["colors"]) ** 2))
    texel_mse_srgb = float(np.mean((linear_to_srgb(gt_texel) - linear_to_srgb(st["colors"])) ** 2))

    p = s["points"].astype(np.float64)
    _, grads = _sdf_eval(sdf, torch.as_tensor(p))
    normals, valid = unit_normals(grads)
    normals, valid = normals.numpy(), valid.numpy()
    changes, projected, at_delta = [], [], None
    for t in (0.25 * delta, 0.5 * delta, 0.75 * delta, delta):
        for sign in (1.0, -1.0):
            q = p + sign * t * normals
            gt = _eval(texture_model, q, s["normals"])
            changes.append(np.abs(gt - g0).mean(axis=1)[valid])
            # what a bake reads there: g at the closest point of f = 0, q − f(q)·∇f(q)/|∇f(q)|, |f| ≤ δ
            qt = torch.as_tensor(q)
            fq, gq = _sdf_eval(sdf, qt)
            nq, okq = unit_normals(gq)
            back = _eval(texture_model, closest_surface_points(qt, fq, nq, okq, delta).numpy(),
                         np.where(okq.numpy()[:, None], nq.numpy(), s["normals"]))
            projected.append(np.abs(back - g0).mean(axis=1)[valid])
        if t == delta:
            at_delta = float(np.mean(np.concatenate(changes[-2:]))) if valid.any() else None
    band_change = float(np.mean(np.concatenate(changes))) if valid.any() else None
    band_change_read = float(np.mean(np.concatenate(projected))) if valid.any() else None

    views = render_views(mesh, n_views, resolution)
    per_view, per_view_band = [], []
    for v in views:
        if len(v["points"]) == 0:
            continue
        uv = np.einsum("mk,mkj->mj", v["bary"], mesh.uv[v["face_index"]])
        truth = sample_texture(rgb, uv, mesh.uv_policy).astype(np.float64)
        face_n = mesh.face_normals[v["face_index"]]
        per_view.append(float(np.mean((_eval(texture_model, v["points"], face_n) - truth) ** 2)))
        _, gv = _sdf_eval(sdf, torch.as_tensor(v["points"]))
        nv, _ = unit_normals(gv)
        nv = nv.numpy()
        band = [np.mean((_eval(texture_model, v["points"] + sg * delta * nv, face_n) - truth) ** 2)
                for sg in (1.0, -1.0)]
        per_view_band.append(float(np.mean(band)))
    return {
        "surface_mse": mse,
        "surface_psnr": _psnr(mse),
        "texel_mse": texel_mse,
        "texel_psnr": _psnr(texel_mse),
        "texel_psnr_srgb": _psnr(texel_mse_srgb),
        "band_change": band_change,
        "band_change_at_delta": at_delta,
        "band_change_read": band_change_read,
        "render_mse": float(np.mean(per_view)) if per_view else None,
        "render_mse_views": per_view,
        "render_mse_band": float(np.mean(per_view_band)) if per_view_band else None,
        "delta": float(delta),
        "n": int(n),
    }
