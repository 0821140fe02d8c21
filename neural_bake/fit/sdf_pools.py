"""The sample pools of SDF fitting and each step's draw from them (hard examples and mined zero-set points).

Pools are drawn from the mesh once per ``refresh_every`` steps, seeded by ``(seed, refresh index)`` so a
resumed run rebuilds exactly the same pools; a time-budgeted run skips the refreshes that would take more
than its share of the time (:class:`_Pools`, ``max_share``).
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np
import torch

from ..constants import (AUDIT_DAMPING, AUDIT_MAX_STEP, AUDIT_STEPS, LOSS_GRAD_FLOOR, MINED_ZERO_SET_TOL,
                         SIGN_MINING_TOL)
from ..errors import FitError
from ..nets.siren import Siren
from ..types import Mesh
from .sdf_config import SdfFitConfig


def near_reach(cfg: SdfFitConfig) -> float:
    """How far from the mesh the pools' near points get gradient targets ("vol_n"): the config's
    ``near_normal_reach`` when its near-normal term is on, else 0 (no targets computed)."""
    return float(cfg.near_normal_reach) if cfg.w_near_normal > 0 else 0.0


def _face_weights(mesh: Mesh, curvature: float, texel: float) -> np.ndarray | None:
    """The pools' per-face probabilities: ``texel`` of them by the map's texels
    (:func:`~neural_bake.fit.sampling.map_texel_weights`; none without UVs), the rest by area with a
    ``curvature`` share by curvature (:func:`~neural_bake.fit.sampling.curvature_face_weights`); None: by area."""
    from .sampling import curvature_face_weights, map_texel_weights

    by_uv = map_texel_weights(mesh) if texel > 0 else None
    if curvature <= 0 and by_uv is None:
        return None
    rest = curvature_face_weights(mesh, 1.0 - curvature)
    return rest if by_uv is None else (1.0 - texel) * rest + texel * by_uv


class _Pools:
    """Sample pools drawn from the mesh, rebuilt for every refresh index (deterministic in (seed, index)).

    ``max_share`` (time-budgeted runs): a refresh is skipped, keeping the current pools, while the time of
    the builds so far plus the last build's (the next one's estimate) would exceed this share of the time
    since the first build began, as ``clock`` measures it; ``skipped`` holds the refresh indices skipped,
    ``built`` counts the builds (:meth:`record`). ``prepare``: applied to every pool built (e.g.
    :func:`band_pools`, which keeps a coarse level's band and adds its values), inside the build's time.
    ``cache``: a dict shared by fits of one mesh, which then draw each pool from it once (keyed by the refresh
    index and the sampling settings; ``prepare`` is applied to the cached pool, not stored)."""

    def __init__(self, mesh: Mesh, cfg: SdfFitConfig, device, dtype, *, max_share: float | None = None,
                 clock: Callable[[], float] = time.perf_counter, prepare: Callable[[dict], dict] | None = None,
                 cache: dict | None = None):
        self.mesh, self.cfg, self.device, self.dtype = mesh, cfg, device, dtype
        self.prepare, self.cache = prepare, cache
        self.index = None
        self.face_weights = None  # curvature sampling's per-face probabilities (computed once)
        self.max_share, self.clock = max_share, clock
        self.started: float | None = None
        self.build_seconds = self.last_build = 0.0
        self.skipped: set[int] = set()
        self.built = 0

    def record(self) -> dict:
        """The pools' account, JSON-ready: ``built`` (pool builds, the first one included), ``skipped``
        (refreshes skipped to keep within the time share), ``build_seconds``."""
        return {"built": self.built, "skipped": len(self.skipped), "build_seconds": round(self.build_seconds, 3)}

    def get(self, step: int):
        idx = step // self.cfg.refresh_every if self.cfg.refresh_every else 0
        if idx != self.index:
            if self.started is not None and self.max_share:
                elapsed = self.clock() - self.started
                if self.build_seconds + self.last_build > self.max_share * (elapsed + self.last_build):
                    self.skipped.add(idx)
                    return self.data
            t0 = self.clock()
            self._build(idx)
            self.last_build = self.clock() - t0
            self.build_seconds += self.last_build
            self.built += 1
            self.started = t0 if self.started is None else self.started
        return self.data

    def _build(self, idx: int) -> None:
        cfg = self.cfg
        key = (idx, cfg.seed, cfg.pool_surface, cfg.pool_near, cfg.pool_uniform, tuple(cfg.sigmas),
               cfg.curvature_sampling, cfg.texel_sampling, cfg.surface_normals, near_reach(cfg), cfg.near_normal_gap_share,
               cfg.edge_sampling, cfg.edge_band,
               str(self.device), self.dtype)
        data = None if self.cache is None else self.cache.get(key)
        if data is None:
            data = self._sample(idx)
            if self.cache is not None:
                self.cache[key] = data
        self.data = data if self.prepare is None else self.prepare(data)
        self.index = idx

    def _sample(self, idx: int) -> dict:
        from .sampling import sample_near, sample_surface, sample_uniform

        cfg, mesh = self.cfg, self.mesh
        seed = int(cfg.seed) * 10_007 + idx
        try:
            if self.face_weights is None and (cfg.curvature_sampling > 0 or cfg.texel_sampling > 0):
                self.face_weights = _face_weights(mesh, cfg.curvature_sampling, cfg.texel_sampling)
            w = self.face_weights
            edges = {"edge_share": cfg.edge_sampling, "edge_band": cfg.edge_band}
            surf = sample_surface(mesh, cfg.pool_surface, seed=seed, face_weights=w, normals=cfg.surface_normals,
                                  colors=False, **edges)
            near = (sample_near(mesh, cfg.pool_near, sigma=cfg.sigmas, seed=seed + 1, face_weights=w,
                                targets=near_reach(cfg), target_normals=cfg.surface_normals,
                                target_gap_share=cfg.near_normal_gap_share, **edges)
                    if cfg.pool_near else None)
            uni = sample_uniform(mesh, cfg.pool_uniform, seed=seed + 2) if cfg.pool_uniform else None
        except (ValueError, RuntimeError) as exc:
            raise FitError(f"{mesh.name}: cannot sample the mesh for fitting ({exc})") from None

        def t(a):
            return torch.as_tensor(np.ascontiguousarray(a), dtype=self.dtype, device=self.device)

        vol_p = [v.points for v in (near, uni) if v is not None]
        vol_d = [v.sdf for v in (near, uni) if v is not None]
        # whether each point's sign is sure (near points are not mined: taken as sure)
        vol_s = [np.ones(len(v), dtype=bool) if v.sure is None or v is near else v.sure
                 for v in (near, uni) if v is not None]
        if surf.points.shape[0] == 0:
            raise FitError(f"{mesh.name}: no surface samples (every face is degenerate)")
        vp = np.concatenate(vol_p) if vol_p else np.zeros((0, 3), np.float32)
        vd = np.concatenate(vol_d) if vol_d else np.zeros(0, np.float32)
        vs = np.concatenate(vol_s) if vol_s else np.zeros(0, bool)
        finite = np.isfinite(vd) & np.isfinite(vp).all(axis=1)
        n_near = int(finite[: near.points.shape[0]].sum()) if near is not None else 0
        out = {"surf_p": t(surf.points), "surf_n": t(surf.normals), "vol_p": t(vp[finite]), "vol_d": t(vd[finite]),
               "vol_sure": torch.as_tensor(vs[finite], device=self.device), "n_near": n_near}
        if near_reach(cfg):  # the near points' gradient targets, zero rows for the others
            vn = np.zeros((len(vp), 3), np.float32)
            if near is not None and near.normals is not None:
                vn[: len(near)] = near.normals
            out["vol_n"] = t(vn[finite])
        return out


#: The keys :func:`band_pools` adds to a pool: the base field's values and gradients at its points, in the
#: order :func:`~neural_bake.fit.sdf_loss.sdf_loss_terms` takes them (``base``).
BASE_KEYS = ("surf_base", "surf_base_grad", "vol_base", "vol_base_grad")


def band_pools(base: Siren, band: float, chunk: int = 65536, audit: tuple | None = None,
               shell: float = 1.0, far: bool = False) -> Callable[[dict], dict]:
    """A pool ``prepare`` (:class:`_Pools`) for a level trained as a residual on the frozen network ``base``:
    it keeps only the points with |base| < ``band`` (surface, near and uniform alike) and adds base's values
    and GEMM gradients at them (:data:`BASE_KEYS`). ``audit``: (points (k, 3), true distances (k,)) of
    :func:`band_audit`, appended to every pool's uniform points (so they are drawn, and sign-mined, with
    them). ``shell``: keep the off-surface points out to ``shell`` × ``band`` (the surface points stay in the
    band), so the level is also held to the true distances just past the band's edge. ``far``: keep the uniform
    (and audit) points beyond the shell too, marked in ``vol_far`` (for sign mining alone: a level that is not
    one network everywhere can grow a surface there). FitError when no surface point is left in the band."""
    from ..nets.gemm import gemm_gradient

    def values(points: torch.Tensor):
        if points.shape[0] == 0:
            return points.new_zeros(0), points.new_zeros(0, 3)
        v, g = gemm_gradient(base, points, "reverse", chunk_size=chunk)
        return v[:, 0].to(points.dtype), g.to(points.dtype)

    def prepare(data: dict) -> dict:
        vol_p, vol_d = data["vol_p"], data["vol_d"]
        vol_s = data.get("vol_sure")
        if vol_s is None:
            vol_s = torch.ones(vol_p.shape[0], dtype=torch.bool, device=vol_p.device)
        if audit is not None:  # its points' signs are sure (band_audit keeps no other)
            vol_p = torch.cat([vol_p, audit[0].to(vol_p)])
            vol_d = torch.cat([vol_d, audit[1].to(vol_d)])
            vol_s = torch.cat([vol_s, torch.ones(audit[0].shape[0], dtype=torch.bool, device=vol_s.device)])
        sv, sg = values(data["surf_p"])
        vv, vg = values(vol_p)
        ks, kv = sv.abs() < band, vv.abs() < shell * band
        if not bool(ks.any()):
            raise FitError(f"band_pools: no surface sample lies in the band |base| < {band:.3g}")
        n_near = int(kv[: data["n_near"]].sum())
        keep = kv.clone()
        if far:
            keep[data["n_near"]:] = True
        out = {"surf_p": data["surf_p"][ks], "surf_n": data["surf_n"][ks], "vol_p": vol_p[keep],
               "vol_d": vol_d[keep], "vol_sure": vol_s[keep], "n_near": n_near, "surf_base": sv[ks],
               "surf_base_grad": sg[ks], "vol_base": vv[keep], "vol_base_grad": vg[keep]}
        if "vol_n" in data:  # the audit's points have no gradient target
            vol_n = data["vol_n"]
            out["vol_n"] = torch.cat([vol_n, vol_n.new_zeros(vol_p.shape[0] - vol_n.shape[0], 3)])[keep]
        if far:
            out["vol_far"] = ~kv[keep]
        return out

    return prepare


def band_audit(base: Siren, mesh: Mesh, band: float, tol: float, n: int, seed: int, chunk: int = 65536):
    """Points where the coarse level ``base`` is small but the mesh is not near (``SdfFitConfig.audit_candidates``):
    ``(points (k, 3), d (k,))`` with their true signed distances, or None where there are none.

    A level trained inside h's band |h| < ``band`` sees only the uniform points that happen to fall where h
    comes close to zero away from the mesh (a valley of h that stops short of crossing it); a few stray
    pieces of its surface there are a thousandth of the volume, below what the uniform pool samples. The
    audit looks there on purpose: ``n`` candidates uniform in [-1, 1]³ take :data:`AUDIT_STEPS
    <neural_bake.constants.AUDIT_STEPS>` damped Gauss–Newton steps on h² (towards h's zero set, or a
    valley's floor), and of those that end inside the band the ones whose true |d| exceeds |h| by more than
    ``tol`` (the coarse level's own distance error) — and is at least :data:`~neural_bake.constants.SIGN_MINING_TOL`
    — are kept, in base's dtype and device, where their sign is sure
    (:func:`~neural_bake.fit.sampling.signed_distance_sure`: not beside an open sheet)."""
    from ..nets.gemm import gemm_gradient
    from .sampling import signed_distance_sure

    p = next(base.parameters())
    gen = torch.Generator().manual_seed(int(seed))
    x = (torch.rand(int(n), 3, generator=gen, dtype=torch.float64) * 2.0 - 1.0).to(device=p.device, dtype=p.dtype)
    if x.shape[0] == 0:
        return None
    with torch.no_grad():
        for _ in range(AUDIT_STEPS):
            v, g = gemm_gradient(base, x, "reverse", chunk_size=chunk)
            step = v * g / ((g * g).sum(dim=1, keepdim=True) + AUDIT_DAMPING)
            length = torch.linalg.vector_norm(step, dim=1, keepdim=True)
            step = step * (AUDIT_MAX_STEP / length.clamp_min(AUDIT_MAX_STEP))
            x = torch.where(torch.isfinite(step), x - step, x).clamp(-1.0, 1.0)
        h = torch.cat([base(part)[:, 0] for part in torch.split(x, chunk)])
    keep = torch.isfinite(h) & (h.abs() < band)
    x, h = x[keep], h[keep]
    if x.shape[0] == 0:
        return None
    d, sure = signed_distance_sure(mesh, x.double().cpu().numpy())
    d = torch.as_tensor(d, dtype=x.dtype, device=x.device)
    far = (d.abs() >= h.abs() + tol) & (d.abs() >= SIGN_MINING_TOL) & torch.as_tensor(sure, device=x.device)
    return (x[far].contiguous(), d[far].contiguous()) if bool(far.any()) else None


def _hard_indices(model: Siren, points: torch.Tensor, cfg: SdfFitConfig, target: torch.Tensor | None = None):
    """Indices of the ``hard_pool`` part of ``points`` with the largest |f − target| (target 0: |f|; at
    least one)."""
    with torch.no_grad():
        err = model(points)[:, 0]
        err = (err if target is None else err - target).abs()
    return _top_part(err, cfg.hard_pool)


def remine_due(cfg: SdfFitConfig, step: int, new_pool: bool) -> bool:
    """Whether a fit re-ranks its mined sets (hard examples, sign errors, zero-set points) at ``step``: at a new
    pool, every ``hard_every`` steps and at each checkpoint step, so that a run resumed from a periodic
    checkpoint re-ranks exactly where the uninterrupted run did."""
    return new_pool or step % cfg.hard_every == 0 or (bool(cfg.checkpoint) and step % cfg.checkpoint_every == 0)


def _sign_errors(model: Callable[[torch.Tensor], torch.Tensor], pools: dict, chunk: int = 65536
                 ) -> torch.Tensor | None:
    """Indices into the volume pool of its uniform points where f and the true distance d differ in sign with
    |d| ≥ :data:`~neural_bake.constants.SIGN_MINING_TOL` and d's sign is sure (``vol_sure``: not beside an
    open sheet) (``SdfFitConfig.sign_fraction``), or None where there are none. ``model`` maps (n, 3) points
    to (n, 1) values; with a residual level's pool (``vol_base``, :func:`band_pools`) f is the sum base + model."""
    n_near, vp, vd = pools["n_near"], pools["vol_p"], pools["vol_d"]
    if vp.shape[0] <= n_near:
        return None
    with torch.no_grad():
        f = torch.cat([model(part)[:, 0] for part in torch.split(vp[n_near:], chunk)])
    if "vol_base" in pools:
        f = f + pools["vol_base"][n_near:]
    d = vd[n_near:]
    wrong = (d.abs() >= SIGN_MINING_TOL) & (torch.sign(f) != torch.sign(d))
    if "vol_sure" in pools:  # a sign the mesh does not define (beside an open sheet) is not an error to mine
        wrong &= pools["vol_sure"][n_near:]
    idx = torch.nonzero(wrong).flatten()
    return idx + n_near if idx.numel() else None


def _error_cdf(model: Siren, points: torch.Tensor, normals: torch.Tensor, chunk: int = 65536):
    """(n,) float64 cumulative sums of the network's normal error 1 − cos(∇f, n) at the surface pool's
    ``points`` (n, 3) with normals ``normals`` (n, 3), for importance draws (``SdfFitConfig.error_sampling``);
    None when the error is zero (or not finite) everywhere. Points where |∇f| vanishes count the error 1."""
    from ..nets.gemm import gemm_gradient

    parts = []
    with torch.no_grad():
        for s in range(0, points.shape[0], chunk):
            _, g = gemm_gradient(model, points[s:s + chunk], "reverse")
            norm = torch.linalg.vector_norm(g, dim=1)
            cos = (g * normals[s:s + chunk]).sum(dim=1) / norm.clamp_min(LOSS_GRAD_FLOOR)
            parts.append(torch.where(norm > LOSS_GRAD_FLOOR, 1.0 - cos, torch.ones_like(cos)))
    err = torch.cat(parts).double() if parts else points.new_zeros(0, dtype=torch.float64)
    err = torch.where(torch.isfinite(err), err.clamp_min(0.0), torch.zeros_like(err))
    cdf = torch.cumsum(err, 0)
    return cdf if cdf.numel() and float(cdf[-1]) > 0 else None


def _importance_draw(cdf: torch.Tensor, n: int, gen: torch.Generator) -> torch.Tensor:
    """(n,) int64 indices drawn with probability proportional to the increments of ``cdf`` (n_pool,)."""
    u = torch.rand(n, generator=gen, dtype=torch.float64).to(cdf.device) * cdf[-1]
    return torch.searchsorted(cdf, u, right=True).clamp_max(cdf.shape[0] - 1)


def _top_part(err: torch.Tensor, part: float) -> torch.Tensor:
    """Indices of the ``part`` of ``err`` (n,) with the largest values (at least one; 0 < part ≤ 1)."""
    return torch.topk(err, max(1, int(round(part * err.shape[0]))), sorted=False).indices


def _zero_set_samples(model: Siren, mesh: Mesh, near_p: torch.Tensor, cfg: SdfFitConfig, seed: int):
    """Mined points of the network's zero level set and their true signed distances: ``(points (k, 3),
    d (k,))`` (see ``SdfFitConfig.zero_fraction``), or None when no candidate reached f ≈ 0."""
    from .metrics import project_to_zero_set
    from .sampling import signed_distance

    gen = torch.Generator().manual_seed(seed)
    pick = torch.randint(0, near_p.shape[0], (int(cfg.zero_candidates),), generator=gen).to(near_p.device)
    x = project_to_zero_set(model, torch.index_select(near_p, 0, pick), 2)
    with torch.no_grad():
        f = model(x)[:, 0]
    ok = torch.isfinite(x).all(dim=1) & (f.abs() <= MINED_ZERO_SET_TOL)
    x = x[ok]
    if x.shape[0] == 0:
        return None
    d = torch.as_tensor(signed_distance(mesh, x.double().cpu().numpy()), dtype=x.dtype, device=x.device)
    top = _top_part(d.abs(), cfg.hard_pool)
    return x[top].contiguous(), d[top].contiguous()


def _with_hard(idx: torch.Tensor, hard: torch.Tensor | None, fraction: float, gen: torch.Generator):
    """``idx`` (n,) with its last ``fraction`` · n entries drawn from ``hard`` instead (unchanged if None)."""
    n_hard = int(idx.shape[0] * fraction) if hard is not None else 0
    if n_hard:
        pick = torch.randint(0, hard.shape[0], (n_hard,), generator=gen)
        idx[idx.shape[0] - n_hard:] = hard.to(idx.device)[pick.to(hard.device)]
    return idx


def _draw(pools: dict, cfg: SdfFitConfig, gen: torch.Generator, hard: dict | None = None, extra: tuple = ()):
    """A step's batch; with ``hard`` ({"surf", "near"} index tensors) the tail of the surface and near
    batches (``hard_fraction`` of each) comes from the hard sets, with ``hard["sign"]`` (:func:`_sign_errors`)
    the tail of the uniform batch (``sign_fraction`` of it) from the network's sign errors; with
    ``hard["error"]`` (a normal-error cdf, :func:`_error_cdf`) the head of the surface batch
    (``error_sampling`` of it) is drawn by it.
    ``extra``: keys of further per-point pool arrays ("surf_*" beside the surface points, "vol_*" beside the
    off-surface ones, e.g. :data:`BASE_KEYS`) drawn with the same indices, returned after the four (not with
    mined zero-set points, which no pool array covers, but "vol_n", the near points' gradient targets: none at
    mined points)."""
    dev = pools["surf_p"].device
    hard = hard or {}
    si = torch.randint(0, pools["surf_p"].shape[0], (cfg.batch,), generator=gen).to(dev)
    n_err = int(cfg.batch * cfg.error_sampling) if hard.get("error") is not None else 0
    if n_err:  # the head of the surface batch: drawn by the network's current normal error
        si[:n_err] = _importance_draw(hard["error"], n_err, gen).to(dev)
    si = _with_hard(si, hard.get("surf"), cfg.hard_fraction, gen)
    n_near, n_vol = pools["n_near"], pools["vol_p"].shape[0]
    parts = []
    if cfg.batch_near and n_near:  # hard near indices point into the near part of the volume pool
        ni = torch.randint(0, n_near, (cfg.batch_near,), generator=gen)
        parts.append(_with_hard(ni, hard.get("near"), cfg.hard_fraction, gen))
    if cfg.batch_uniform and n_vol > n_near:  # its tail from the network's sign errors, where there are any
        ui = torch.randint(n_near, n_vol, (cfg.batch_uniform,), generator=gen)
        parts.append(_with_hard(ui, hard.get("sign"), cfg.sign_fraction, gen))
    vi = torch.cat(parts).to(dev) if parts else torch.zeros(0, dtype=torch.long, device=dev)
    # index_select, not x[idx]: advanced indexing of these small rows is several times slower on a CPU
    take = torch.index_select
    vp, vd = take(pools["vol_p"], 0, vi), take(pools["vol_d"], 0, vi)
    zero = hard.get("zero")
    n_zero = int(cfg.batch_near * cfg.zero_fraction) if zero is not None and cfg.batch_near and n_near else 0
    if n_zero:  # the head of the near batch: mined zero-set points with their true distances
        if set(extra) - {"vol_n"}:
            raise FitError("_draw: mined zero-set points have no pool arrays to draw beside them")
        pick = torch.randint(0, zero[0].shape[0], (n_zero,), generator=gen).to(dev)
        vp[:n_zero] = take(zero[0], 0, pick)
        vd[:n_zero] = take(zero[1], 0, pick)
    more = tuple(take(pools[k], 0, si if k.startswith("surf") else vi) for k in extra)
    if n_zero and extra:  # mined points carry no gradient target
        more[extra.index("vol_n")][:n_zero] = 0.0
    return (take(pools["surf_p"], 0, si), take(pools["surf_n"], 0, si), vp, vd, *more)

