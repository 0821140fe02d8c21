"""A multiresolution feature grid in front of a small MLP (Müller et al. 2022, Instant-NGP), in plain torch.

``GridNet: R^3 (unit frame) -> R^out_dim``. L levels of 3-D grids over [-1, 1]³, level l with R_l cells per side
(R_l = ⌊R_0 · b^l⌋, b chosen so the last level has ``max_resolution``), each vertex holding F learned features. A
point's features at each level are the trilinear interpolation of its cell's 8 vertices; the L·F features,
concatenated, go through an MLP of ``depth + 1`` hidden layers of ``width`` (ReLU, or sine with ω) to a linear
output. A level whose (R_l + 1)³ vertices fit in 2^``log2_table`` entries is stored densely; a finer one hashes
its vertices into that many entries (the spatial hash of Instant-NGP, primes 1, 2654435761, 805459861).

With ``in_dim=6`` the network also takes the surface normal at each point (columns 3..5, unit vectors):
scaled by ``normal_scale``, the three go to the MLP beside the grid's features. A colour field then holds two
colours at one place of space where two surfaces meet or lie back to back (a board's edge, two sides of a
thin panel), which one colour per point cannot. The grid reads the point only.

Points outside [-1, 1]³ read the features of the closest point of the cube. The output is differentiable with
respect to the points (autograd through the interpolation weights; :meth:`GridNet.directional` gives the
derivative along a direction in closed form, differentiable with respect to the parameters), continuous, and
piecewise smooth: the derivative jumps across cell faces.

Works on any device and dtype (``.to(...)``); the tensors a model file holds are its ``state_dict``:
``table`` (Σ_l size_l, F) and ``layers.<i>.weight`` / ``layers.<i>.bias``.

On the CPU, in float32 and float64, the encoding and its gradient with respect to the table run in a C kernel
(``grid.c``: cells, hashing, gathering and weighting in one pass per point, the gradient scattered level by
level, on torch's OpenMP team) where it builds, for points that need no gradient themselves; elsewhere, and with
``NEURAL_BAKE_NATIVE_GRID=0``, in torch (:func:`kernel_status` says which).
"""

from __future__ import annotations

import ctypes
import math
from pathlib import Path

import torch
from torch import nn

from ..constants import (MAX_GRID_FEATURES, MAX_GRID_LEVELS, MAX_GRID_LOG2_TABLE, MAX_GRID_RESOLUTION, MAX_NET_DEPTH,
                         MAX_NET_WIDTH)
from ..errors import NeuralBakeError
from .native import Kernel, threads

__all__ = ["GridNet", "ACTIVATIONS", "IN_DIMS", "NORMAL_SCALE", "grid_resolutions", "grid_table_sizes",
           "grid_layer_dims", "check_grid_settings", "valid_normal_scale", "kernel_status", "ENV_SWITCH"]

#: 0/off/false: the torch encoding even where the C kernel (grid.c) builds (A/B checks).
ENV_SWITCH = "NEURAL_BAKE_NATIVE_GRID"


def _declare(lib) -> None:
    p, i64 = ctypes.c_void_p, ctypes.c_int64
    for name in ("nb_grid_encode_f32", "nb_grid_encode_f64", "nb_grid_backward_f32", "nb_grid_backward_f64"):
        fn = getattr(lib, name)
        fn.argtypes = [p, i64, p, i64, i64, p, p, p, p, p, i64]
        fn.restype = None


#: The C kernel (grid.c, :class:`neural_bake.nets.native.Kernel`; on torch's OpenMP team where it shares it);
#: torch where it does not build.
KERNEL = Kernel(Path(__file__).with_name("grid.c"), switch=ENV_SWITCH, declare=_declare, openmp=True)


def kernel_status() -> str:
    """Which grid encoding runs here on the CPU: the C kernel (and its file), or why torch's does."""
    return KERNEL.status().replace("numpy (", "torch (", 1)


_SUFFIX = {torch.float32: "f32", torch.float64: "f64"}


