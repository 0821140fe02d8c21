"""The classical bake as maps of its own: a tilted plane baked onto a flat one gives the known tangent-space
normal, and the source texture lands in the coarse layout."""

import numpy as np
import pytest

from neural_bake.bake.classical import classical_bake
from neural_bake.types import Frame, Mesh


def _grid(n: int, slope: float, texture=None) -> Mesh:
    """A square [-0.5, 0.5]² in z = slope · x, n × n quads split in two, UVs (x + 0.5, y + 0.5)."""
    t = np.linspace(-0.5, 0.5, n + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), slope * x.ravel()], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    uv = v[f][..., :2] + 0.5
    normal = np.array([-slope, 0.0, 1.0]) / np.hypot(slope, 1.0)
    return Mesh(vertices=v, faces=f, uv=uv, texture=texture, vertex_normals=np.tile(normal, (len(v), 1)),
                frame=Frame(), watertight=False)


def test_a_tilted_plane_bakes_to_its_tangent_space_normal_and_its_texture():
    size = 32
    u = (np.arange(size) + 0.5) / size
    tex = np.stack(np.broadcast_arrays(u[None, :], u[::-1, None], np.full((size, size), 0.25)), axis=2)
    slope = np.tan(np.radians(10.0))
    fine = _grid(8, slope, tex.astype(np.float32))
    coarse = _grid(1, 0.0)
    result, baker = classical_bake(coarse, fine, size, cage=0.2, padding=None)
    cov = result.coverage
    assert cov.mean() > 0.9
    n = result.normal_map[cov] * 2 - 1
    expected = np.array([-np.sin(np.radians(10.0)), 0.0, np.cos(np.radians(10.0))])  # tangent = +x, +Y green
    assert np.abs(n - expected).max() < 1e-5
    # colours: the fine mesh's texture where the rays land (x, y unchanged by the tilt: the same u, v) — the
    # texture read at the texel's own UV, to bilinear accuracy of a linear ramp
    assert np.abs(result.albedo[cov] - tex[cov]).max() < 1e-4
    assert result.stats["texels_covered"] == int(cov.sum()) and result.stats["fallback"] == 0
    # a flat plane on a flat plane is the flat normal (0.5, 0.5, 1): the bake can fail
    flat, _ = classical_bake(coarse, _grid(8, 0.0, tex.astype(np.float32)), size, cage=0.2, padding=None)
    assert np.allclose(flat.normal_map[flat.coverage], (0.5, 0.5, 1.0), atol=1e-6)
    assert not np.allclose(result.normal_map[cov], (0.5, 0.5, 1.0), atol=1e-2)
    with pytest.raises(Exception, match="cage"):
        classical_bake(coarse, fine, size, cage=-1.0)
