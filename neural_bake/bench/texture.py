"""`neural-bake bench texture`: accuracy of the texture MLP against training time, with and without the
gradient-orthogonality term.

For each case (textured mesh) and setting (network preset, λ) the colour net is fitted within a time budget
and measured with :func:`texture_metrics`: surface PSNR/MSE against the texture, colour change across the
δ-band along the normals (read at the band's points, and as a bake reads it: at their closest points of
f = 0), and render-space MSE against ray-cast views of the ground-truth textured mesh (also read ±δ off the
surface). Each setting runs with the paper's λ (:data:`PAPER_LAM`); the comparison is λ = 0 — what the
presets train (bakes read g at the closest point of f = 0), and what the authors' public code trains (it
computes the orthogonality term but leaves it out of the loss) — fitted in the same run, so the band-change
ratio ``λ=0 / λ`` is measured on equal terms (same seed, budget and network).

The frozen f used here is the exact signed distance of the mesh itself (closest point by open3d, sign by
ray parity): the benchmark measures texture fitting alone, not the quality of a fitted SDF. Cases:

- ``sphere``: the lat-long colour sphere (the bundled sample when present, else generated here);
- ``torus``: the bundled torus sample (checker/stripe texture) when present;
- ``checker<k>``: the generated lat-long sphere with a k × k/2 checkerboard texture (high frequency: the PSNR ceiling
  that a given network reaches in the budget, reported rather than hidden);
- ``spot``: ``spot/`` of the data folder (textured cow) when present.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from ..geometry import import_open3d, raycasting_scene
from ..errors import NeuralBakeError
from ..types import Mesh
from .common import data_file, load_note, machine_info, timeit

__all__ = ["run", "default_settings", "latlong_sphere", "mesh_sdf", "SPOT", "PAPER_LAM"]

#: λ of the settings measured against λ = 0: the orthogonality term's weight that keeps the band constant.
PAPER_LAM = 1e-3

#: The textured Spot mesh of the shared data (used when present).
SPOT = data_file("spot/spot_triangulated.obj")


def latlong_sphere(n_lat: int = 48, n_lon: int = 96, tex_hw: tuple[int, int] = (256, 512), radius: float = 0.9,
                   checker: int | None = None) -> Mesh:
    """A lat-long UV sphere (unit frame, seam at u = 0/1 with duplicated vertices) and its texture.

    The texture is a smooth colour field periodic in u (``checker=None``) or a ``checker`` × ``checker``/2
    black-and-white checkerboard (linear RGB 0.05 / 0.9). Shapes as in :class:`Mesh`.
    """
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    V = radius * np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    UV = np.stack([P / (2 * np.pi), 1 - T / np.pi], -1).reshape(-1, 2)
    idx = np.arange((n_lat + 1) * (n_lon + 1)).reshape(n_lat + 1, n_lon + 1)
    i, j = np.meshgrid(np.arange(n_lat), np.arange(n_lon), indexing="ij")
    a, b, c, d = idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]
    upper = np.stack([a, b, d], -1)[1:].reshape(-1, 3)
    lower = np.stack([b, c, d], -1)[:-1].reshape(-1, 3)
    F = np.concatenate([upper, lower]).astype(np.int64)
    h, w = tex_hw
    U, Vv = np.meshgrid((np.arange(w) + 0.5) / w, 1 - (np.arange(h) + 0.5) / h)
    if checker:
        cells = (np.floor(U * checker) + np.floor(Vv * checker / 2)) % 2
        tex = np.repeat((0.05 + 0.85 * cells)[..., None], 3, axis=2).astype(np.float32)
    else:
        tex = np.stack([0.5 + 0.35 * np.sin(2 * np.pi * U) * np.sin(np.pi * Vv),
                        0.5 + 0.35 * np.cos(np.pi * Vv),
                        0.45 + 0.3 * np.cos(4 * np.pi * U) * np.sin(np.pi * Vv) ** 2], -1).astype(np.float32)
    vn = V / np.linalg.norm(V, axis=1, keepdims=True)
    return Mesh(vertices=V, faces=F, uv=UV[F], texture=tex, vertex_normals=vn, watertight=False,
                source="<lat-long sphere>" if not checker else f"<checker {checker} sphere>")


def mesh_sdf(mesh: Mesh):
    """The exact signed distance of ``mesh`` as an SDF callable: points (N, 3) -> (values (N,), grads (N, 3)).

    Distance to the closest point q (open3d), sign by ray parity; the gradient is sign·(p − q)/|p − q|, or the
    closest face's normal within 1e-5 of the surface. Unit frame, float tensors in and out (CPU).
    """
    o3d = import_open3d()

    scene = raycasting_scene(mesh.vertices, mesh.faces)

    def f(x: torch.Tensor):
        p = x.detach().cpu().numpy().astype(np.float32)
        q = o3d.core.Tensor(p)
        cp = scene.compute_closest_points(q)
        sd = scene.compute_signed_distance(q).numpy().astype(np.float64)
        d = p.astype(np.float64) - cp["points"].numpy()
        dist = np.linalg.norm(d, axis=1, keepdims=True)
        face_n = cp["primitive_normals"].numpy().astype(np.float64)
        sign = np.where(sd < 0, -1.0, 1.0)[:, None]
        grad = np.where(dist > 1e-5, sign * d / np.maximum(dist, 1e-12), face_n)
        return torch.as_tensor(sd, dtype=x.dtype), torch.as_tensor(grad, dtype=x.dtype)

    return f


def _cases(names, quick: bool) -> dict[str, Mesh]:
    out = {}
    for name in names:
        if name == "sphere":
            out[name] = _bundled("sphere") or latlong_sphere(24 if quick else 48, 48 if quick else 96)
        elif name == "torus":
            m = _bundled("torus")
            if m is not None:
                out[name] = m
        elif name.startswith("checker"):
            digits = name[len("checker"):] or "16"
            if not digits.isdigit() or int(digits) < 1:
                raise NeuralBakeError(f"--case: {name!r} needs a positive cell count, e.g. checker16")
            k = int(digits)
            out[name] = latlong_sphere(24 if quick else 48, 48 if quick else 96, (256, 512), checker=k)
        elif name == "spot":
            if SPOT.is_file():
                from ..io.mesh_io import load_mesh

                tex = SPOT.parent / "spot_texture.png"
                out[name] = load_mesh(SPOT, tex if tex.is_file() else None)
        else:
            raise NeuralBakeError(f"--case: unknown case {name!r} (choose sphere, torus, checker<k>, spot)")
    return out


def _bundled(name: str) -> Mesh | None:
    """The bundled sample mesh ``name`` loaded with load_mesh, or None when samples/load_mesh are missing."""
    try:
        from ..io.mesh_io import load_mesh
        from ..samples import sample_path

        p = Path(sample_path(name))
        return load_mesh(p) if p.is_file() else None
    except (ImportError, AttributeError, FileNotFoundError):
        return None


def _step_times(quick: bool) -> list[dict]:
    """Seconds per training step's orthogonality term: GEMM Jacobian vs one directional stream."""
    from ..fit.texture import band_orthogonality
    from ..nets.siren import Siren

    rows = []
    n = 1024 if quick else 4096
    nets = [(64, 1)] if quick else [(64, 1), (128, 2), (256, 3)]
    for w, d in nets:
        net = Siren(w, d, 3, 3, generator=torch.Generator().manual_seed(0))
        x = torch.rand(n, 3) * 2 - 1
        nrm = torch.nn.functional.normalize(torch.randn(n, 3), dim=1)

        def colour_only():
            net.zero_grad()
            (net(x) ** 2).mean().backward()

        def term(method):
            def fn():
                net.zero_grad()
                band_orthogonality(net, x, nrm, method=method).mean().backward()
            return fn

        base = timeit(colour_only, repeat=3)
        jac = timeit(term("jacobian"), repeat=3)
        dirn = timeit(term("directional"), repeat=3)
        rows.append({"net": f"({w},{d})", "points": n, "colour_fwd_bwd_s": base, "orth_jacobian_s": jac,
                     "orth_directional_s": dirn, "jacobian/colour": jac / base, "jacobian/directional": jac / dirn})
    return rows


