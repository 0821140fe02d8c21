"""The preview renderer: primary rays, then only the effects the scene calls for, with evaluation counters.

Plan of a render (each step evaluates networks only where the scene asks for it, only at the pixels that
need it, and counts it under its effect in :class:`~neural_bake.render.stats.EvalCounter`):

1. ``trace``: primary rays of every object, in its unit frame (empty-space skipping, Algorithm 1 or the
   guaranteed caster, LOD); nearest hit wins. A pixel that misses evaluates nothing after the miss.
2. ``normals`` (for shading, the normal channel, shadows or AO): GEMM normals of the last traced level at
   the hits; with ``normal_mapping`` instead those of ``scene.normal_level`` (the fine f by default:
   neural normal mapping, §4.1), counted under ``normal_mapping``.
3. ``texture``: the texture field at the hits (neural texture mapping, §4.2); with ``normal_mapping``, at
   the hits' closest points of the mapped level's zero set (p − f(p)·∇f(p), |f| clamped to the texture's δ).
   A colour field with normal inputs also reads the hits' unit normals (step 2's ∇f).
4. ``shadows``: one shadow ray per hit and light, traced against every object.
5. ``ambient_occlusion``: SDF samples along the normal of the last traced level.
6. ``hole_map``: the guaranteed caster on f along the rays sphere tracing missed: pixels where it finds a
   surface are holes (a δ too small, or a network that is not a distance bound).

Cameras, lights and outputs are in the source (scene) frame; each object's rays are moved into its model's
unit frame (its transform, then its frame), and distances and normals are moved back.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..constants import GRAD_EPS, UNIT_FRAME_EXTENT
from ..limits import check_image_size
from .asset import RenderAsset, RenderError
from .camera import Camera
from .guaranteed import cast_guaranteed
from .scene import Scene, Transform
from .shading import default_lights, light_samples, shade_blinn_phong, shade_matcap
from .skip import occupancy_for
from .stats import EvalCounter
from .trace import TraceSettings, lod_weights, trace_rays

__all__ = ["RenderResult", "render", "default_camera", "scene_camera", "object_bounds"]


@dataclass
class RenderResult:
    """Channels as (H, W[, C]) numpy arrays, row 0 on top:

    - ``color``: float32 (H, W, 3) linear RGB (background where missed);
    - ``depth``: float32 (H, W) distance from the eye to the hit along the pixel's ray, source units (inf
      where missed);
    - ``normal``: float32 (H, W, 3) unit normals, source frame (0 where missed or invalid);
    - ``hit``: bool (H, W); ``iterations``: int32 (H, W) tracing evaluations per pixel (all objects);
    - ``holes``: bool (H, W) the hole map; ``lod``: float32 (H, W) continuous level (−1 where missed).

    Only the channels asked for (and ``hit``) are present. ``stats``: the evaluation counters
    (:meth:`EvalCounter.to_dict`), seconds per phase, pixel counts and skipping figures.
    """

    channels: dict[str, np.ndarray]
    stats: dict
    camera: Camera
    counter: EvalCounter = field(repr=False, default_factory=EvalCounter)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.channels[name]


def object_bounds(asset: RenderAsset, transform: Transform | None = None, grid=None) -> tuple[np.ndarray, np.ndarray]:
    """Scene-frame box (lo, hi) holding the object: the occupied cells of its skipping ``grid`` when given
    (the box of its coarsest band), else its unit frame's normalised box; mapped back to the scene."""
    e = UNIT_FRAME_EXTENT / 2
    lo_u, hi_u = np.full(3, -e), np.full(3, e)
    if grid is not None and bool(grid.occupied.any()):
        idx = grid.occupied.nonzero().numpy()
        cell = 2 * grid.bound / grid.resolution
        lo_u = -grid.bound + idx.min(axis=0) * cell
        hi_u = -grid.bound + (idx.max(axis=0) + 1) * cell
    corners = np.array([[x, y, z] for x in (lo_u[0], hi_u[0]) for y in (lo_u[1], hi_u[1])
                        for z in (lo_u[2], hi_u[2])], dtype=np.float64)
    src = asset.frame.to_source(corners)
    if transform is not None and not transform.is_identity():
        src = (transform.rotation() @ (transform.scale * src).T).T + np.asarray(transform.translate)
    return src.min(axis=0), src.max(axis=0)