class _NativeEncode(torch.autograd.Function):
    """The encoding by the C kernel; differentiable with respect to the table (not the points)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, table: torch.Tensor, net: "GridNet") -> torch.Tensor:  # type: ignore[override]
        lib = KERNEL.lib()
        assert lib is not None
        x, table = x.contiguous(), table.contiguous()
        out = x.new_empty(x.shape[0], net.levels * net.features)
        getattr(lib, f"nb_grid_encode_{_SUFFIX[x.dtype]}")(
            x.data_ptr(), x.shape[0], table.data_ptr(), net.levels, net.features, *net._kernel_args(),
            out.data_ptr(), threads())
        ctx.save_for_backward(x)
        ctx.net, ctx.table_shape = net, table.shape
        return out

    @staticmethod
    def backward(ctx, grad: torch.Tensor):  # type: ignore[override]
        (x,) = ctx.saved_tensors
        net = ctx.net
        grad = grad.to(x.dtype).contiguous()
        grad_table = grad.new_zeros(ctx.table_shape)
        lib = KERNEL.lib()
        assert lib is not None
        getattr(lib, f"nb_grid_backward_{_SUFFIX[x.dtype]}")(
            x.data_ptr(), x.shape[0], grad.data_ptr(), net.levels, net.features, *net._kernel_args(),
            grad_table.data_ptr(), threads())
        return None, grad_table, None

#: The MLP's hidden activations: ReLU (Instant-NGP's) or sine (sin(ω·(W x + b)), SIREN's initialisation).
ACTIVATIONS = ("relu", "sine")

#: Spatial-hash primes of Instant-NGP, one per axis.
_PRIMES = (1, 2654435761, 805459861)

#: Half-width of the uniform initialisation of the features (Instant-NGP's).
_TABLE_INIT = 1e-4


def grid_resolutions(levels: int, base_resolution: int, max_resolution: int) -> list[int]:
    """Cells per side of each level: ``⌊R_0 · b^l⌋``, b = (max / R_0)^(1 / (L − 1)), the last exactly ``max``."""
    if levels == 1:
        return [int(base_resolution)]
    b = math.exp((math.log(max_resolution) - math.log(base_resolution)) / (levels - 1))
    out = [int(math.floor(base_resolution * b ** level + 1e-9)) for level in range(levels)]
    out[-1] = int(max_resolution)
    return out


def grid_table_sizes(resolutions: list[int], log2_table: int) -> list[int]:
    """Entries of each level's table: its (R + 1)³ vertices when they fit in 2^``log2_table``, else that many."""
    cap = 1 << int(log2_table)
    return [min((r + 1) ** 3, cap) for r in resolutions]


#: The inputs a grid network takes: points (3), or points and unit surface normals (6).
IN_DIMS = (3, 6)

#: The default scale of the normal inputs: small beside the grid's features, so the MLP leans on them only where
#: the colour changes with the side (a normal off by 10° costs 1.4 dB on the cabinet, against 3.7 dB at scale 1).
NORMAL_SCALE = 0.2


def valid_normal_scale(value) -> bool:
    """Whether ``value`` is a usable ``normal_scale``: a number in (0, 100]."""
    return (not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
            and 0 < value <= 100)


def grid_layer_dims(levels: int, features: int, width: int, depth: int, out_dim: int, in_dim: int = 3) -> list[int]:
    """The MLP's layer sizes, input to output: the L·F features (and the normal's 3 with ``in_dim`` 6), D + 1
    hidden layers of width W, the outputs."""
    return [int(levels) * int(features) + int(in_dim) - 3] + [int(width)] * (int(depth) + 1) + [int(out_dim)]


def check_grid_settings(*, levels, features, log2_table, base_resolution, max_resolution, activation, width=None,
                        depth=None, omega=None, error: type[NeuralBakeError] = NeuralBakeError,
                        prefix: str = "") -> None:
    """Raise ``error`` (one line naming ``prefix + name``) when a setting of :class:`GridNet` is out of range;
    ``width``, ``depth`` and ``omega`` are checked when given (without the prefix: they are the MLP's)."""

    def whole(name, v, lo, hi, pre=prefix):
        if (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or int(v) != v
                or not lo <= v <= hi):
            raise error(f"{pre}{name}: must be an integer in {lo}..{hi}, got {v!r}", parameter=pre + name)

    whole("levels", levels, 1, MAX_GRID_LEVELS)
    whole("features", features, 1, MAX_GRID_FEATURES)
    whole("log2_table", log2_table, 4, MAX_GRID_LOG2_TABLE)
    whole("max_resolution", max_resolution, 1, MAX_GRID_RESOLUTION)
    whole("base_resolution", base_resolution, 1, int(max_resolution))
    if activation not in ACTIVATIONS:
        raise error(f"{prefix}activation: must be one of {', '.join(ACTIVATIONS)}, got {activation!r}",
                    parameter=prefix + "activation")
    if width is not None:
        whole("width", width, 1, MAX_NET_WIDTH, "")
    if depth is not None:
        whole("depth", depth, 0, MAX_NET_DEPTH, "")
    if omega is not None and (isinstance(omega, bool) or not isinstance(omega, (int, float))
                              or not (math.isfinite(omega) and omega > 0)):
        raise error(f"omega: must be a positive number, got {omega!r}", parameter="omega")