def _grid_times(quick: bool) -> list[dict]:
    """The `default` preset's feature grid (with normal inputs): seconds to encode and evaluate points, and a
    training step, with the grid's C kernel and with torch's encoding (the baseline), Adam fused and torch's
    default; "kernel" says which encoding the first ran."""
    from dataclasses import replace

    from ..fit.texture import PRESETS, TextureFitConfig, make_texture_network
    from ..fit.training import adam_options
    from ..nets import grid

    cfg = replace(TextureFitConfig(), **PRESETS["default"])
    net = make_texture_network(cfg, torch.Generator().manual_seed(0), open_mesh=True)
    gen = torch.Generator().manual_seed(1)
    n_eval, n_step = (8192, 1024) if quick else (65536, int(cfg.batch))
    x = torch.rand(n_eval, 6, generator=gen) * 2 - 1
    x[:, 3:] = torch.nn.functional.normalize(x[:, 3:], dim=1)
    xb, yb = x[:n_step], torch.rand(n_step, 3, generator=gen)

    def evaluate(native):
        def fn():
            with torch.no_grad():
                feats = net.encode(x[:, :3]) if native else net._encode_torch(x[:, :3])
                net._mlp(net._mlp_input(feats, x))
        return fn

    def step(native, opt):
        def fn():
            opt.zero_grad()
            feats = net.encode(xb[:, :3]) if native else net._encode_torch(xb[:, :3])
            ((net._mlp(net._mlp_input(feats, xb)) - yb) ** 2).mean().backward()
            opt.step()
        return fn

    params = list(net.parameters())
    fused = torch.optim.Adam(params, lr=1e-3, **adam_options(params))
    plain = torch.optim.Adam(params, lr=1e-3)
    kernel = grid.KERNEL.lib() is not None
    ev_k, ev_t = timeit(evaluate(kernel), repeat=3), timeit(evaluate(False), repeat=3)
    st_k, st_t = timeit(step(kernel, fused), repeat=5), timeit(step(False, plain), repeat=5)
    return [{"grid": f"{cfg.grid_levels}x{cfg.grid_features} 2^{cfg.grid_log2_table} "
                     f"{cfg.grid_base_resolution}–{cfg.grid_max_resolution}, ({cfg.width},{cfg.depth}), normals",
             "kernel": grid.kernel_status(), "adam": "fused" if adam_options(params) else "default",
             "eval_points": n_eval, "eval_s": ev_k, "eval_torch_s": ev_t, "eval_torch/kernel": ev_t / ev_k,
             "step_points": n_step, "step_s": st_k, "step_torch_s": st_t, "step_torch/kernel": st_t / st_k,
             "threads": torch.get_num_threads()}]


