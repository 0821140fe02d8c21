"""The classical mesh-to-mesh bake as maps of its own: what a DCC tool's bake gives on the same texels.

:func:`classical_bake` rasterises a coarse mesh's UV layout (a :class:`~neural_bake.bake.baker.Baker`, which
unwraps only a mesh without UVs), runs :func:`~neural_bake.bake.baseline.baseline_bake` (rays along ± the
interpolated normal to the fine mesh, the closest point where none hits) at every texel sample, and encodes
its normals and colours into a tangent-space normal map and an albedo map exactly as the neural bake does
(glTF / OpenGL, +Y green up; per-texel average of the samples, then chart padding). Its :class:`BakeResult`
goes through the same :func:`~neural_bake.bake.report.bake_report`, so the two bakes' figures compare.
"""

from __future__ import annotations

import time

import numpy as np

from ..constants import DIRECTION_EPS
from ..types import Mesh
from .baker import Baker, BakeResult
from .baseline import baseline_bake
from .maps import encode_tangent_space, splat_into
from .padding import pad_charts

__all__ = ["classical_bake"]


def classical_bake(coarse: Mesh, fine: Mesh, size: int, *, supersample: int = 1, cage: float | None = None,
                   padding: str | None = "pull-push") -> tuple[BakeResult, Baker]:
    """Bake ``fine``'s normals (and texture, when it has one) onto ``coarse``'s texels by rays.

    - ``coarse``: the mesh to bake onto (its UV layout is kept; unit frame of its own ``frame``).
    - ``fine``: the high-resolution mesh (normals from its vertex normals, colours from its texture).
    - ``size``, ``supersample``, ``padding``: as :class:`Baker` takes them.
    - ``cage``: ray length on each side (unit frame of ``fine``; None: the baseline's default).

    Returns (result, baker): ``result.normal_map`` (H, W, 3) encoded ``(n + 1) / 2`` in the tangent space
    of ``baker.tangents``; ``result.albedo`` linear RGB or None; per-sample normals and colours in the order
    of ``baker.texels``; ``stats["seconds"]`` with the baseline's stages.
    """
    t_all = time.perf_counter()
    baker = Baker(coarse, size, supersample=supersample, padding=padding, cache_texels=True)
    t_prep = time.perf_counter() - t_all
    t_bake = time.perf_counter()
    tx = baker.texels
    base = baseline_bake(baker.mesh, fine, tx, cage=cage)
    t0 = time.perf_counter()
    normals = np.asarray(base["normals"], dtype=np.float64)
    encoded, _ = encode_tangent_space(normals, tx.tangent, tx.bitangent, tx.normal, "opengl")
    h, w = baker.shape
    acc = np.zeros((h, w, 3), dtype=np.float64)
    wsum = np.zeros((h, w), dtype=np.float64)
    splat_into(acc, wsum, encoded, tx.pixel, tx.weight)
    covered = wsum > 0
    norm = np.linalg.norm(acc, axis=2, keepdims=True)
    vec = np.where(norm > DIRECTION_EPS, acc / np.maximum(norm, DIRECTION_EPS), (0.0, 0.0, 1.0))
    normal_map = np.clip((vec + 1.0) / 2.0, 0.0, 1.0)
    albedo = None
    colors = base.get("colors")
    if colors is not None:
        col = np.zeros((h, w, colors.shape[1]), dtype=np.float64)
        splat_into(col, None, colors, tx.pixel, tx.weight)
        albedo = np.divide(col, wsum[..., None], out=np.zeros_like(col), where=wsum[..., None] > 0)
    if padding is not None:
        normal_map = pad_charts(normal_map, covered, method=padding)
        if albedo is not None:
            albedo = pad_charts(albedo, covered, method=padding)
    t_maps = time.perf_counter() - t0
    m = len(normals)
    stats = {"size": [h, w], "normal_space": "tangent", "y_convention": "opengl", "supersample": baker.supersample,
             "samples": m, "texels_covered": int(covered.sum()), "coverage": float(covered.mean()),
             "invalid_gradients": 0, "fallback": base["fallback"], "cage": base["cage"],
             "seconds": {**{k: float(v) for k, v in baker.timings.items()},
                         "prepare": t_prep, "rays": base["seconds"]["rays"] + base["seconds"]["setup"],
                         "closest": base["seconds"]["closest"], "shade": base["seconds"]["shade"], "maps": t_maps,
                         "bake": time.perf_counter() - t_bake}}
    result = BakeResult(normal_map=normal_map.astype(np.float32),
                        albedo=None if albedo is None else albedo.astype(np.float32), coverage=covered,
                        miss=np.zeros((h, w), dtype=bool), normals=normals, encoded=encoded,
                        valid=np.ones(m, dtype=bool), values=np.zeros(m), colors=colors, stats=stats)
    return result, baker
