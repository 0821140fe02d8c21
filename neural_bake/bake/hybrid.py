"""Hybrid bake: every texel where the neural field is not faithful takes the classical mesh-to-mesh normal.

A texel sample is *not faithful* when |f| at the point of the source surface it maps to (where the classical
bake's ray lands) is above ``sdf_tol`` (the field does not put its surface there), when ∇f at the texel
disagrees with the source mesh's normal there by more than ``angle_deg``, or when ∇f is unusable (|∇f| ≈ 0).
Such samples take the classical bake's normal (:func:`~neural_bake.bake.baseline.baseline_bake`), so no
texel of the map is further than ``angle_deg`` from the source mesh's normal.

:class:`HybridFallback` is what :meth:`neural_bake.bake.baker.Baker.bake` calls per band of texel samples.
"""

from __future__ import annotations

import numpy as np

from ..constants import HYBRID_ANGLE_DEG, HYBRID_SDF_TOL
from ..errors import NeuralBakeError
from ..types import Mesh

__all__ = ["HybridFallback", "unfaithful"]


def unfaithful(f_surface: np.ndarray, neural: np.ndarray, source: np.ndarray, valid: np.ndarray, *,
               sdf_tol: float = HYBRID_SDF_TOL, angle_deg: float = HYBRID_ANGLE_DEG) -> dict[str, np.ndarray]:
    """Which samples the neural field does not represent faithfully.

    - ``f_surface``: (M,) f at the source-surface point of each sample (unit frame distances).
    - ``neural``: (M, 3) unit ∇f at the samples; ``source``: (M, 3) unit source-mesh normals there.
    - ``valid``: (M,) bool, ∇f was usable.

    Returns ``{"mask": (M,) bool (any reason), "sdf": |f| > sdf_tol, "angle": angle > angle_deg,
    "invalid": ~valid}``; a non-finite f counts as above the tolerance.
    """
    f = np.asarray(f_surface, dtype=np.float64)
    far = ~(np.abs(f) <= sdf_tol)  # NaN counts as far
    cos = np.einsum("ij,ij->i", np.asarray(neural, dtype=np.float64), np.asarray(source, dtype=np.float64))
    off = ~(cos >= np.cos(np.radians(angle_deg)))
    invalid = ~np.asarray(valid, dtype=bool)
    return {"mask": far | off | invalid, "sdf": far, "angle": off & ~invalid, "invalid": invalid}