def default_camera(assets, transforms=None, *, width: int = 256, height: int = 256, fov_deg: float = 40.0,
                   grids=None) -> Camera:
    """A camera that frames every object (by its skipping grid's occupied box where ``grids`` has one),
    looking from the front (+Z), a little from above and the right."""
    transforms = transforms or [None] * len(assets)
    grids = grids or [None] * len(assets)
    boxes = [object_bounds(a, t, g) for a, t, g in zip(assets, transforms, grids)]
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    return Camera.framing(lo, hi, direction=(0.35, 0.3, 1.0), fov_deg=fov_deg, width=width, height=height,
                          margin=1.05)


class _Object:
    """One object's rays in its unit frame and the factors back to the scene frame."""

    def __init__(self, asset: RenderAsset, transform: Transform | None, o_w: torch.Tensor, d_w: torch.Tensor):
        self.asset = asset
        self.transform = transform or Transform()
        dt, dev = o_w.dtype, o_w.device
        self.rot = torch.as_tensor(self.transform.rotation(), dtype=dt, device=dev)
        self.k = float(asset.frame.scale) * self.transform.scale  # unit-frame length of one scene unit
        self.o, self.d = self.to_unit_rays(o_w, d_w)

    def to_unit_rays(self, o_w: torch.Tensor, d_w: torch.Tensor):
        tr = self.transform
        trans = torch.as_tensor(tr.translate, dtype=o_w.dtype, device=o_w.device)
        o_src = ((o_w - trans) @ self.rot) / tr.scale  # R^T (o - T) / s, rows
        d_u = d_w @ self.rot
        center = torch.as_tensor(self.asset.frame.center, dtype=o_w.dtype, device=o_w.device)
        return (o_src - center) * float(self.asset.frame.scale), d_u

    def normal_to_scene(self, n_u: torch.Tensor) -> torch.Tensor:
        return n_u @ self.rot.T


def _plan_check(assets, scene: Scene) -> None:
    for i, a in enumerate(assets):
        k = len(a.levels)
        scene.trace.iterations_for(k)
        if "normal_mapping" in scene.effects and not -k <= scene.normal_level < k:
            raise RenderError(f"normal_level {scene.normal_level}: object {i} has {k} levels")
        if "texture" in scene.effects and a.texture is None:
            raise RenderError(f"effects: 'texture' asked for, but object {i} has no texture field")
        if scene.guaranteed and a.levels[-1].bound is None:
            raise RenderError(f"guaranteed: object {i}'s fine level {a.levels[-1].name} has no range bound")


