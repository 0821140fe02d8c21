"""A texture field g: unit-frame points (N, 3) -> linear RGB (N, 3) or RGBA (N, 4).

A field with normal inputs (a grid network with ``in_dim`` 6) also reads the unit surface normal at each point:
the two sides of a thin board, or the two faces at its edge, keep their own colours. Its readers pass the normal
they have: a bake onto the source itself the mesh's face normal (what the field was fitted with), a bake onto
another mesh the SDF's ∇f (the coarse face's normal where ∇f faces the other way), the renderer ∇f.

A fitted network may hold its colours sRGB-encoded (``encoding="srgb"``, what an 8-bit colour map stores);
:meth:`TextureField.color` decodes them, so every reader sees linear RGB.
"""

from __future__ import annotations

from typing import Callable

import torch

from ..errors import ModelFileError
from ..io.colour import srgb_to_linear
from ..types import Frame

__all__ = ["TextureField", "ColorField", "ENCODINGS", "decode_colors", "texture_agreement",
           "check_texture_matches_sdf"]

#: What a colour network's outputs hold: linear RGB, or sRGB-encoded values (IEC 61966-2-1).
ENCODINGS = ("linear", "srgb")


def decode_colors(out: torch.Tensor, encoding: str) -> torch.Tensor:
    """Linear RGB(A) from a colour network's outputs: sRGB-encoded colour channels (the first three) are
    clipped to [0, 1] and decoded; alpha and linear outputs are returned as they are."""
    if encoding == "linear":
        return out
    if encoding != "srgb":
        raise ValueError(f"colour encoding must be one of {', '.join(ENCODINGS)}, got {encoding!r}")
    return torch.cat([srgb_to_linear(out[..., :3]), out[..., 3:]], dim=-1)


