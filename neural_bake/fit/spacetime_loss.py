"""The loss of a space-time fit (:mod:`neural_bake.fit.spacetime` describes its terms): the static terms at the
shapes' times and the level set equation, interpolation or eikonal term in between, from one GEMM pass."""

from __future__ import annotations

import torch

from ..constants import LOSS_GRAD_FLOOR
from ..nets.gemm import gemm_gradient
from ..nets.siren import Siren
from .spacetime_config import SpaceTimeFitConfig

__all__ = ["spacetime_loss_terms"]


def spacetime_loss_terms(model: Siren, surf: torch.Tensor, surf_n: torch.Tensor, vol: torch.Tensor,
                         vol_d: torch.Tensor, between: torch.Tensor, between_d: torch.Tensor | None,
                         cfg: SpaceTimeFitConfig, *, mode: str, dtau_dt: float,
                         between_w: torch.Tensor | None = None) -> dict:
    """The loss terms of one step (scalar tensors) and their weighted sum ``"loss"``.

    Args:
        surf, surf_n: (S, 4) surface points (x, τ) at shape times and (S, 3) their unit outward normals.
        vol, vol_d: (V, 4) near/uniform points at shape times and (V,) their true signed distances.
        between: (B, 4) points at times in between.
        between_d: (B, 2) the distances (d_A, d_B) of the shapes before and after each between point (None
            with "eikonal").
        mode: "lse", "interpolate" or "eikonal" (eikonal only in between).
        dtau_dt: dτ/dt = 2E / (t1 − t0), the factor turning ∂f/∂τ into ∂f/∂t.
        between_w: (B,) the interpolation weight s of d_B at each between point (default: a morph's,
            s = (τ / E + 1) / 2).

    One differentiable GEMM pass gives f and its full gradient at all S + V + B points (no double-backward).
    """
    s, v = surf.shape[0], vol.shape[0]
    pts = torch.cat([surf, vol, between], dim=0)
    values, grads = gemm_gradient(model, pts, "reverse", differentiable=True)
    f = values[:, 0]
    gx = grads[:, :3]
    gnorm = torch.linalg.vector_norm(gx, dim=1)
    zero = f.new_zeros(())
    terms = {
        "surface": (f[:s] ** 2).mean() if s else zero,
        "normal": (1.0 - (gx[:s] * surf_n).sum(1) / gnorm[:s].clamp_min(LOSS_GRAD_FLOOR)).mean() if s else zero,
        "sdf": ((f[s:s + v] - vol_d) ** 2).mean() if v else zero,
        "eikonal": ((1.0 - gnorm) ** 2).mean(),
    }
    loss = (cfg.w_surface * terms["surface"] + cfg.w_normal * terms["normal"] + cfg.w_sdf * terms["sdf"]
            + cfg.w_eikonal * terms["eikonal"])
    b = between.shape[0]
    if b and mode == "lse":
        f_t = grads[s + v:, 3] * dtau_dt
        speed = between_d[:, 0] - between_d[:, 1]  # v = d_A − d_B per unit of t (t1 − t0 = 1 for a morph)
        terms["lse"] = ((f_t + speed * gnorm[s + v:]) ** 2).mean()
        loss = loss + cfg.w_lse * terms["lse"]
    elif b and mode == "interpolate":
        w = (between[:, 3] / cfg.time_extent + 1.0) * 0.5 if between_w is None else between_w
        target = (1.0 - w) * between_d[:, 0] + w * between_d[:, 1]
        terms["interp"] = ((f[s + v:] - target) ** 2).mean()
        loss = loss + cfg.w_interp * terms["interp"]
    terms["loss"] = loss
    return terms
