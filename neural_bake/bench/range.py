"""Range-analysis benchmark: cost and tightness of each method, like Spelunking Table 1.

For each network and region kind (1-D ray segments of random direction, 3-D axis-aligned boxes) and each
method of :func:`~neural_bake.nets.range_analysis.range_bound`:

- **time ×fwd**: wall time per box relative to a plain forward pass per point (the same number of box
  centres, same model, float32), and microseconds per box;
- **tightness**: median over random boxes of (bound width) / (true range width), the true range being
  estimated by dense sampling (so the ratio is, if anything, overestimated), for half-sizes 1e-3 … 1;
- **useful h**: the largest half-size whose median ratio is at most 2;
- **signed h**: the paper's measure — the largest half-size at which at least half the boxes are bounded
  away from zero (``lo > 0`` or ``hi < 0``), i.e. classified POSITIVE / NEGATIVE by Procedure 1.

The baseline a user would otherwise pick is dense sampling of each box (no guarantee: it can only
*underestimate* the range); its row shows its time and the fraction of the true range it sees.
"""

from __future__ import annotations

import time

import torch

from ..nets.range_analysis import METHODS, difference_bound, range_bound
from ..nets.siren import Siren
from .common import load_note, machine_info, timeit

__all__ = ["run"]


def _regions(kind: str, n: int, half: float, g: torch.Generator):
    """n random regions of half-size ``half``: centres in [-1, 1]^3; segments of random direction, or cubes."""
    c = torch.rand(n, 3, generator=g) * 2 - 1
    if kind == "1d segment":
        v = torch.randn(n, 1, 3, generator=g)
        axes = v / v.norm(dim=-1, keepdim=True) * half
    else:
        axes = torch.eye(3).expand(n, 3, 3) * half
    return c, axes.contiguous()


def _dense_points(c: torch.Tensor, axes: torch.Tensor, per_axis: int) -> torch.Tensor:
    """(B, per_axis^s, 3) grid points of each region (ends and corners included)."""
    s = axes.shape[1]
    t1 = torch.linspace(-1, 1, per_axis)
    grids = torch.stack(torch.meshgrid(*([t1] * s), indexing="ij"), dim=-1).reshape(-1, s)
    return c[:, None, :] + torch.einsum("ns,bsd->bnd", grids, axes)


@torch.no_grad()
def _dense_range(model, c, axes, per_axis: int, batch: int = 1 << 16):
    pts = _dense_points(c, axes, per_axis)
    flat = pts.reshape(-1, 3)
    vals = torch.cat([model(flat[i:i + batch])[:, 0] for i in range(0, flat.shape[0], batch)])
    vals = vals.reshape(pts.shape[:2])
    return vals.amin(1), vals.amax(1)


def _timed(fn, repeat: int, min_time: float, warm: float = 0.3) -> float:
    """Best time of ``fn`` after warming up for ``warm`` seconds (the first calls of a process can be 100×
    slower while thread pools and kernels settle)."""
    t_end = time.perf_counter() + warm
    fn()
    while time.perf_counter() < t_end:
        fn()
    return timeit(fn, repeat=repeat, warmup=0, min_time=min_time)


@torch.no_grad()
def _difference_rows(f, methods, quick: bool, g: torch.Generator) -> list[dict]:
    """Certified sup|h - f| over boxes, h = f with every weight perturbed by 0.1 % (a stand-in for a distilled
    coarse level), with shared input symbols (difference_bound) and without (range(h) - range(f))."""
    h = Siren(**f.architecture)
    h.load_state_dict(f.state_dict())
    for p in h.parameters():
        p.mul_(1 + 1e-3 * torch.randn(p.shape, generator=g))
    big = f.width * (f.depth + 1) > 256
    n = (8 if big else 24) if quick else (24 if big else 96)
    rows = []
    for kind in ("1d segment", "3d box"):
        per_axis = 256 if kind == "1d segment" else 8
        for half in (1e-3, 1e-2, 1e-1):
            c, ax = _regions(kind, n, half, g)
            pts = _dense_points(c, ax, per_axis).reshape(-1, 3)
            sampled = (h(pts) - f(pts)).abs().reshape(n, -1).amax(1)
            for method in methods:
                lo, hi = difference_bound(h, f, c, ax, method)
                shared = torch.maximum(-lo, hi)
                hlo, hhi = range_bound(h, c, ax, method)
                flo, fhi = range_bound(f, c, ax, method)
                unshared = torch.maximum(fhi - hlo, hhi - flo)
                rows.append({
                    "region": kind, "half-size": half, "method": method,
                    "sampled max|h-f|": float(sampled.median()),
                    "certified (shared)": float(shared.median()),
                    "certified (range h - range f)": float(unshared.median()),
                    "shared / sampled": float((shared / sampled.clamp_min(1e-30)).median()),
                })
    return rows