class TextureField:
    """A colour field g, fitted on the surface of an SDF's mesh and read at the closest points of f = 0.

    - ``fn``: callable on (N, 3) tensors (a Siren or a :class:`~neural_bake.nets.grid.GridNet` with 3 or 4
      outputs, or analytic).
    - ``frame``: the unit frame the field lives in (None = the mesh's).
    - ``name``: what messages and reports call it.
    - ``delta``: half-width of the band |f| ≤ δ the field was fitted for (or None): a bake moves a read at most δ
      onto f = 0, and a field fitted with λ > 0 is constant across the band.
    - ``fitted_against``: what SDF it was fitted against: ``{"name", "kind" ("sdf" or "nested"),
      "delta", "surface"}`` (None when unknown); ``surface``, when recorded, is a list of
      :data:`~neural_bake.constants.TEXTURE_SURFACE_SAMPLES` points [x, y, z] of the fitted mesh's surface
      (unit frame), where :func:`check_texture_matches_sdf` reads another SDF.
    - ``metadata``: provenance, the file's JSON metadata (λ, training config…).
    - ``model``: the network of a fitted field (a Siren or a GridNet), None for an analytic one.
    - ``gemm_dtype``: None, or the reduced precision of the network's hidden GEMMs (:meth:`with_precision`).
    - ``encoding``: what ``fn`` outputs, "linear" or "srgb" (:data:`ENCODINGS`); :meth:`color` gives linear RGB.
    - ``normal_inputs``: whether ``fn`` also reads unit surface normals (:attr:`normal_inputs`; None: the
      network says).
    """

    def __init__(self, fn: Callable[[torch.Tensor], torch.Tensor], *, frame: Frame | None = None,
                 name: str = "analytic", delta: float | None = None, fitted_against: dict | None = None,
                 metadata: dict | None = None, encoding: str = "linear", normal_inputs: bool | None = None):
        if encoding not in ENCODINGS:
            raise ModelFileError(f"{name}: colour encoding must be one of {', '.join(ENCODINGS)}, got {encoding!r}")
        self.fn, self.frame, self.name, self.delta, self.encoding = fn, frame, name, delta, encoding
        self.fitted_against = fitted_against
        self.metadata = dict(metadata or {})
        self.model = fn if isinstance(fn, torch.nn.Module) else None
        self.gemm_dtype: torch.dtype | None = None
        self._normal_inputs = normal_inputs

    @classmethod
    def from_model(cls, model, *, frame: Frame | None = None, name: str = "siren", delta: float | None = None,
                   fitted_against: dict | None = None, metadata: dict | None = None,
                   encoding: str = "linear") -> "TextureField":
        """A network (Siren or GridNet) with 3 (RGB) or 4 (RGBA) outputs, holding ``encoding`` colours."""
        if getattr(model, "out_dim", 3) not in (3, 4):
            raise ModelFileError(f"{name}: a texture model must have 3 or 4 outputs, this one has {model.out_dim}")
        return cls(model, frame=frame, name=name, delta=delta, fitted_against=fitted_against, metadata=metadata,
                   encoding=encoding)

    def with_precision(self, precision: str, *, measure=None, probe: torch.Tensor | None = None
                       ) -> tuple["TextureField", str, str]:
        """``(field, resolved, reason)`` as :meth:`neural_bake.fields.sdf.SdfField.with_precision`; with
        ``probe`` points, "auto" keeps float32 when the colours there differ from float32 ones by more than
        :data:`~neural_bake.constants.ADAPTIVE_COLOR_TOL` (median of the largest channel difference). A network
        other than a Siren runs in its own dtype (fp32; "bf16" is refused naming ``precision``)."""
        from ..constants import ADAPTIVE_COLOR_TOL
        from ..errors import NeuralBakeError
        from ..nets.precision import PRECISIONS, reduced_copy
        from ..nets.siren import Siren

        if self.model is not None and not isinstance(self.model, Siren):
            if precision not in PRECISIONS:
                raise NeuralBakeError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}",
                                      parameter="precision")
            why = f"a {type(self.model).__name__} has no reduced-precision path"
            if precision == "bf16":
                raise NeuralBakeError(f"precision bf16: {why}", parameter="precision")
            return self, "fp32", why

        out, resolved, reason = reduced_copy(self, precision, measure=measure)
        if out is self:
            return self, resolved, reason
        if precision == "auto" and probe is not None and len(probe):
            diff = float((self.color(probe) - out.color(probe)).abs().amax(dim=1).median())
            if diff > ADAPTIVE_COLOR_TOL:
                return self, "fp32", (f"{reason}, but its colours measured {diff:.2g} median off float32 at "
                                      f"{len(probe)} points (> {ADAPTIVE_COLOR_TOL:.2g})")
            reason += f"; colours {diff:.2g} median off float32 at {len(probe)} points"
        return out, resolved, reason

    @property
    def normal_inputs(self) -> bool:
        """Whether :meth:`color` needs the surface normals: a network with normal inputs, or an analytic field
        made with ``normal_inputs=True`` (its ``fn`` then reads (N, 6): points, then normals)."""
        if self._normal_inputs is not None:
            return bool(self._normal_inputs)
        return bool(getattr(self.model, "normal_inputs", False))

    def color(self, points: torch.Tensor, normals: torch.Tensor | None = None) -> torch.Tensor:
        """Linear RGB(A) (N, C) at ``points`` (N, 3) (sRGB outputs decoded); non-finite outputs become 0. A
        field with a ``gemm_dtype`` runs its Siren through :func:`~neural_bake.nets.siren.siren_forward_inference`
        with it. ``normals`` (N, 3), unit surface normals at the points, are read by a field with
        :attr:`normal_inputs` (it needs them: :class:`~neural_bake.errors.NeuralBakeError` without) and ignored
        by any other."""
        if self.normal_inputs:
            if normals is None or tuple(normals.shape) != (points.shape[0], 3):
                from ..errors import NeuralBakeError

                got = "none" if normals is None else f"shape {tuple(normals.shape)}"
                raise NeuralBakeError(f"{self.name}: this colour field reads the surface normal at each point; "
                                      f"pass normals of shape ({points.shape[0]}, 3), got {got}")
            points = torch.cat([points, normals.to(points.dtype)], dim=1)
        with torch.no_grad():
            if self.gemm_dtype is not None:
                from ..nets.siren import siren_forward_inference

                layers = self.model.affine_layers(dtype=points.dtype, device=points.device)
                out = siren_forward_inference(layers, points, gemm_dtype=self.gemm_dtype)
            else:
                out = self.fn(points)
        out = torch.nan_to_num(out.reshape(points.shape[0], -1), nan=0.0, posinf=0.0, neginf=0.0)
        return decode_colors(out, self.encoding)

    def __repr__(self) -> str:
        extra = ", normal inputs" if self.normal_inputs else ""
        return f"TextureField({self.name!r}, delta={self.delta}, encoding={self.encoding!r}{extra})"