def _row(name, label, fit, m, total_s, baseline):
    return {"case": name, "setting": label, "net": f"({fit.config.width},{fit.config.depth})", "lam": fit.lam,
            "baseline": baseline, "steps": fit.steps, "train_s": round(fit.seconds, 1),
            "total_s": round(total_s, 1), "psnr_db": m["surface_psnr"], "mse": m["surface_mse"],
            "texel_psnr_db": m["texel_psnr"], "texel_psnr_srgb_db": m["texel_psnr_srgb"],
            "band_change": m["band_change"], "band_change_at_delta": m["band_change_at_delta"],
            "band_change_read": m["band_change_read"], "band_ratio": None, "render_mse": m["render_mse"],
            "render_mse_band": m["render_mse_band"]}


def default_settings(quick: bool, presets=None, lam: float = PAPER_LAM) -> list[dict]:
    """The benchmark's settings: quick, a (64, 1) net for 9 s; else the presets quick and default on every
    case and high on sphere and Spot (about an hour). ``presets`` keeps only those presets (shared names or
    the earlier fast, medium, fine), each on every case; NeuralBakeError for an unknown name."""
    from ..fit.presets import PRESET_NAMES, TEXTURE_ALIASES

    wanted = None if not presets else [TEXTURE_ALIASES.get(p, p) for p in presets]
    unknown = [p for p in wanted or () if p not in PRESET_NAMES]
    if unknown:
        raise NeuralBakeError(f"--preset: unknown preset {unknown[0]!r} (choose {', '.join(PRESET_NAMES)})")
    if quick:
        return [{"label": "(64,1) 9s", "width": 64, "depth": 1, "minutes": 0.15, "steps": 100000,
                 "batch": 1024, "lr": 5e-4, "pool": 50000, "lam": lam}]
    settings = [{"label": "quick", "preset": "quick", "lam": lam},
                {"label": "default", "preset": "default", "lam": lam, "equal_time": False},
                {"label": "high", "preset": "high", "lam": lam, "equal_time": False, "only": ["sphere", "spot"]}]
    if wanted is None:
        return settings
    return [{k: v for k, v in s.items() if k != "only"} for s in settings if s["label"] in wanted]