def _largest(sizes, ok):
    """The largest size whose flag is set, or ``"<smallest"`` when none is."""
    good = [h for h, k in zip(sizes, ok) if k]
    return max(good) if good else f"<{min(sizes):g}"


def run(
    quick: bool = False,
    *,
    seed: int = 0,
    omega: float = 30.0,
    model_path: str | None = None,
    methods: tuple[str, ...] = METHODS,
    truncate_keep: int = 64,
    threads: int | None = 1,
) -> dict:
    """Measure every range-analysis method on a (64, 1) and a (256, 3) SIREN (or one model file).

    Args:
        quick: a shrunken run (fewer boxes, sizes and samples) that finishes in well under two minutes.
        seed: seed of the random networks and regions.
        omega: ω0 of the random SIRENs (first and hidden layers).
        model_path: measure this model file (``neural-bake fit sdf`` output) instead of random SIRENs.
        methods: which methods to run.
        truncate_keep: ``keep`` of ``affine-truncate``.
        threads: torch threads while timing (default 1: on a shared CPU, multi-threaded small GEMMs stall on
            descheduled threads and the figures become noise; None keeps the current setting).

    Returns:
        The benchmark dict (``name``, ``title``, ``machine``, ``quick``, ``tables``, ``notes``).
    """
    old_threads = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(int(threads))
    try:
        return _run(quick, seed, omega, model_path, methods, truncate_keep)
    finally:
        torch.set_num_threads(old_threads)


