"""Small SIRENs over a grid of tiles, blended by a partition of unity: a residual level whose capacity grows with
the surface instead of with one network's width (nested-neighbourhoods §3's fine level, split in space).

The unit frame is cut into G³ cubic cells of side ``cell`` from ``origin``; ``active`` lists the cells that
hold a network (e.g. those the surface passes through). Tile t's network sees its cell widened by ``margin``
cells on every side, in local coordinates ``(x − centre_t) / half`` with ``half = cell · (½ + margin)``, and its
output is scaled back by ``half``, so its gradient in the unit frame is its gradient in local coordinates.

Along each axis a cell's weight is 1 inside it, and across the seam of width 2 · margin · cell around each
face it hands over to its neighbour by a smoothstep (s(t) = 3t² − 2t³, whose slope is 0 at both ends): the
weights of the cells around a point sum to 1 and are C¹. The blend is ``r(x) = Σ_t w_t(x) r_t(x)`` over the
active tiles, with ``∇r = Σ_t (w_t ∇r_t + r_t ∇w_t)``; where a cell is not active its share is simply missing,
so r fades to 0 across the seams at the edge of the active region and is exactly 0 beyond them. It is meant
as a residual on a base field (f = h + r), which holds f everywhere the tiles do not reach.

:class:`TiledSdf` is that field: a coarse :class:`~neural_bake.nets.siren.Siren` h and its tile level r, with
the value, GEMM value-and-gradient and guaranteed range bounds of f = h + r that the field layer, the baker,
marching cubes and the renderer take from a network (:func:`~neural_bake.nets.gemm.gemm_gradient` and
:func:`~neural_bake.nets.range_analysis.range_bound` hand a TiledSdf to its own methods).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ..errors import NeuralBakeError
from .gemm import gemm_gradient
from .siren import Siren, siren_forward_inference

__all__ = ["TileGrid", "TiledSiren", "TiledSdf", "smoothstep", "by_tile"]


def smoothstep(t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(s, ds/dt) of s(t) = 3t² − 2t³ at ``t`` clamped to [0, 1] (ds/dt 0 outside)."""
    u = t.clamp(0.0, 1.0)
    return u * u * (3.0 - 2.0 * u), torch.where((t > 0) & (t < 1), 6.0 * u * (1.0 - u), torch.zeros_like(u))


