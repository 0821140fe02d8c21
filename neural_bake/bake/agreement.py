"""Does an SDF describe the mesh it is baked onto? Two checks before a bake spends its time.

- **frames**: the SDF's frame (the mesh it was fitted on, normalised) and the mesh's own must agree within
  ``constants.FRAME_MISMATCH_TOL`` (:func:`~neural_bake.geometry.frame_mismatch`);
- **surface**: the median |f| at area-uniform samples of the mesh's surface must stay below
  ``constants.SDF_MISMATCH_MEDIAN`` (unit frame): a fitted SDF of that mesh reads about its sampled distance
  error there, another shape's reads the distance between the two surfaces.

Either failure is one line saying which check and by how much (:class:`NeuralBakeError`); ``force`` bakes
anyway and the figures still go into the report.
"""

from __future__ import annotations

import numpy as np
import torch

from ..constants import FRAME_MISMATCH_TOL, SDF_CHECK_SAMPLES, SDF_MISMATCH_MEDIAN
from ..errors import NeuralBakeError
from ..fields import SdfField
from ..geometry import frame_mismatch, mismatch_problem
from ..types import Mesh

__all__ = ["sdf_agreement", "check_sdf_describes_mesh"]


def sdf_agreement(mesh: Mesh, sdf: SdfField, *, samples: int = SDF_CHECK_SAMPLES, seed: int = 0) -> dict:
    """``{"frame_mismatch", "median_abs_f", "p95_abs_f", "samples"}`` of ``sdf`` against ``mesh``.

    ``frame_mismatch`` is 0 for a field without a frame (it lives in the mesh's); |f| is read in the
    field's unit frame at ``samples`` seeded area-uniform surface points of ``mesh``, moved into that frame.
    """
    from ..fit.sampling import sample_surface

    frame = sdf.frame or mesh.frame
    pts = sample_surface(mesh, int(samples), seed=seed).points
    pts = pts if frame == mesh.frame else frame.to_unit(mesh.frame.to_source(pts))
    model = sdf.model
    p = next(model.parameters()) if model is not None else None
    x = torch.as_tensor(np.asarray(pts), dtype=p.dtype if p is not None else torch.float64,
                        device=p.device if p is not None else "cpu")
    with torch.no_grad():
        f = (model(x)[:, 0] if model is not None else sdf.fn(x).reshape(-1)).double().abs().cpu().numpy()
    f = np.where(np.isfinite(f), f, np.inf)
    return {"frame_mismatch": frame_mismatch(frame, mesh.frame), "median_abs_f": float(np.median(f)),
            "p95_abs_f": float(np.percentile(f, 95)), "samples": int(samples)}


def check_sdf_describes_mesh(mesh: Mesh, sdf: SdfField, *, force: bool = False, option: str = "force=True") -> dict:
    """:func:`sdf_agreement`, raising :class:`NeuralBakeError` (one line: which check, by how much) when the
    frames differ beyond ``FRAME_MISMATCH_TOL`` or the median |f| exceeds ``SDF_MISMATCH_MEDIAN``, unless
    ``force``. ``option`` is how the message names the override. Returns the figures with ``"passed"``."""
    a = sdf_agreement(mesh, sdf)
    f = sdf.frame
    problem = mismatch_problem(
        a,
        frames=lambda: (f"the frames differ by {a['frame_mismatch']:.3g} (tolerance {FRAME_MISMATCH_TOL:g}): SDF "
                        f"centre {[round(c, 6) for c in f.center]} scale {f.scale:.6g}, mesh centre "
                        f"{[round(c, 6) for c in mesh.frame.center]} scale {mesh.frame.scale:.6g}"),
        surface=lambda: (f"median |f| on the mesh's surface is {a['median_abs_f']:.4g} (unit frame, {a['samples']} "
                         f"samples; threshold {SDF_MISMATCH_MEDIAN:g})"))
    a["passed"] = problem is None
    if problem and not force:
        raise NeuralBakeError(f"{sdf.name}: does not describe {mesh.name}: {problem}; fit the SDF on this mesh, "
                              f"or {option} bakes anyway")
    return a