def run(quick: bool = False, *, cases=None, settings=None, presets=None, seed: int = 0,
        delta: float | None = None, progress: bool = False) -> dict:
    """Fit and measure texture nets; returns the benchmark dict (see the module docstring).

    - ``cases``: names among "sphere", "torus", "checker<k>", "spot" (default: all four with checker16;
      quick: sphere and checker16).
    - ``settings``: list of dicts of :class:`TextureFitConfig` overrides with a "label" and λ > 0, plus
      optional "equal_time" (bool, default True) and "only" (case names); default :func:`default_settings`.
      Each setting runs with its λ in its budget, then the λ = 0 baseline for the same number of steps
      ("equal steps") and, if "equal_time", for the same time budget. ``band_ratio`` = the equal-steps
      baseline's band change / this λ's.
    - ``presets``: keep only these presets of :func:`default_settings` (not with ``quick``).
    """
    from ..fit.texture import DEFAULT_DELTA, fit_texture, texture_metrics

    if cases is None:
        cases = ["sphere", "checker16"] if quick else ["sphere", "torus", "checker16", "spot"]
    if settings is None:
        settings = default_settings(quick, presets)
    delta = DEFAULT_DELTA if delta is None else float(delta)
    metric_opts = {"n": 4000, "n_views": 2, "resolution": 48} if quick else {"n": 50000, "n_views": 8,
                                                                            "resolution": 256}
    meshes = _cases(cases, quick)
    rows, notes = [], []
    for name in cases:
        if name not in meshes:
            notes.append(f"case {name!r} skipped: {SPOT} not found" if name == "spot"
                         else f"case {name!r} skipped: bundled sample not found")
            continue
        mesh = meshes[name]
        sdf = mesh_sdf(mesh)
        for s in settings:
            s = dict(s)
            label = s.pop("label", "")
            equal_time = s.pop("equal_time", True)
            only = s.pop("only", None)
            if only is not None and name not in only:
                continue

            def one(**over):
                t0 = time.perf_counter()
                fit = fit_texture(mesh, sdf, seed=seed, delta=delta, progress=progress, **dict(s, **over))
                m = texture_metrics(fit.field(), mesh, sdf, delta=delta, seed=seed + 1, **metric_opts)
                return fit, m, time.perf_counter() - t0

            fit, m, t = one()
            main = _row(name, label, fit, m, t, "")
            rows.append(main)
            if fit.lam > 0:
                fit0, m0, t0 = one(lam=0.0, steps=fit.steps, minutes=None)
                rows.append(_row(name, label, fit0, m0, t0, "λ=0 equal steps"))
                if m0["band_change"] and m["band_change"]:
                    main["band_ratio"] = m0["band_change"] / m["band_change"]
                if equal_time:
                    fit1, m1, t1 = one(lam=0.0)
                    rows.append(_row(name, label, fit1, m1, t1, "λ=0 equal time"))
    notes += [
        "psnr_db / mse: surface samples vs the texture (linear RGB, peak 1); texel_psnr_db (_srgb_db): at samples "
        "drawn by UV area, each texel once (sRGB-encoded: what an 8-bit map shows); band_change: mean |g(p±t·n) − g(p)| "
        f"for t in δ/4..δ, δ = {delta:g} (unit frame); band_change_read: the same read where a bake reads g, at "
        "the closest point of f = 0 (the presets: λ = 0, read there); band_ratio: band change of the λ=0 run "
        "with the same steps (same seed, network, this run) / this row's. Target: ≥ 2 at about equal psnr_db.",
        "render_mse: mean over ray-cast views of the ground-truth mesh of the per-view MSE between the texture "
        "at the hit point and g there (hit pixels only); render_mse_band: g read ±δ along ∇f (a coarse surface).",
        "f is the mesh's exact signed distance (closest point), so this measures the texture fit alone.",
        "checker<k>: a hard-edged high-frequency texture; its psnr_db is the ceiling of that network in that "
        "budget, not a bug.",
        load_note(),
    ]
    return {"name": "texture", "title": "Gradient-orthogonal neural texture: accuracy vs training time",
            "machine": machine_info(), "quick": quick, "delta": delta,
            "tables": {"accuracy": rows, "orthogonality term cost per step": _step_times(quick),
                       "feature grid: C kernel against torch's encoding": _grid_times(quick)},
            "notes": notes}