def render(assets, scene: Scene | None = None, *, camera: Camera | None = None, size: tuple[int, int] | None = None,
           fov_deg: float | None = None, device=None, dtype=torch.float32, cache_dir=None) -> RenderResult:
    """Render one or more :class:`RenderAsset` (one per ``scene.objects`` entry when it has any, placed by
    their transforms; identity otherwise) with ``scene`` (default :class:`Scene`).

    ``camera`` overrides the scene's; without either, :func:`default_camera` frames the objects (by their
    skipping grids when skipping is on), ``size`` (width, height) and ``fov_deg`` setting its image (default
    256², 40°); both are ignored when a camera is given. ``cache_dir``: a folder keeping the skipping grids
    between processes (in memory only by default).
    Raises RenderError (one line) for a scene the assets cannot satisfy (texture without a texture field,
    iteration counts that do not match the levels, a normal level out of range…).
    """
    scene = scene or Scene()
    if size is not None and camera is None:
        check_image_size(*size, error=RenderError)
    assets = [assets] if isinstance(assets, RenderAsset) else list(assets)
    if not assets:
        raise RenderError("render: no object to draw")
    transforms = [o.transform for o in scene.objects] if scene.objects else [None] * len(assets)
    if len(transforms) != len(assets):
        raise RenderError(f"render: {len(assets)} assets for {len(transforms)} scene objects")
    _plan_check(assets, scene)
    counter = EvalCounter()
    grids = [_grid(a, scene, counter, dtype, device, cache_dir) for a in assets]
    cam = camera or scene_camera(assets, scene, size=size, fov_deg=fov_deg, grids=[g for g, _, _ in grids])
    seconds: dict[str, float] = {}
    t_start = time.perf_counter()
    o_w, d_w = cam.rays(device=device, dtype=dtype)
    n = o_w.shape[0]
    threads = _choose_threads(assets, o_w)
    pixel_angle = 2 * math.tan(math.radians(cam.fov_deg) / 2) / cam.height
    objs = [_Object(a, t, o_w, d_w) for a, t in zip(assets, transforms)]
    settings = scene.trace

    # 1. primary rays
    tic = time.perf_counter()
    t_scene = torch.full((n,), math.inf, dtype=dtype, device=o_w.device)
    winner = torch.full((n,), -1, dtype=torch.long, device=o_w.device)
    iterations = torch.zeros(n, dtype=torch.int32, device=o_w.device)
    per_obj = []
    skip_info = []
    for i, ob in enumerate(objs):
        far_u = None if scene.far is None else torch.full((n,), scene.far * ob.k, dtype=dtype, device=o_w.device)
        near_u, far_skip, info = _skip_interval(ob, grids[i])
        skip_info.append(info)
        if far_skip is not None:
            far_u = far_skip if far_u is None else torch.minimum(far_u, far_skip)
        if scene.guaranteed:
            hit, t_u, its = cast_guaranteed(ob.asset.levels[-1], ob.o, ob.d, counter, bound=settings.bound,
                                            t_near=near_u, t_far=far_u, effect="trace")
            lod = torch.full((n,), float(len(ob.asset.levels) - 1), dtype=dtype, device=o_w.device)
        else:
            res = trace_rays(ob.asset.levels, ob.o, ob.d, settings, counter, t_near=near_u, t_far=far_u,
                             pixel_angle=pixel_angle)
            hit, t_u, its, lod = res.hit, res.t, res.iterations, res.lod
        iterations += its
        t_w = torch.where(hit, t_u / ob.k, torch.full_like(t_u, math.inf))
        closer = hit & (t_w < t_scene)
        t_scene = torch.where(closer, t_w, t_scene)
        winner = torch.where(closer, torch.full_like(winner, i), winner)
        per_obj.append((t_u, lod))
    hit_any = winner >= 0
    seconds["trace"] = time.perf_counter() - tic

    want = set(scene.channels) | {"hit"}
    effects = set(scene.effects)
    need_color = "color" in want
    need_normals = bool({"shading", "shadows", "ambient_occlusion"} & effects) or "normal" in want or (
        need_color and {"texture", "normal_mapping"} <= effects)  # the texture is read at the mapped point
    if need_color and "texture" in effects:  # a colour field with normal inputs reads ∇f's at the hits
        need_normals = need_normals or any(getattr(ob.asset.texture, "normal_inputs", False) for ob in objs)

    color = torch.empty((n, 3), dtype=dtype, device=o_w.device)
    color[:] = torch.as_tensor(scene.background, dtype=dtype, device=o_w.device)
    normals_w = torch.zeros((n, 3), dtype=dtype, device=o_w.device)
    lods = torch.full((n,), -1.0, dtype=dtype, device=o_w.device)
    lights = list(scene.lights) or default_lights(cam)
    for i, ob in enumerate(objs):
        pix = (winner == i).nonzero().squeeze(1)
        if pix.numel() == 0:
            continue
        t_u, lod = per_obj[i]
        lods[pix] = lod[pix]
        p_u = ob.o[pix] + t_u[pix, None] * ob.d[pix]
        levels = ob.asset.levels
        its = settings.iterations_for(len(levels))
        last = max(j for j, k in enumerate(its) if k > 0) if not scene.guaranteed else len(levels) - 1
        n_u = v_nm = None
        if need_normals:  # 2. normals
            tic = time.perf_counter()
            if "normal_mapping" in effects:
                v_nm, g = counter.value_and_gradient(levels[scene.normal_level], "normal_mapping", p_u)
            elif settings.lod is not None and len(levels) > 1 and not scene.guaranteed:
                g = _blended_gradient(levels, lod[pix], counter, p_u)
            else:
                _, g = counter.value_and_gradient(levels[last], "normals", p_u)
            norm = g.norm(dim=1, keepdim=True)
            ok = torch.isfinite(norm) & (norm > GRAD_EPS)
            n_u = torch.where(ok, g / torch.where(ok, norm, torch.ones_like(norm)), torch.zeros_like(g))
            normals_w[pix] = ob.normal_to_scene(n_u)
            seconds["normals"] = seconds.get("normals", 0.0) + time.perf_counter() - tic
        if not need_color:
            continue
        albedo = torch.as_tensor(scene.material.albedo, dtype=dtype, device=o_w.device).expand(pix.numel(), 3)
        if "texture" in effects:  # 3. texture
            tic = time.perf_counter()
            p_t = p_u
            if v_nm is not None:  # the colour of the mapped level's closest point, p − f(p)·∇f(p) (§4.2)
                from ..fields import closest_surface_points

                p_t = closest_surface_points(p_u, v_nm, n_u, ok, ob.asset.texture.delta)
            albedo = counter.color(ob.asset.texture, "texture", p_t, n_u).to(dtype)
            seconds["texture"] = seconds.get("texture", 0.0) + time.perf_counter() - tic
        if "shading" not in effects:
            color[pix] = albedo
            continue
        p_w = o_w[pix] + t_scene[pix, None] * d_w[pix]
        visibility = None
        if "shadows" in effects:  # 4. shadows
            tic = time.perf_counter()
            visibility = _shadows(objs, ob, pix, p_w, normals_w[pix], lights, scene, counter, dtype)
            seconds["shadows"] = seconds.get("shadows", 0.0) + time.perf_counter() - tic
        ao = None
        if "ambient_occlusion" in effects:  # 5. ambient occlusion
            tic = time.perf_counter()
            ao = _ambient_occlusion(levels[last], last == len(levels) - 1, p_u, n_u, scene, counter)
            seconds["ambient_occlusion"] = seconds.get("ambient_occlusion", 0.0) + time.perf_counter() - tic
        if scene.material.kind == "matcap":
            rgb = shade_matcap(normals_w[pix], cam)
            if "texture" in effects:  # the texture tinted by the matcap's grey level
                rgb = albedo * rgb.mean(dim=1, keepdim=True)
            if ao is not None:
                rgb = rgb * ao[:, None]
            if visibility is not None:
                rgb = rgb * (0.5 + 0.5 * torch.stack(visibility).mean(0))[:, None]
        else:
            rgb = shade_blinn_phong(normals_w[pix], p_w, d_w[pix], albedo, lights, scene.material,
                                    visibility=visibility, ambient_occlusion=ao)
        color[pix] = torch.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0)

    holes = None
    if "hole_map" in effects or "holes" in want:  # 6. hole map
        tic = time.perf_counter()
        holes = torch.zeros(n, dtype=torch.bool, device=o_w.device)
        if not scene.guaranteed:
            missed = (~hit_any).nonzero().squeeze(1)
            for ob in objs:
                if ob.asset.levels[-1].bound is None:
                    raise RenderError(f"hole map: the fine level {ob.asset.levels[-1].name} has no range bound")
                far_u = None if scene.far is None else torch.full((missed.numel(),), scene.far * ob.k,
                                                                   dtype=dtype, device=o_w.device)
                h, _, _ = cast_guaranteed(ob.asset.levels[-1], ob.o[missed], ob.d[missed], counter,
                                          bound=settings.bound, t_far=far_u, effect="hole_map")
                holes[missed[h]] = True
        seconds["hole_map"] = time.perf_counter() - tic
    seconds["total"] = time.perf_counter() - t_start

    hh, ww = cam.height, cam.width
    channels: dict[str, np.ndarray] = {"hit": hit_any.reshape(hh, ww).cpu().numpy()}
    if "color" in want:
        channels["color"] = color.reshape(hh, ww, 3).float().cpu().numpy()
    if "depth" in want:
        channels["depth"] = t_scene.reshape(hh, ww).float().cpu().numpy()
    if "normal" in want:
        channels["normal"] = normals_w.reshape(hh, ww, 3).float().cpu().numpy()
    if "iterations" in want:
        channels["iterations"] = iterations.reshape(hh, ww).cpu().numpy()
    if "lod" in want:
        channels["lod"] = lods.reshape(hh, ww).float().cpu().numpy()
    if holes is not None:
        channels["holes"] = holes.reshape(hh, ww).cpu().numpy()
    stats = {
        "evaluations": counter.to_dict(),
        "seconds": {k: round(v, 6) for k, v in seconds.items()},
        "pixels": {"total": int(n), "hit": int(hit_any.sum()),
                   "holes": int(holes.sum()) if holes is not None else None},
        "trace_iterations": int(iterations.sum()),
        "skip": skip_info,
        "effects": list(scene.effects),
        "channels": list(scene.channels),
        "camera": cam.to_dict(),
        "mode": "guaranteed" if scene.guaranteed else settings.mode,
        "threads": threads.as_dict(),
    }
    return RenderResult(channels, stats, cam, counter)