def _run(quick, seed, omega, model_path, methods, truncate_keep) -> dict:
    g = torch.Generator().manual_seed(seed)
    if model_path is not None:
        from ..fields import load_model  # any network: range analysis does not care what it is

        model, _ = load_model(model_path, dtype=torch.float32)
        nets = [(f"{model_path} ({model.width},{model.depth})", model)]
    else:
        nets = [(f"({w},{d}) random SIREN ω0={omega:g}", Siren(w, d, omega_0=omega, hidden_omega=omega, generator=g))
                for w, d in ((64, 1), (256, 3))]
    sizes = [1e-3, 1e-2, 1e-1, 1.0] if quick else [1e-3, 3e-3, 1e-2, 3e-2, 1e-1, 3e-1, 1.0]
    shown = [1e-3, 1e-2, 1e-1, 1.0]
    n_time = 128 if quick else 1024  # boxes per timing batch
    min_time = 0.1 if quick else 1.0  # best of repeated runs over at least this long: less disturbed by load
    started = time.perf_counter()
    tables = {}
    for label, model in nets:
        model = model.float().eval()
        big = model.width * (model.depth + 1) > 256
        n_tight = (12 if big else 32) if quick else (48 if big else 128)
        rows = []
        for kind in ("1d segment", "3d box"):
            per_axis_ref = (1024 if kind == "1d segment" else (8 if quick else 12))
            per_axis_base = 64 if kind == "1d segment" else 8
            c_t, ax_t = _regions(kind, n_time, 0.01, g)
            with torch.no_grad():
                t_fwd = _timed(lambda: model(c_t), 5, min_time) / n_time
            regions = [_regions(kind, n_tight, h, g) for h in sizes]
            refs = [_dense_range(model, c, ax, per_axis_ref) for c, ax in regions]
            for method in methods:
                heavy = method in ("affine-full", "affine-truncate") and big
                nb = max(8, n_time // (16 if heavy else 1))
                t_box = _timed(lambda: range_bound(model, c_t[:nb], ax_t[:nb], method, keep=truncate_keep),
                               2 if (quick or heavy) else 3, min_time, warm=0.0 if heavy else 0.3) / nb
                ratios, signed = [], []
                for (c, ax), (rlo, rhi) in zip(regions, refs):
                    lo, hi = range_bound(model, c, ax, method, keep=truncate_keep)
                    if bool(((lo > rlo) | (hi < rhi)).any()):  # cannot happen: the bound must contain samples
                        raise RuntimeError(f"range bench: {method} bound misses sampled values on {label}")
                    true_w = (rhi - rlo).clamp_min(1e-12)
                    ratios.append(float(((hi - lo) / true_w).median()))
                    signed.append(float(((lo > 0) | (hi < 0)).float().mean()))
                row = {"region": kind, "method": method, "time ×fwd": t_box / t_fwd, "µs/box": t_box * 1e6}
                for h in shown:
                    row[f"w/true h={h:g}"] = ratios[sizes.index(h)]
                row["useful h (≤2×)"] = _largest(sizes, [r <= 2.0 for r in ratios])
                row["signed h (≥50%)"] = _largest(sizes, [f >= 0.5 for f in signed])
                row["guarantee"] = "yes"
                rows.append(row)
            # baseline: dense sampling of each box (what a user would do without range analysis)
            pts = _dense_points(c_t, ax_t, per_axis_base).reshape(-1, 3)
            with torch.no_grad():
                t_dense = _timed(lambda: model(pts), 2 if quick else 3, min_time) / n_time
            seen, signed = [], []
            for (c, ax), (rlo, rhi) in zip(regions, refs):
                blo, bhi = _dense_range(model, c, ax, per_axis_base)
                seen.append(float(((bhi - blo) / (rhi - rlo).clamp_min(1e-12)).median()))
                signed.append(float(((blo > 0) | (bhi < 0)).float().mean()))
            n_pts = per_axis_base ** (1 if kind == "1d segment" else 3)
            row = {"region": kind, "method": f"dense {n_pts} pts", "time ×fwd": t_dense / t_fwd,
                   "µs/box": t_dense * 1e6}
            for h in shown:
                row[f"w/true h={h:g}"] = seen[sizes.index(h)]
            row["useful h (≤2×)"] = "-"
            row["signed h (≥50%)"] = _largest(sizes, [f >= 0.5 for f in signed])
            row["guarantee"] = "no"
            rows.append(row)
        tables[label] = rows
    diff_nets = nets[:1] if quick else nets
    diff_methods = [m for m in methods if m != "affine-truncate"]
    for label, model in diff_nets:
        tables[f"difference_bound on {label}: h = f with weights perturbed by 0.1 %"] = _difference_rows(
            model, diff_methods, quick, g)
    notes = [
        "time ×fwd: wall time per region / plain float32 forward time per point (same model, same batch of "
        "centres); range analysis runs in float64 (see nets/range_analysis.py).",
        "w/true: median (bound width / true range width); true range by dense sampling "
        f"({1024} points per segment, {8 if quick else 12}^3 per box), so ratios are if anything overestimated; "
        "the dense baseline's value (< 1) is the fraction of the range its samples see.",
        "useful h: largest half-size with median ratio <= 2; signed h: largest half-size at which >= 50% of the "
        "regions are bounded away from 0 (Spelunking Table 1's length/volume measure, as a half-size).",
        f"affine-truncate keeps {truncate_keep} symbols per layer besides the input ones.",
        "difference tables: medians over regions of the certified sup|h - f| (max(-lo, hi)) with the input "
        "symbols shared (difference_bound) and without (range(h) - range(f)), against the sampled maximum "
        "(256 points per segment, 8^3 per box); this is the certificate behind a nesting threshold δ.",
        "Networks are randomly initialised SIRENs (a stand-in for trained ones) unless a model file is given.",
        f"Timed with {torch.get_num_threads()} torch thread(s); {load_note()}.",
        f"total bench time {time.perf_counter() - started:.1f} s",
    ]
    return {
        "name": "range",
        "title": "Range analysis: time and tightness per method (Spelunking Table 1 style)",
        "machine": machine_info(),
        "quick": quick,
        "tables": tables,
        "notes": notes,
    }