class GridNet(nn.Module):
    """Multiresolution feature grid + MLP (module docstring); inputs (N, 3) unit frame, outputs (N, out_dim).

    Args:
        levels: L, the number of grid levels.
        features: F, features per grid vertex.
        log2_table: log2 of the most entries a level's table holds (finer levels are hashed into it).
        base_resolution: cells per side of the coarsest level.
        max_resolution: cells per side of the finest level.
        width: W, the MLP's hidden width.
        depth: D, the MLP's hidden W×W matrices (D + 1 hidden layers, the papers' (W, D) notation).
        out_dim: outputs (3 for RGB).
        activation: "relu" or "sine" (:data:`ACTIVATIONS`).
        omega: ω of the sine activation (unused with ReLU).
        in_dim: 3 (points of the unit frame) or 6 (points, then unit surface normals; module docstring).
        normal_scale: what the normals are multiplied by before the MLP (``in_dim`` 6 only).
        generator: makes the initialisation reproducible.
    """

    def __init__(self, levels: int = 16, features: int = 2, log2_table: int = 17, base_resolution: int = 16,
                 max_resolution: int = 1024, width: int = 64, depth: int = 1, out_dim: int = 3,
                 activation: str = "relu", omega: float = 1.0, in_dim: int = 3, normal_scale: float | None = None,
                 *, generator: torch.Generator | None = None):
        super().__init__()
        if isinstance(in_dim, bool) or in_dim not in IN_DIMS:
            raise NeuralBakeError(f"GridNet: in_dim must be 3 (points of the unit frame) or 6 (points and surface "
                                  f"normals), got {in_dim!r}", parameter="in_dim")
        if in_dim == 3 and normal_scale is not None:
            raise NeuralBakeError("GridNet: normal_scale needs in_dim 6 (normal inputs)", parameter="normal_scale")
        scale = NORMAL_SCALE if normal_scale is None else normal_scale
        if not valid_normal_scale(scale):
            raise NeuralBakeError(f"GridNet: normal_scale must be a number in (0, 100], got {normal_scale!r}",
                                  parameter="normal_scale")
        if isinstance(out_dim, bool) or int(out_dim) != out_dim or not 1 <= out_dim <= 16:
            raise NeuralBakeError(f"GridNet: out_dim must be an integer in 1..16, got {out_dim!r}",
                                  parameter="out_dim")
        check_grid_settings(levels=levels, features=features, log2_table=log2_table,
                            base_resolution=base_resolution, max_resolution=max_resolution, width=width,
                            depth=depth, activation=activation, omega=omega)
        self.levels, self.features, self.log2_table = int(levels), int(features), int(log2_table)
        self.base_resolution, self.max_resolution = int(base_resolution), int(max_resolution)
        self.width, self.depth, self.in_dim, self.out_dim = int(width), int(depth), int(in_dim), int(out_dim)
        self.normal_scale = float(scale) if self.in_dim == 6 else None
        self.activation, self.omega = str(activation), float(omega)
        self.resolutions = grid_resolutions(self.levels, self.base_resolution, self.max_resolution)
        self.sizes = grid_table_sizes(self.resolutions, self.log2_table)
        offsets = [0]
        for s in self.sizes:
            offsets.append(offsets[-1] + s)
        self.table = nn.Parameter(torch.empty(offsets[-1], self.features))
        dims = grid_layer_dims(self.levels, self.features, self.width, self.depth, self.out_dim, self.in_dim)
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))
        # per-level integer constants (not saved: they follow from the architecture)
        res = torch.tensor(self.resolutions, dtype=torch.int64)
        self.register_buffer("_res", res, persistent=False)
        self.register_buffer("_size", torch.tensor(self.sizes, dtype=torch.int64), persistent=False)
        self.register_buffer("_offset", torch.tensor(offsets[:-1], dtype=torch.int64), persistent=False)
        self.register_buffer("_dense", torch.tensor([(r + 1) ** 3 <= s for r, s in zip(self.resolutions, self.sizes)]),
                             persistent=False)
        self.register_buffer("_step", torch.tensor([[0], [1]], dtype=torch.int64), persistent=False)
        # the same per-level constants for the C kernel, kept on the CPU whatever the module's device
        self._kernel_arrays = [self._res, self._size, self._offset, self._dense.to(torch.int64)]
        self.reset_parameters(generator)

    @property
    def architecture(self) -> dict:
        """The constructor arguments with ``"network": "grid"``: what a model file stores to rebuild it
        (``normal_scale`` only with normal inputs)."""
        arch = {"network": "grid", "levels": self.levels, "features": self.features, "log2_table": self.log2_table,
                "base_resolution": self.base_resolution, "max_resolution": self.max_resolution,
                "width": self.width, "depth": self.depth, "in_dim": self.in_dim, "out_dim": self.out_dim,
                "activation": self.activation, "omega": self.omega}
        if self.normal_scale is not None:
            arch["normal_scale"] = self.normal_scale
        return arch

    @property
    def normal_inputs(self) -> bool:
        """Whether the network also takes the surface normal at each point (``in_dim`` 6)."""
        return self.in_dim == 6

    @torch.no_grad()
    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """Features U(±1e-4) (Instant-NGP); ReLU layers He-uniform with zero biases, sine layers SIREN's
        (first U(±1/n), later U(±√(6/n)/ω)); the linear output layer U(±√(6/(n_in + n_out)))."""
        self.table.uniform_(-_TABLE_INIT, _TABLE_INIT, generator=generator)
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            n = layer.in_features
            if i == last:
                bound = math.sqrt(6.0 / (n + layer.out_features))
            elif self.activation == "relu":
                bound = math.sqrt(6.0 / n)
            else:
                bound = 1.0 / n if i == 0 else math.sqrt(6.0 / n) / self.omega
            layer.weight.uniform_(-bound, bound, generator=generator)
            if self.activation == "sine" and i != last:
                layer.bias.uniform_(-1.0 / math.sqrt(n), 1.0 / math.sqrt(n), generator=generator)
            else:
                layer.bias.zero_()

    # ------------------------------------------------------------------------------------------- encoding
    def _cells(self, x: torch.Tensor):
        """(indices (N, L, 8) into ``table``, per-axis weights (N, L, 2, 3) of the cell's low and high vertices,
        cells per unit of x (L,) in x's dtype, the in-cube mask (N, 3)). Corner c = i + 2j + 4k is vertex
        (i, j, k) of the cell along (x, y, z)."""
        res_f = self._res.to(x.dtype)
        inside = (x > -1) & (x < 1)
        u = (x.clamp(-1.0, 1.0) + 1.0).mul(0.5).unsqueeze(1) * res_f[:, None]  # (N, L, 3), in [0, R]
        cell = torch.minimum(torch.floor(u), (res_f - 1)[:, None])  # the last vertex belongs to the last cell
        frac = u - cell  # (N, L, 3) in [0, 1]
        w = torch.stack([1 - frac, frac], dim=2)  # (N, L, 2, 3)
        c = cell.to(torch.int64).unsqueeze(2) + self._step  # (N, L, 2, 3): low and high vertex per axis
        cx, cy, cz = c[..., 0][..., None, None, :], c[..., 1][..., None, :, None], c[..., 2][..., :, None, None]
        side = (self._res + 1)[:, None, None, None]
        dense = cx + side * (cy + side * cz)
        hashed = (cx * _PRIMES[0]) ^ (cy * _PRIMES[1]) ^ (cz * _PRIMES[2])
        idx = torch.where(self._dense[:, None, None, None], dense,
                          torch.remainder(hashed, self._size[:, None, None, None]))
        idx = (idx + self._offset[:, None, None, None]).reshape(*idx.shape[:2], 8)
        return idx, w, 0.5 * res_f, inside

    @staticmethod
    def _trilinear(w: torch.Tensor) -> torch.Tensor:
        """The 8 corner weights (N, L, 8) from per-axis weights (N, L, 2, 3)."""
        wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
        return (wz[..., :, None, None] * wy[..., None, :, None] * wx[..., None, None, :]).flatten(-3)

    def _gather(self, idx: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
        """Features (N, L, 8, F) of the table rows ``idx`` (N, L, 8)."""
        return self.table.to(dtype).index_select(0, idx.reshape(-1)).reshape(*idx.shape, self.features)

    def _kernel_args(self) -> tuple[int, ...]:
        """The per-level arrays the C kernel reads (pointers; the arrays are kept on the module)."""
        return tuple(a.data_ptr() for a in self._kernel_arrays)

    def _native(self, x: torch.Tensor) -> bool:
        """Whether the C kernel encodes ``x``: CPU, float32 or float64, no gradient with respect to the points."""
        return (x.device.type == "cpu" and self.table.device.type == "cpu" and x.dtype in _SUFFIX
                and not x.requires_grad and KERNEL.lib() is not None)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """The concatenated interpolated features (N, L·F) at points ``x`` (N, 3)."""
        if self._native(x):
            return _NativeEncode.apply(x, self.table.to(x.dtype), self)
        return self._encode_torch(x)

    def _encode_torch(self, x: torch.Tensor) -> torch.Tensor:
        """:meth:`encode` in torch (any device and dtype; differentiable with respect to the points too)."""
        idx, w, _, _ = self._cells(x)
        feats = self._gather(idx, x.dtype)
        return (feats * self._trilinear(w).unsqueeze(-1)).sum(2).reshape(x.shape[0], -1)

    def _encode_directional(self, x: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(features (N, L·F), their derivative along ``v`` (N, L·F)); a component of x outside (-1, 1) has
        zero derivative (the clamp)."""
        idx, w, half_res, inside = self._cells(x)
        feats = self._gather(idx, x.dtype)
        # the low vertex's weight 1 − frac falls at R/2 per unit of x, the high one's frac rises at R/2
        rate = (v * inside.to(v.dtype)).unsqueeze(1) * half_res[:, None]  # (N, L, 3)
        dw = torch.stack([-rate, rate], dim=2)  # (N, L, 2, 3)
        wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
        dx, dy, dz = dw[..., 0], dw[..., 1], dw[..., 2]
        dweight = (dz[..., :, None, None] * wy[..., None, :, None] * wx[..., None, None, :]
                   + wz[..., :, None, None] * dy[..., None, :, None] * wx[..., None, None, :]
                   + wz[..., :, None, None] * wy[..., None, :, None] * dx[..., None, None, :]).flatten(-3)
        n = x.shape[0]
        return ((feats * self._trilinear(w).unsqueeze(-1)).sum(2).reshape(n, -1),
                (feats * dweight.unsqueeze(-1)).sum(2).reshape(n, -1))

    # ------------------------------------------------------------------------------------------- network
    def _check(self, x: torch.Tensor) -> None:
        if x.dim() != 2 or x.shape[-1] != self.in_dim:
            what = "points" if self.in_dim == 3 else "points and surface normals"
            raise NeuralBakeError(f"GridNet: expected {what} of shape (N, {self.in_dim}), got {tuple(x.shape)}")

    def _mlp_input(self, features: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """The MLP's input: the grid's ``features``, and with normal inputs the scaled normals of ``x``."""
        if self.normal_scale is None:
            return features
        return torch.cat([features, x[:, 3:] * self.normal_scale], dim=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Values (N, out_dim) at ``x`` (N, in_dim): points, and with normal inputs their unit surface normals;
        in the dtype and device of ``x``."""
        self._check(x)
        return self._mlp(self._mlp_input(self.encode(x[:, :3]), x))

    def _mlp(self, h: torch.Tensor) -> torch.Tensor:
        """The MLP on its input ``h`` (:meth:`_mlp_input`), in ``h``'s dtype."""
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            h = torch.addmm(layer.bias.to(h.dtype), h, layer.weight.to(h.dtype).t())
            if i != last:
                h = torch.relu(h) if self.activation == "relu" else torch.sin(self.omega * h)
        return h

    def directional(self, x: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(g(x) (N, out_dim), J_g(x) v (N, out_dim))``: values and derivatives along ``v`` (N, 3), one forward
        tangent stream (differentiable with respect to the parameters: one ordinary backward trains it). With
        normal inputs ``x`` is (N, 6) and the derivative is the point's alone (the normal held fixed)."""
        self._check(x)
        h, t = self._encode_directional(x[:, :3], v.to(x.dtype))
        if self.normal_scale is not None:
            h, t = self._mlp_input(h, x), torch.cat([t, t.new_zeros(t.shape[0], 3)], dim=1)
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            wt = layer.weight.to(x.dtype).t()
            a = torch.addmm(layer.bias.to(x.dtype), h, wt)
            t = t @ wt
            if i == last:
                h = a
            elif self.activation == "relu":
                on = (a > 0).to(a.dtype)
                h, t = a * on, t * on
            else:
                h, t = torch.sin(self.omega * a), self.omega * torch.cos(self.omega * a) * t
        return h, t

    def extra_repr(self) -> str:
        return (f"levels={self.levels}, features={self.features}, table=2^{self.log2_table}, "
                f"resolution {self.base_resolution}..{self.max_resolution}, MLP (W, D) = ({self.width}, {self.depth}) "
                f"{self.activation}, out={self.out_dim}"
                + ("" if self.normal_scale is None else f", normal inputs ×{self.normal_scale:g}"))