def _choose_threads(assets, origins: torch.Tensor):
    """The CPU threads the render's evaluations run fastest with on the machine as it is
    (:func:`~neural_bake.nets.threads.choose_threads`), probed on the finest level's values and gradients at
    points spread over the unit cube (not counted as the render's evaluations)."""
    from ..nets.threads import choose_threads

    gen = torch.Generator().manual_seed(0)
    points = (torch.rand(2048, 3, generator=gen) * 1.8 - 0.9).to(device=origins.device, dtype=origins.dtype)
    finest = assets[0].levels[-1]
    return choose_threads(lambda: finest.value_and_gradient(points), device=origins.device)


def scene_camera(assets, scene: Scene, *, size: tuple[int, int] | None = None, fov_deg: float | None = None,
                 grids=None, device=None, dtype=torch.float32, cache_dir=None) -> Camera:
    """The camera :func:`render` uses for ``assets`` (a list, one per scene object) and ``scene``: the scene's,
    else :func:`default_camera` framing the objects by their skipping grids (built here when ``grids`` is
    None), of ``size`` (default 256²) and ``fov_deg`` (default 40°)."""
    if scene.camera is not None:
        return scene.camera
    if size is not None:
        check_image_size(*size, error=RenderError)
    transforms = [o.transform for o in scene.objects] if scene.objects else [None] * len(assets)
    if grids is None:
        grids = [_grid(a, scene, EvalCounter(), dtype, device, cache_dir)[0] for a in assets]
    w, h = size or (256, 256)
    return default_camera(assets, transforms, width=w, height=h, fov_deg=40.0 if fov_deg is None else fov_deg,
                          grids=grids)


