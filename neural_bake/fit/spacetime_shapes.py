"""The shapes of a space-time fit in their common unit frame: meshes (exact signed distances) and fitted SDFs
(a network seen from the common frame), each giving surface, near-surface and uniform samples and distances."""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np
import torch

from ..constants import MIN_SURFACE_GRAD, MINED_ZERO_SET_TOL, UNIT_FRAME_EXTENT
from ..errors import FitError
from ..nets.gemm import gemm_gradient
from ..nets.siren import Siren
from ..types import Frame, Mesh

__all__ = ["common_frame", "reframe", "field_parts", "shape_of", "MeshShape", "FieldShape"]


def common_frame(shapes: Sequence) -> Frame:
    """The unit frame that holds every shape: meshes (their vertices, in their source frame) and fitted fields
    (the source box of their unit cube's [−0.9, 0.9]³, where a normalised shape lies)."""
    pts = []
    half = UNIT_FRAME_EXTENT / 2
    corners = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)])
    for s in shapes:
        if isinstance(s, Mesh):
            pts.append(s.frame.to_source(s.vertices))
        else:
            pts.append(field_parts(s, "shape")[1].to_source(corners))
    return Frame.fit(np.concatenate(pts))


def reframe(mesh: Mesh, frame: Frame) -> Mesh:
    """``mesh`` with its vertices moved into ``frame`` (same source geometry; normals unchanged: frames only
    scale uniformly and shift)."""
    vertices = frame.to_unit(mesh.frame.to_source(mesh.vertices))
    return replace(mesh, vertices=vertices, frame=frame)


def field_parts(s, name: str) -> tuple[Siren, Frame]:
    """(3-D Siren, frame) of a fitted SDF: an SdfFit / SdfField (``model``, ``frame``) or a nested sequence
    (its fine level)."""
    model = s.levels[-1] if hasattr(s, "levels") else getattr(s, "model", None)
    frame = getattr(s, "frame", None)
    if not isinstance(model, Siren) or not isinstance(frame, Frame):
        raise FitError(f"{name}: expected a Mesh or a fitted SDF (a network with its frame), got {type(s).__name__}")
    if model.in_dim != 3 or model.out_dim != 1:
        raise FitError(f"{name}: an SDF maps R^3 to R, this network maps R^{model.in_dim} to R^{model.out_dim}")
    return model, frame


class MeshShape:
    """A mesh in the common frame: samples and exact signed distances (:mod:`neural_bake.fit.sampling`)."""

    def __init__(self, mesh: Mesh, frame: Frame, name: str):
        if mesh.n_faces == 0 or mesh.n_vertices == 0:
            raise FitError(f"{name}: the mesh has no faces to fit")
        if not np.isfinite(mesh.vertices).all():
            raise FitError(f"{name}: the mesh has non-finite vertex coordinates")
        self.mesh, self.name = reframe(mesh, frame), name

    def surface(self, n: int, seed: int):
        from .sampling import sample_surface

        s = sample_surface(self.mesh, n, seed=seed)
        if len(s) == 0:
            raise FitError(f"{self.name}: no surface samples (every face is degenerate)")
        return s.points, s.normals

    def near(self, n: int, sigmas, seed: int):
        from .sampling import sample_near

        v = sample_near(self.mesh, n, sigma=list(sigmas), seed=seed)
        return v.points, v.sdf

    def uniform(self, n: int, seed: int):
        from .sampling import sample_uniform

        v = sample_uniform(self.mesh, n, seed=seed)
        return v.points, v.sdf

    def distance(self, x: np.ndarray) -> np.ndarray:
        from .sampling import signed_distance

        return signed_distance(self.mesh, x)


class FieldShape:
    """A fitted SDF seen from the common frame: d(x) = g(x in g's frame) in common-frame units. Outside g's
    unit cube the value is g at the nearest point of the cube plus the distance to it (the network is not
    trained there). Surface samples: uniform points of g's cube nearest to g = 0, projected onto it by Newton
    steps (not area-uniform), normals ∇g / |∇g|."""

    def __init__(self, s, frame: Frame, name: str):
        self.model, self.own = field_parts(s, name)
        self.frame, self.name = frame, name
        p = next(self.model.parameters())
        self.dtype, self.device = p.dtype, p.device

    def _own(self, x: np.ndarray) -> np.ndarray:
        return self.own.to_unit(self.frame.to_source(x))

    def _common(self, u: np.ndarray) -> np.ndarray:
        return self.frame.to_unit(self.own.to_source(u))

    def _values(self, u: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            t = torch.as_tensor(u, dtype=self.dtype, device=self.device)
            return self.model(t)[:, 0].double().cpu().numpy()

    def distance(self, x: np.ndarray) -> np.ndarray:
        u = self._own(np.asarray(x, dtype=np.float64))
        inside = np.clip(u, -1.0, 1.0)
        d = self._values(inside) + np.linalg.norm(u - inside, axis=1)
        return d * self.frame.scale / self.own.scale

    def surface(self, n: int, seed: int):
        from .metrics import project_to_zero_set

        rng = np.random.default_rng([seed, 11])
        got_p, got_n, have = [], [], 0
        for _ in range(8):
            cand = rng.uniform(-1.0, 1.0, size=(16 * n, 3))
            near = cand[np.argsort(np.abs(self._values(cand)))[: 2 * n]]
            x = project_to_zero_set(self.model, torch.as_tensor(near, dtype=self.dtype, device=self.device), 3)
            values, grads = gemm_gradient(self.model, x)
            gn = torch.linalg.vector_norm(grads, dim=1)
            ok = (values[:, 0].abs() < MINED_ZERO_SET_TOL) & (gn > MIN_SURFACE_GRAD) & (x.abs() <= 1.0).all(dim=1)
            got_p.append(x[ok].double().cpu().numpy())
            got_n.append((grads[ok] / gn[ok, None]).double().cpu().numpy())
            have += int(ok.sum())
            if have >= n:
                break
        if have == 0:
            raise FitError(f"{self.name}: the field has no zero level set in its unit cube")
        p, nn = np.concatenate(got_p)[:n], np.concatenate(got_n)[:n]
        return self._common(p).astype(np.float32), nn.astype(np.float32)

    def near(self, n: int, sigmas, seed: int):
        rng = np.random.default_rng([seed, 13])
        p, _ = self.surface(n, seed)
        sig = np.asarray(sigmas, dtype=np.float64)[rng.integers(0, len(sigmas), len(p))]
        x = p + rng.normal(size=p.shape) * sig[:, None]
        return x.astype(np.float32), self.distance(x).astype(np.float32)

    def uniform(self, n: int, seed: int):
        x = np.random.default_rng([seed, 17]).uniform(-1.0, 1.0, size=(n, 3))
        return x.astype(np.float32), self.distance(x).astype(np.float32)


def shape_of(s, frame: Frame, name: str):
    """A :class:`MeshShape` of a mesh, else a :class:`FieldShape` of a fitted SDF."""
    return MeshShape(s, frame, name) if isinstance(s, Mesh) else FieldShape(s, frame, name)