class HybridFallback:
    """Per band of texel samples: the classical bake, f at its source points, and the replacement.

    - ``fine``: the source mesh (unit frame), the classical bake's target and the normals' reference.
    - ``sdf``: the SDF field the neural normals come from (its ``frame``, if any, is honoured).
    - ``sdf_tol``, ``angle_deg``: the two thresholds (:data:`~neural_bake.constants.HYBRID_SDF_TOL`,
      :data:`~neural_bake.constants.HYBRID_ANGLE_DEG`).
    - ``cage``: the classical bake's ray distance (unit frame; None: its default).
    - ``keep_baseline``: keep each band's classical bake (``self.baselines``), e.g. for the quality report
      of a bake whose texels are cached, so it is not cast twice.

    Called as ``fallback(coarse, texels, normals, valid)`` with the coarse mesh the texels lie on, a
    :class:`~neural_bake.mesh.texels.TexelSet` band, its (M, 3) unit ∇f and (M,) valid mask; returns
    ``(normals (M, 3) with the unfaithful samples replaced, mask (M,) bool of the replaced samples)``.
    ``self.counts`` sums the samples per reason over the calls; ``self.f_abs`` keeps |f| at the source points.
    """

    def __init__(self, fine: Mesh, sdf, *, sdf_tol: float = HYBRID_SDF_TOL, angle_deg: float = HYBRID_ANGLE_DEG,
                 cage: float | None = None, keep_baseline: bool = False, chunk_size: int = 1 << 16):
        if not (np.isfinite(sdf_tol) and sdf_tol > 0):
            raise NeuralBakeError(f"hybrid sdf_tol must be a positive distance, got {sdf_tol!r}")
        if not (np.isfinite(angle_deg) and 0 < angle_deg <= 180):
            raise NeuralBakeError(f"hybrid angle_deg must be in (0, 180] degrees, got {angle_deg!r}")
        from .baseline import raycasting_scene

        self.fine, self.sdf, self.sdf_tol, self.angle_deg = fine, sdf, float(sdf_tol), float(angle_deg)
        self.cage, self.keep_baseline, self.chunk_size = cage, bool(keep_baseline), int(chunk_size)
        self.scene = raycasting_scene(fine)
        self.baselines: list[dict] = []
        self.counts = {"samples": 0, "replaced": 0, "sdf": 0, "angle": 0, "invalid": 0}
        self.f_abs: list[np.ndarray] = []
        self.seconds = 0.0

    def field_values(self, points: np.ndarray) -> np.ndarray:
        """f (M,) at ``points`` (M, 3) in the fine mesh's unit frame (converted to the field's frame): the
        field's forward pass alone (:meth:`~neural_bake.fields.sdf.SdfField.value`), no gradient."""
        import torch

        from .baker import _tensor_kwargs, _to_field_frame

        pts = _to_field_frame(np.asarray(points, dtype=np.float64), self.fine.frame, self.sdf.frame)
        kw = _tensor_kwargs(self.sdf)
        out = np.empty(len(pts))
        for s in range(0, len(pts), self.chunk_size):
            out[s: s + self.chunk_size] = self.sdf.value(torch.as_tensor(pts[s: s + self.chunk_size], **kw)).double().cpu().numpy()
        return out

    def __call__(self, coarse: Mesh, texels, normals: np.ndarray, valid: np.ndarray):
        import time

        from .baseline import baseline_bake

        t0 = time.perf_counter()
        base = baseline_bake(coarse, self.fine, texels, cage=self.cage, scene=self.scene)
        f_surf = self.field_values(base["points"]) if len(base["points"]) else np.zeros(0)
        why = unfaithful(f_surf, normals, base["normals"], valid, sdf_tol=self.sdf_tol, angle_deg=self.angle_deg)
        mask = why["mask"]
        out = np.array(normals, dtype=np.float64, copy=True)
        out[mask] = base["normals"][mask]
        self.counts["samples"] += len(mask)
        self.counts["replaced"] += int(mask.sum())
        for k in ("sdf", "angle", "invalid"):
            self.counts[k] += int(why[k].sum())
        self.f_abs.append(np.abs(f_surf))
        if self.keep_baseline:
            self.baselines.append(base)
        self.seconds += time.perf_counter() - t0
        return out, mask

    def summary(self) -> dict:
        """JSON-ready totals: thresholds, counts per reason, share of samples replaced, |f| at the source."""
        f = np.concatenate(self.f_abs) if self.f_abs else np.zeros(0)
        n = max(1, self.counts["samples"])
        return {"sdf_tol": self.sdf_tol, "angle_deg": self.angle_deg, **self.counts,
                "sample_fraction": self.counts["replaced"] / n,
                "f_at_source": {"median": float(np.median(f)) if f.size else None,
                                "p95": float(np.percentile(f, 95)) if f.size else None,
                                "max": float(f.max()) if f.size else None},
                "seconds": self.seconds}

    def baseline(self) -> dict | None:
        """The kept classical bake over every call, concatenated in call order (None if not kept)."""
        if not self.keep_baseline or not self.baselines:
            return None
        b = self.baselines
        out = {k: np.concatenate([x[k] for x in b]) for k in ("normals", "points", "hit", "distance")}
        out["colors"] = None if b[0]["colors"] is None else np.concatenate([x["colors"] for x in b])
        out["fallback"] = int(sum(x["fallback"] for x in b))
        out["cage"] = b[0]["cage"]
        out["seconds"] = {k: float(sum(x["seconds"][k] for x in b)) for k in b[0]["seconds"]}
        return out