def _grid(asset: RenderAsset, scene: Scene, counter: EvalCounter, dtype, device, cache_dir=None):
    """(grid, built_now, seconds) of the asset's coarsest level, or (None, False, 0) without skipping."""
    level = asset.levels[0]
    if not scene.skip or level.bound is None:
        return None, False, 0.0
    tic = time.perf_counter()
    grid, built = occupancy_for(level, counter, depth=scene.skip_depth, bound=scene.trace.bound, dtype=dtype,
                                device=device, cache_dir=cache_dir)
    return grid, built, time.perf_counter() - tic


def _skip_interval(ob: _Object, grid_info):
    """(t_near, t_far, info) of the rays from the object's occupancy grid, or (None, None, info) without one."""
    grid, built, build_s = grid_info
    if grid is None:
        return None, None, {"used": False}
    if bool(grid.occupied.all()):  # nothing proven empty: sampling the rays would only cost time
        return None, None, {"used": False, "built_now": built, "build_seconds": round(build_s, 6) if built else 0.0,
                            "occupied_fraction": 1.0, "boxes": grid.boxes, "rays_skipped_entirely": 0}
    start, end = grid.ray_interval(ob.o, ob.d)
    return start, end, {"used": True, "built_now": built, "build_seconds": round(build_s, 6) if built else 0.0,
                        "occupied_fraction": round(grid.fraction(), 6), "boxes": grid.boxes,
                        "rays_skipped_entirely": int((end < start).sum())}