#: The name of earlier releases.
ColorField = TextureField


def texture_agreement(texture: TextureField, sdf) -> dict:
    """``{"frame_mismatch", "median_abs_f", "samples"}`` of ``texture`` against ``sdf``: how far apart their
    frames are (:func:`~neural_bake.geometry.frame_mismatch`; 0 when either has none) and the median |f| of
    ``sdf`` at the surface points the texture recorded (``fitted_against["surface"]``, moved into the SDF's
    unit frame), None when it recorded none or ``sdf`` is not a static SDF field (a space-time one: frames only).

    ``sdf``: an :class:`~neural_bake.fields.sdf.SdfField`, a nested sequence (its fine f) or any field with a
    ``frame`` (a space-time SDF)."""
    import numpy as np

    from ..geometry import frame_mismatch
    from .sdf import SdfField

    tf, sf = texture.frame, getattr(sdf, "frame", None)
    out: dict = {"frame_mismatch": 0.0 if tf is None or sf is None else frame_mismatch(tf, sf),
                 "median_abs_f": None, "samples": 0}
    if hasattr(sdf, "finest") and getattr(sdf, "in_dim", 3) == 3:
        sdf = sdf.finest
    surface = (texture.fitted_against or {}).get("surface")
    if not isinstance(sdf, SdfField) or sdf.in_dim != 3 or not surface:
        return out
    pts = np.asarray(surface, dtype=np.float64).reshape(-1, 3)
    if tf is not None and sf is not None and tf != sf:
        pts = sf.to_unit(tf.to_source(pts))
    p = next(sdf.model.parameters()) if sdf.model is not None else None
    x = torch.as_tensor(pts, dtype=p.dtype if p is not None else torch.float64,
                        device=p.device if p is not None else "cpu")
    f = sdf.value(x).double().abs().cpu().numpy()
    f = np.where(np.isfinite(f), f, np.inf)
    out.update(median_abs_f=float(np.median(f)), samples=int(len(pts)))
    return out


def check_texture_matches_sdf(texture: TextureField, sdf, *, force: bool = False, option: str = "force=True",
                              sdf_name: str | None = None) -> dict:
    """:func:`texture_agreement`, raising :class:`~neural_bake.errors.NeuralBakeError` (one line naming the
    texture and the mismatch) when the frames differ beyond ``FRAME_MISMATCH_TOL`` or the SDF's median |f| at
    the texture's recorded surface points exceeds ``SDF_MISMATCH_MEDIAN`` (the texture was fitted on another
    surface), unless ``force`` (then a :class:`~neural_bake.errors.NeuralBakeWarning` says it). ``option`` is
    how the messages name the override, ``sdf_name`` the SDF (default its ``name``). Returns the figures with
    ``"passed"``."""
    from ..constants import FRAME_MISMATCH_TOL, SDF_MISMATCH_MEDIAN
    from ..errors import NeuralBakeError
    from ..geometry import mismatch_problem

    a = texture_agreement(texture, sdf)
    name = sdf_name or getattr(sdf, "name", "the SDF")
    tf, sf = texture.frame, sdf.frame
    problem = mismatch_problem(
        a,
        frames=lambda: (f"fitted in another frame than {name}: the frames differ by {a['frame_mismatch']:.3g} "
                        f"(tolerance {FRAME_MISMATCH_TOL:g}): texture centre {[round(c, 6) for c in tf.center]} "
                        f"scale {tf.scale:.6g}, SDF centre {[round(c, 6) for c in sf.center]} scale {sf.scale:.6g}"),
        surface=lambda: (f"fitted on another surface than {name}: median |f| at the texture's {a['samples']} "
                         f"surface points is {a['median_abs_f']:.4g} (unit frame; threshold {SDF_MISMATCH_MEDIAN:g})"))
    a["passed"] = problem is None
    if problem and not force:
        raise NeuralBakeError(f"{texture.name}: {problem}; give the texture model fitted with this SDF, or "
                              f"{option} uses it anyway")
    if problem:
        import warnings

        from ..errors import NeuralBakeWarning

        warnings.warn(f"{texture.name}: {problem}; used anyway ({option})", NeuralBakeWarning, stacklevel=2)
    return a