class TileGrid:
    """Where the tiles are: ``origin`` (3,) unit-frame corner of the grid, ``cell`` the cells' side, ``grid`` G
    (cells per axis), ``margin`` the seam's half-width in cells (0 < margin ≤ ¼), ``active`` the (K,) flat
    indices ``i·G² + j·G + k`` of the cells with a network, in the order of the networks."""

    def __init__(self, origin, cell: float, grid: int, margin: float, active):
        origin = torch.as_tensor(origin, dtype=torch.float64).reshape(-1)
        active = torch.as_tensor(active, dtype=torch.long).reshape(-1)
        if origin.numel() != 3 or not bool(torch.isfinite(origin).all()):
            raise NeuralBakeError(f"TileGrid: origin must be 3 finite numbers, got {origin.tolist()}")
        if not (math.isfinite(cell) and cell > 0):
            raise NeuralBakeError(f"TileGrid: cell must be a positive length, got {cell!r}")
        if isinstance(grid, bool) or int(grid) != grid or grid < 1:
            raise NeuralBakeError(f"TileGrid: grid must be a positive integer, got {grid!r}")
        if not (0 < margin <= 0.25):
            raise NeuralBakeError(f"TileGrid: margin must be in (0, 0.25] cells, got {margin!r}")
        if active.numel() == 0 or int(active.min()) < 0 or int(active.max()) >= int(grid) ** 3 \
                or len(torch.unique(active)) != active.numel():
            raise NeuralBakeError(f"TileGrid: active must be distinct cell indices in [0, {int(grid) ** 3}), "
                                  f"at least one")
        self.origin, self.cell, self.grid, self.margin = origin, float(cell), int(grid), float(margin)
        self.active = active
        self.slot = torch.full((self.grid ** 3,), -1, dtype=torch.long)
        self.slot[active] = torch.arange(active.numel())

    @property
    def half(self) -> float:
        """Half the side of a tile's support (its cell and the seams around it)."""
        return self.cell * (0.5 + self.margin)

    def centres(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """(K, 3) the active cells' centres."""
        g = self.grid
        ijk = torch.stack([self.active // (g * g), (self.active // g) % g, self.active % g], dim=1)
        return (self.origin + self.cell * (ijk.double() + 0.5)).to(dtype=dtype, device=device)

    def to_dict(self) -> dict:
        """JSON-ready: what :meth:`from_dict` rebuilds the grid from."""
        return {"origin": self.origin.tolist(), "cell": self.cell, "grid": self.grid, "margin": self.margin,
                "active": self.active.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "TileGrid":
        return cls(d["origin"], d["cell"], d["grid"], d["margin"], d["active"])

    def covering(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The tiles around each point: ``(tiles (N, 8), weights (N, 8), weight gradients (N, 8, 3))``, in the
        points' dtype and device. ``tiles`` holds network indices (0 … K−1) or −1 where the cell is outside
        the grid, not active or not reached (its weight and gradient are then 0); the weights of the cells
        around a point sum to 1 before the missing ones are dropped."""
        dtype, device = points.dtype, points.device
        u = (points - self.origin.to(dtype=dtype, device=device)) / self.cell  # in cells from the origin
        own = torch.floor(u)
        r = u - own
        own = own.long()
        m = self.margin
        lower, upper = r < m, r > 1.0 - m
        s_lo, d_lo = smoothstep((r + m) / (2.0 * m))  # own weight rising across the lower seam
        s_up, d_up = smoothstep((r - (1.0 - m)) / (2.0 * m))  # own weight falling across the upper seam
        scale = 1.0 / (2.0 * m * self.cell)
        w_own = torch.where(lower, s_lo, torch.where(upper, 1.0 - s_up, torch.ones_like(r)))
        d_own = torch.where(lower, d_lo, torch.where(upper, -d_up, torch.zeros_like(r))) * scale
        seam = lower | upper
        other = torch.where(lower, own - 1, own + 1)
        g, slot = self.grid, self.slot.to(device)
        tiles, weights, grads = [], [], []
        for corner in range(8):
            take = [(corner >> ax) & 1 for ax in range(3)]  # per axis: own cell (0) or the seam's other (1)
            cells = torch.stack([other[:, ax] if take[ax] else own[:, ax] for ax in range(3)], dim=1)
            w = [1.0 - w_own[:, ax] if take[ax] else w_own[:, ax] for ax in range(3)]
            dw = [-d_own[:, ax] if take[ax] else d_own[:, ax] for ax in range(3)]
            ok = ((cells >= 0) & (cells < g)).all(dim=1)
            for ax in range(3):
                if take[ax]:
                    ok &= seam[:, ax]
            flat = (cells[:, 0] * g + cells[:, 1]) * g + cells[:, 2]
            t = torch.where(ok, slot[flat.clamp(0, g ** 3 - 1)], torch.full_like(flat, -1))
            ok &= t >= 0
            tiles.append(t)
            weights.append(torch.where(ok, w[0] * w[1] * w[2], torch.zeros_like(w[0])))
            grads.append(torch.stack([dw[0] * w[1] * w[2], w[0] * dw[1] * w[2], w[0] * w[1] * dw[2]], dim=1)
                         * ok.unsqueeze(1))
        return torch.stack(tiles, 1), torch.stack(weights, 1), torch.stack(grads, 1)


def by_tile(tiles: torch.Tensor, count: int) -> tuple[torch.Tensor, list[int]]:
    """The (point, corner) pairs of :meth:`TileGrid.covering`'s ``tiles`` (N, 8) grouped by tile: ``pairs`` the
    flat indices ``8 · point + corner`` sorted by tile, and ``bounds`` (count + 1) such that tile t's pairs are
    ``pairs[bounds[t]:bounds[t + 1]]`` (the point is ``pair // 8``)."""
    flat = tiles.reshape(-1)
    pairs = torch.nonzero(flat >= 0).reshape(-1)
    pairs = pairs[torch.argsort(flat[pairs], stable=True)]
    bounds = torch.searchsorted(flat[pairs], torch.arange(count + 1, device=tiles.device)).tolist()
    return pairs, bounds


class _TileView:
    """One tile's network as :func:`~neural_bake.nets.gemm.gemm_gradient` takes it."""

    in_dim, out_dim = 3, 1

    def __init__(self, layers):
        self.layers = layers

    def affine_layers(self, *, dtype=None, device=None):
        return [(w.to(dtype=dtype, device=device), b.to(dtype=dtype, device=device)) for w, b in self.layers]


class TiledSiren(nn.Module):
    """K SIRENs (R³ → R, ``width`` units, ``depth`` hidden W×W matrices, as :class:`~neural_bake.nets.siren.Siren`)
    on the tiles of ``grid``, their weights stacked: layer i's are (K, out_i, in_i) and (K, out_i).

    ``zero_output``: the output layers start at 0 (a residual level that starts as no change). ``generator``:
    a seeded initialisation.
    """

    def __init__(self, grid: TileGrid, width: int = 64, depth: int = 2, omega_0: float = 30.0,
                 hidden_omega: float = 30.0, *, zero_output: bool = True, generator: torch.Generator | None = None):
        super().__init__()
        if isinstance(width, bool) or int(width) != width or width < 1:
            raise NeuralBakeError(f"TiledSiren: width must be a positive integer, got {width!r}")
        if isinstance(depth, bool) or int(depth) != depth or depth < 0:
            raise NeuralBakeError(f"TiledSiren: depth must be a non-negative integer, got {depth!r}")
        if not (math.isfinite(omega_0) and omega_0 > 0 and math.isfinite(hidden_omega) and hidden_omega > 0):
            raise NeuralBakeError(f"TiledSiren: omega_0 and hidden_omega must be positive, got {omega_0!r}, "
                                  f"{hidden_omega!r}")
        self.grid = grid
        self.width, self.depth = int(width), int(depth)
        self.omega_0, self.hidden_omega = float(omega_0), float(hidden_omega)
        k = int(grid.active.numel())
        dims = [3] + [self.width] * (self.depth + 1) + [1]
        self.weights = nn.ParameterList(nn.Parameter(torch.empty(k, b, a)) for a, b in zip(dims[:-1], dims[1:]))
        self.biases = nn.ParameterList(nn.Parameter(torch.empty(k, b)) for b in dims[1:])
        with torch.no_grad():
            for i, (w, b) in enumerate(zip(self.weights, self.biases)):
                fan_in = w.shape[2]
                last = i == len(dims) - 2
                bound = 1.0 / fan_in if i == 0 else math.sqrt(6.0 / fan_in) / self.omegas[i - 1 if last else i]
                w.uniform_(-bound, bound, generator=generator)
                b.uniform_(-1.0 / math.sqrt(fan_in), 1.0 / math.sqrt(fan_in), generator=generator)
                if last and zero_output:
                    w.zero_()
                    b.zero_()

    @property
    def tiles(self) -> int:
        return int(self.grid.active.numel())

    @property
    def omegas(self) -> list[float]:
        """ω of each layer (1.0 for the linear output layer)."""
        return [self.omega_0] + [self.hidden_omega] * self.depth + [1.0]

    @property
    def architecture(self) -> dict:
        """What a model file stores to rebuild this network (with the weights)."""
        return {"width": self.width, "depth": self.depth, "omega_0": self.omega_0,
                "hidden_omega": self.hidden_omega, "grid": self.grid.to_dict()}

    def affine_layers(self, *, dtype=None, device=None) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """[(W_i (K, out, in), b_i (K, out))] with ω folded in, converted before folding; differentiable."""
        return [(w.to(device=device, dtype=dtype) * o, b.to(device=device, dtype=dtype) * o)
                for w, b, o in zip(self.weights, self.biases, self.omegas)]

    def tile_values_and_gradients(self, local: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Each tile's network at its own points: ``local`` (K, B, 3) local coordinates → values (K, B) in
        the unit frame (scaled by ``grid.half``) and gradients (K, B, 3), by the reverse-mode formula of
        :mod:`~neural_bake.nets.gemm` batched over tiles; on the autograd graph (a training loss on both
        backpropagates with one ordinary backward pass)."""
        if local.dim() != 3 or local.shape[0] != self.tiles or local.shape[2] != 3:
            raise NeuralBakeError(f"TiledSiren: expected local points of shape ({self.tiles}, B, 3), got "
                                  f"{tuple(local.shape)}")
        layers = self.affine_layers(dtype=local.dtype, device=local.device)
        h, cos = local, []
        for w, b in layers[:-1]:
            a = torch.baddbmm(b.unsqueeze(1), h, w.transpose(1, 2))
            h = torch.sin(a)
            cos.append(torch.cos(a))
        w_n, b_n = layers[-1]
        values = torch.baddbmm(b_n.unsqueeze(1), h, w_n.transpose(1, 2))[..., 0] * self.grid.half
        g = cos[-1] * w_n
        for i in range(len(cos) - 1, 0, -1):
            g = torch.bmm(g, layers[i][0]) * cos[i - 1]
        return values, torch.bmm(g, layers[0][0])

    def _per_tile(self, points: torch.Tensor):
        """The covering of ``points`` (N, 3) (:meth:`TileGrid.covering`: tiles, weights, weight gradients) and a
        generator of ``(rows, layers, local)`` per tile with points: the flat (point, corner) slots ``8 · point +
        corner`` it fills, its ω-folded layers and its points in its local coordinates."""
        if points.dim() != 2 or points.shape[1] != 3 or not points.is_floating_point():
            raise NeuralBakeError(f"TiledSiren: expected floating points of shape (N, 3), got {tuple(points.shape)}")
        dtype, device = points.dtype, points.device
        tiles, weights, wgrads = self.grid.covering(points)
        pairs, bounds = by_tile(tiles, self.tiles)
        centres = self.grid.centres(dtype=dtype, device=device)
        layers = self.affine_layers(dtype=dtype, device=device)

        def each():
            for t in range(self.tiles):
                lo, hi = bounds[t], bounds[t + 1]
                if lo < hi:
                    rows = pairs[lo:hi]
                    yield rows, [(w[t], b[t]) for w, b in layers], (points[rows // 8] - centres[t]) / self.grid.half

        return weights, wgrads, each()

    @torch.no_grad()
    def value_and_gradient(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The blend r (N,) and ∇r (N, 3) at unit-frame ``points`` (N, 3), dtype and device of ``points``: every
        tile's network runs once on the points it covers (:func:`~neural_bake.nets.gemm.gemm_gradient`)."""
        weights, wgrads, tiles = self._per_tile(points)
        n = points.shape[0]
        values = torch.zeros(n * 8, dtype=points.dtype, device=points.device)
        grads = torch.zeros(n * 8, 3, dtype=points.dtype, device=points.device)
        for rows, layers, local in tiles:
            v, g = gemm_gradient(_TileView(layers), local)
            values[rows] = v[:, 0] * self.grid.half
            grads[rows] = g
        values, grads = values.view(n, 8), grads.view(n, 8, 3)
        r = (weights * values).sum(dim=1)
        grad = (weights.unsqueeze(2) * grads + values.unsqueeze(2) * wgrads).sum(dim=1)
        return r, grad

    @torch.no_grad()
    def value(self, points: torch.Tensor) -> torch.Tensor:
        """The blend r (N,) at unit-frame ``points`` (N, 3) without its gradient (each tile's forward pass)."""
        weights, _, tiles = self._per_tile(points)
        values = torch.zeros(points.shape[0] * 8, dtype=points.dtype, device=points.device)
        for rows, layers, local in tiles:
            values[rows] = siren_forward_inference(layers, local)[:, 0] * self.grid.half
        return (weights * values.view(-1, 8)).sum(dim=1)

    def tile_view(self, t: int) -> "_TileView":
        """Tile ``t``'s network alone (on its local coordinates; its output not yet scaled by ``grid.half``)."""
        return _TileView([(w[t].detach(), b[t].detach()) for w, b in self.affine_layers()])

    @torch.no_grad()
    def range_bound(self, center: torch.Tensor, axes: torch.Tensor, method: str = "affine-fixed"
                    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Guaranteed (lo, hi) of r over boxes ``center + Σ_k t_k axes[:, k]``, t ∈ [−1, 1]^s (``center`` (B, 3),
        ``axes`` (B, s, 3), unit frame), as :func:`~neural_bake.nets.range_analysis.range_bound`.

        The weights are ≥ 0 and sum to at most 1, so r lies between 0 and the bounds of the tiles that reach
        the box: each is bounded by range analysis over the box in its local coordinates. A box spanning
        more than two cells along an axis takes the bound of every tile over its whole support instead."""
        from .range_analysis import range_bound

        dtype, device = center.dtype, center.device
        b = center.shape[0]
        lo_r = torch.zeros(b, dtype=dtype, device=device)
        hi_r = torch.zeros(b, dtype=dtype, device=device)
        if b == 0:
            return lo_r, hi_r
        g, m = self.grid.grid, self.grid.margin
        ext = axes.abs().sum(dim=1)
        u_lo = (center - ext - self.grid.origin.to(dtype=dtype, device=device)) / self.grid.cell - m
        u_hi = (center + ext - self.grid.origin.to(dtype=dtype, device=device)) / self.grid.cell + m
        c_lo, c_hi = torch.floor(u_lo).long(), torch.floor(u_hi).long()
        wide = ((c_hi - c_lo) > 1).any(dim=1)
        if bool(wide.any()):
            s_lo, s_hi = self._support_bounds(method)
            lo_r[wide], hi_r[wide] = min(0.0, s_lo), max(0.0, s_hi)
        narrow = torch.nonzero(~wide).reshape(-1)
        if narrow.numel() == 0:
            return lo_r, hi_r
        slot = self.grid.slot.to(device)
        boxes, tiles = [], []
        for corner in range(8):  # the ≤ 2 cells per axis a narrow box reaches (duplicates are harmless)
            cells = torch.stack([c_hi[narrow, ax] if (corner >> ax) & 1 else c_lo[narrow, ax] for ax in range(3)], 1)
            ok = ((cells >= 0) & (cells < g)).all(dim=1)
            flat = (cells[:, 0] * g + cells[:, 1]) * g + cells[:, 2]
            t = torch.where(ok, slot[flat.clamp(0, g ** 3 - 1)], torch.full_like(flat, -1))
            boxes.append(narrow[t >= 0])
            tiles.append(t[t >= 0])
        box, tile = torch.cat(boxes), torch.cat(tiles)
        centres = self.grid.centres(dtype=dtype, device=device)
        half = self.grid.half
        for t in torch.unique(tile).tolist():
            sel = box[tile == t]
            lo, hi = range_bound(self.tile_view(t), (center[sel] - centres[t]) / half, axes[sel] / half, method)
            lo_r.scatter_reduce_(0, sel, lo * half, "amin")  # a box reached by several tiles: the widest
            hi_r.scatter_reduce_(0, sel, hi * half, "amax")
        return lo_r, hi_r

    def _support_bounds(self, method: str) -> tuple[float, float]:
        """(lo, hi) of every tile's r_t over its whole support, the least and the most."""
        from .range_analysis import range_bound

        key = (method, tuple(p._version for p in self.parameters()))  # recomputed when the weights change
        if getattr(self, "_support", (None,))[0] != key:
            los, his = [], []
            c = torch.zeros(1, 3, dtype=torch.float64)
            ax = torch.eye(3, dtype=torch.float64).unsqueeze(0)
            for t in range(self.tiles):
                lo, hi = range_bound(self.tile_view(t), c, ax, method)
                los.append(float(lo[0]) * self.grid.half)
                his.append(float(hi[0]) * self.grid.half)
            self._support = (key, (min(los), max(his)))
        return self._support[1]

    def extra_repr(self) -> str:
        g = self.grid
        return f"{self.tiles} tiles of (W, D) = ({self.width}, {self.depth}) on a {g.grid}³ grid, margin {g.margin:g}"


class TiledSdf(nn.Module):
    """The field f = h + r of a coarse SIREN ``coarse`` (R³ → R) and a tile level ``tiles`` on it, as one network:
    ``forward`` gives f (N, 1); :meth:`gemm_gradient` f and ∇f (each part's GEMM normals, added);
    :meth:`range_bound` guaranteed bounds over boxes (h's by range analysis plus r's). ``composite`` marks a
    network that :func:`~neural_bake.nets.gemm.gemm_gradient` and
    :func:`~neural_bake.nets.range_analysis.range_bound` hand to its own methods."""

    composite = True
    in_dim, out_dim = 3, 1

    def __init__(self, coarse: Siren, tiles: TiledSiren):
        super().__init__()
        if int(coarse.in_dim) != 3 or int(coarse.out_dim) != 1:
            raise NeuralBakeError(f"TiledSdf: the coarse level must map R^3 to R, got R^{coarse.in_dim} to "
                                  f"R^{coarse.out_dim}")
        self.coarse, self.tiles = coarse, tiles

    @property
    def architecture(self) -> dict:
        """What a model file stores to rebuild this network (``"network": "tiles"``)."""
        return {"network": "tiles", "coarse": self.coarse.architecture, "tiles": self.tiles.architecture}

    @property
    def label(self) -> str:
        """"64x3+44x(64x2)": the coarse level's (W, D), the number of tiles and theirs."""
        c, t = self.coarse, self.tiles
        return f"{c.width}x{c.depth}+{t.tiles}x({t.width}x{t.depth})"

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """f (N, 1) at ``x`` (N, 3); no autograd graph through the tiles (inference)."""
        with torch.no_grad():
            return self.value(x).unsqueeze(1)

    @torch.no_grad()
    def value(self, points: torch.Tensor, *, gemm_dtype: torch.dtype | None = None) -> torch.Tensor:
        """f (N,) at ``points`` (N, 3), in their dtype and device (``gemm_dtype`` for h's hidden GEMMs)."""
        layers = self.coarse.affine_layers(dtype=points.dtype, device=points.device)
        h = siren_forward_inference(layers, points, gemm_dtype=gemm_dtype)[:, 0]
        return h + self.tiles.value(points)

    @torch.no_grad()
    def gemm_gradient(self, points: torch.Tensor, **kwargs) -> tuple[torch.Tensor, torch.Tensor]:
        """f (N, 1) and ∇f (N, 3): h's by :func:`~neural_bake.nets.gemm.gemm_gradient` (``kwargs`` passed on;
        ``differentiable`` is refused: a tiled SDF is trained by :func:`~neural_bake.fit.tiles.fit_tiles`) plus
        the tile level's (:meth:`TiledSiren.value_and_gradient`)."""
        if kwargs.pop("differentiable", False):
            raise NeuralBakeError("gemm_gradient: a tiled SDF has no differentiable GEMM gradient")
        kwargs.pop("blocks", None)
        values, grads = gemm_gradient(self.coarse, points, **kwargs)
        r, rg = self.tiles.value_and_gradient(points)
        return values + r.unsqueeze(1), grads + rg

    def affine_layers(self, *, dtype=None, device=None):
        raise NeuralBakeError("a tiled SDF is not one SIREN: it has no single list of affine layers")

    @torch.no_grad()
    def range_bound(self, center: torch.Tensor, axes: torch.Tensor, method: str = "affine-fixed"
                    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Guaranteed (lo, hi) of f = h + r over boxes (as :func:`~neural_bake.nets.range_analysis.range_bound`)."""
        from .range_analysis import add_bounds, range_bound

        lo, hi = range_bound(self.coarse, center, axes, method)
        return add_bounds(lo, hi, *self.tiles.range_bound(center.to(lo.dtype), axes.to(lo.dtype), method))

    def extra_repr(self) -> str:
        return f"f = h {self.coarse.width}x{self.coarse.depth} + {self.tiles.extra_repr()}"