def _blended_gradient(levels, lod: torch.Tensor, counter: EvalCounter, p_u: torch.Tensor) -> torch.Tensor:
    w = lod_weights(lod, len(levels))
    g = torch.zeros_like(p_u)
    for j in range(len(levels)):
        sel = (w[:, j] > 0).nonzero().squeeze(1)
        if sel.numel():
            _, gj = counter.value_and_gradient(levels[j], "normals", p_u[sel])
            g.index_add_(0, sel, w[sel, j, None] * gj)
    return g


def _shadows(objs, ob, pix, p_w, n_w, lights, scene: Scene, counter: EvalCounter, dtype) -> list[torch.Tensor]:
    """Per light, visibility (P,) in {0, 1} of the hit points ``p_w`` (scene frame) against every object."""
    start = p_w + n_w * (scene.shadow_bias / ob.k)
    settings = TraceSettings(mode="threshold", iterations=scene.trace.iterations, epsilon=scene.trace.epsilon,
                             hit_tolerance=scene.trace.hit_tolerance, chunk=scene.trace.chunk,
                             bound=scene.trace.bound)
    out = []
    for l_dir, _, dist in light_samples(lights, p_w):
        vis = torch.ones(p_w.shape[0], dtype=dtype, device=p_w.device)
        for other in objs:
            o_u, d_u = other.to_unit_rays(start, l_dir.contiguous())
            far = None if not torch.isfinite(dist).any() else torch.where(
                torch.isfinite(dist), dist * other.k, torch.full_like(dist, math.inf))
            near = None
            level0 = other.asset.levels[0]
            if scene.skip and level0.bound is not None:
                grid, _ = occupancy_for(level0, counter, depth=scene.skip_depth, bound=settings.bound, dtype=dtype,
                                        device=p_w.device)
                near, f2 = grid.ray_interval(o_u, d_u)
                far = f2 if far is None else torch.minimum(far, f2)
            res = trace_rays(other.asset.levels, o_u, d_u, settings, counter, t_near=near, t_far=far,
                             effect="shadows")
            vis = torch.where(res.hit, torch.zeros_like(vis), vis)
        out.append(vis)
    return out


def _ambient_occlusion(level, is_fine: bool, p_u, n_u, scene: Scene, counter: EvalCounter) -> torch.Tensor:
    """(P,) in [0, 1]: 1 − strength · Σ_i w_i (d_i − g(p + d_i n)) / d_i, w_i = 2^-i / Σ 2^-i, g the traced
    function of the surface's level (f, or h − δ for a coarse level)."""
    ao_cfg = scene.ambient_occlusion
    k = ao_cfg.samples
    dists = [ao_cfg.distance * (i + 1) / k for i in range(k)]
    weights = [2.0 ** -i for i in range(k)]
    total = sum(weights)
    offset = 0.0 if is_fine else level.delta
    pts = torch.cat([p_u + d * n_u for d in dists])
    vals = counter.value(level, "ambient_occlusion", pts).reshape(k, -1) - offset
    occ = torch.zeros(p_u.shape[0], dtype=p_u.dtype, device=p_u.device)
    for i, d in enumerate(dists):
        occ = occ + weights[i] / total * ((d - vals[i]) / d).clamp(0, 1)
    occ = torch.nan_to_num(occ, nan=0.0)
    return (1 - ao_cfg.strength * occ).clamp(0, 1)
