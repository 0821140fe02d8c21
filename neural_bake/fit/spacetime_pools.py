"""The sample pools of a space-time fit: every shape's samples at its time (:class:`ShapePools`) and the points in
between with the distances of the shapes around them (:func:`between_pool`, :func:`sequence_between_pool`)."""

from __future__ import annotations

import numpy as np
import torch

from .spacetime_config import SpaceTimeFitConfig

__all__ = ["ShapePools", "between_pool", "sequence_between_pool"]


def _tensor(a, dtype, device) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)


class ShapePools:
    """Every shape's samples, concatenated with each sample's τ: surface (p, n, τ), volume (p, d, τ)."""

    def __init__(self, shapes, taus, cfg: SpaceTimeFitConfig, dtype, device, *, share: bool):
        k = len(shapes)
        per = (lambda n, low: max(n // k, min(n, low))) if share else (lambda n, low: n)
        sp, sn, st, vp, vd, vt = [], [], [], [], [], []
        for i, (shape, tau) in enumerate(zip(shapes, taus)):
            seed = int(cfg.seed) * 10_007 + 101 * i
            p, n = shape.surface(per(cfg.pool_surface, 4096), seed)
            sp.append(p), sn.append(n), st.append(np.full(len(p), tau))
            parts = []
            if cfg.batch_near:
                parts.append(shape.near(per(cfg.pool_near, 4096), cfg.sigmas, seed + 1))
            if cfg.batch_uniform:
                parts.append(shape.uniform(per(cfg.pool_uniform, 1024), seed + 2))
            for p, d in parts:
                ok = np.isfinite(d) & np.isfinite(p).all(axis=1)
                vp.append(p[ok]), vd.append(d[ok]), vt.append(np.full(int(ok.sum()), tau))
        t = lambda parts, shape: _tensor(np.concatenate(parts) if parts else np.zeros(shape), dtype, device)  # noqa: E731
        self.surf = torch.cat([t(sp, (0, 3)), t(st, (0,))[:, None]], dim=1)
        self.surf_n = t(sn, (0, 3))
        self.vol = torch.cat([t(vp, (0, 3)), t(vt, (0,))[:, None]], dim=1)
        self.vol_d = t(vd, (0,))

    def draw(self, cfg: SpaceTimeFitConfig, gen: torch.Generator):
        dev = self.surf.device
        si = torch.randint(0, self.surf.shape[0], (cfg.batch,), generator=gen).to(dev)
        nv = cfg.batch_near + cfg.batch_uniform
        vi = torch.randint(0, max(self.vol.shape[0], 1), (nv if self.vol.shape[0] else 0,), generator=gen).to(dev)
        take = torch.index_select
        return take(self.surf, 0, si), take(self.surf_n, 0, si), take(self.vol, 0, vi), take(self.vol_d, 0, vi)


def between_pool(shapes, cfg: SpaceTimeFitConfig, dtype, device):
    """Morph: points near either end and uniform in the cube, with both ends' distances: (P, 3), (P, 2)."""
    rng_seed = int(cfg.seed) * 10_007 + 7_777
    n = int(cfg.pool_between)
    parts = [shapes[0].near(n // 3, cfg.sigmas, rng_seed)[0], shapes[1].near(n // 3, cfg.sigmas, rng_seed + 1)[0],
             np.random.default_rng([rng_seed, 3]).uniform(-1.0, 1.0, size=(n - 2 * (n // 3), 3))]
    x = np.concatenate(parts).astype(np.float64)
    d = np.stack([shapes[0].distance(x), shapes[1].distance(x)], axis=1)
    ok = np.isfinite(d).all(axis=1) & np.isfinite(x).all(axis=1)
    return _tensor(x[ok], dtype, device), _tensor(d[ok], dtype, device)


def sequence_between_pool(shapes, taus, cfg: SpaceTimeFitConfig, dtype, device):
    """Sequence: points for the in-between terms, each in one time step [τ_k, τ_{k+1}] (steps drawn in
    proportion to their length, so τ ends up uniform): near frame k, near frame k + 1 and uniform in the cube,
    with the distances to both frames. Returns (P, 3) points, (P, 2) distances, (P, 2) the step's τ ends."""
    rng_seed = int(cfg.seed) * 10_007 + 7_777
    rng = np.random.default_rng([rng_seed, 5])
    lengths = np.diff(np.asarray(taus, dtype=np.float64))
    counts = rng.multinomial(int(cfg.pool_between), lengths / lengths.sum())
    xs, ds, ends = [], [], []
    for k, c in enumerate(counts):
        a, b = shapes[k], shapes[k + 1]
        third = int(c) // 3
        parts = [rng.uniform(-1.0, 1.0, size=(int(c) - 2 * third, 3))]
        if third:
            parts += [a.near(third, cfg.sigmas, rng_seed + 2 * k)[0], b.near(third, cfg.sigmas, rng_seed + 2 * k + 1)[0]]
        x = np.concatenate(parts).astype(np.float64)
        if len(x) == 0:
            continue
        xs.append(x)
        ds.append(np.stack([a.distance(x), b.distance(x)], axis=1))
        ends.append(np.tile([taus[k], taus[k + 1]], (len(x), 1)))
    x, d, e = np.concatenate(xs), np.concatenate(ds), np.concatenate(ends)
    ok = np.isfinite(d).all(axis=1) & np.isfinite(x).all(axis=1)
    return _tensor(x[ok], dtype, device), _tensor(d[ok], dtype, device), _tensor(e[ok], dtype, device)
