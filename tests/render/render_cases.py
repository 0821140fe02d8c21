"""Analytic assets for the renderer's tests (imported by them as ``render_cases``): the bundled samples' SDFs as trace levels, exact ray-sphere hits."""

import numpy as np
import torch

from neural_bake.render.asset import RenderAsset, analytic_level


def sample_level(sample, delta: float = 0.0, offset: float = 0.0, name: str | None = None, lipschitz=1.0):
    """A trace level of a bundled sample's analytic SDF (shifted by ``offset``), source frame = unit frame."""

    def fn(p):
        return torch.as_tensor(sample.sdf(p.detach().cpu().double().numpy()) - offset, dtype=p.dtype, device=p.device)

    def grad(p):
        return torch.as_tensor(sample.normal(p.detach().cpu().double().numpy()), dtype=p.dtype, device=p.device)

    return analytic_level(fn, grad, delta, name=name or f"{sample.name}{'+' if offset else ''}", lipschitz=lipschitz)


def sphere_level(radius=0.5, delta=0.0, name="sphere", center=(0.0, 0.0, 0.0)):
    c = torch.tensor(center, dtype=torch.float64)

    def fn(p):
        return (p - c.to(p)).norm(dim=1) - radius

    def grad(p):
        q = p - c.to(p)
        return q / q.norm(dim=1, keepdim=True).clamp_min(1e-30)

    return analytic_level(fn, grad, delta, name=name)


def exact_sphere_hits(camera, radius, center=(0.0, 0.0, 0.0)):
    """(hit (H, W) bool, t (H, W) float64 distance along each pixel's ray) of the exact ray-sphere test."""
    d = camera.pixel_directions().reshape(-1, 3)
    o = np.asarray(camera.position) - np.asarray(center)
    b = d @ o
    c = o @ o - radius * radius
    disc = b * b - c
    hit = (disc > 0) & (-b - np.sqrt(np.clip(disc, 0, None)) > 0)
    t = np.where(hit, -b - np.sqrt(np.clip(disc, 0, None)), np.inf)
    return hit.reshape(camera.height, camera.width), t.reshape(camera.height, camera.width)


def nested_sphere_asset():
    """h1 = |p| − 0.52 with δ1 = 0.04 around f = |p| − 0.5 (|h1 − f| = 0.02 < δ1: nested)."""
    return RenderAsset([sphere_level(0.52, 0.04, "h1"), sphere_level(0.5, 0.0, "f")])
