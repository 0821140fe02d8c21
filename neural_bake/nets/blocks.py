"""SIRENs whose hidden units fall into independent blocks, evaluated block by block.

A residual SDF (a coarse level plus a fine one, :func:`~neural_bake.nets.siren_sum.siren_sum`) is kept as one
SIREN whose hidden W×W matrices are block-diagonal: the levels' units side by side, zeros between them. Its
output is the sum of the blocks' own networks (each block's rows of the first layer, its diagonal blocks, its
columns of the last layer; the output bias once), and so is its gradient. The no-grad paths on the CPU
(:func:`~neural_bake.nets.gemm.gemm_gradient`, :func:`~neural_bake.nets.siren.siren_forward_inference`)
evaluate the blocks one after another and add them, so the zero blocks cost no product: a (64 + 128, 3)
sum takes 56 % of the merged network's hidden multiply-adds (BENCHMARKS.md, "normals").

:func:`hidden_blocks` finds the blocks from the matrices themselves (exact zeros), so a model file needs no
mark; blocks narrower than :data:`MIN_BLOCK` are joined to a neighbour, and a split that would save less than
:data:`MIN_SAVING` of the hidden products is not made.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["hidden_blocks", "split_layers", "MIN_BLOCK", "MIN_SAVING"]

#: Hidden units of the narrowest block evaluated on its own (narrower ones join a neighbour).
MIN_BLOCK = 16

#: The share of the merged network's hidden multiply-adds a split must save to be made.
MIN_SAVING = 0.25


def _crossed(weights: list[torch.Tensor], width: int) -> np.ndarray:
    """(width − 1,) bool: whether some nonzero of ``weights`` links a unit before boundary j (1 … width − 1) with
    one at or after it."""
    nz = np.zeros((width, width), dtype=bool)
    for w in weights:
        nz |= w.detach().cpu().numpy() != 0
    idx = np.arange(width)
    has = nz.any(axis=1)
    first = np.where(has, nz.argmax(axis=1), idx)  # first nonzero column of each row
    last = np.where(has, width - 1 - nz[:, ::-1].argmax(axis=1), idx)
    lo, hi = np.minimum(idx, first), np.maximum(idx, last)  # each row's links span [lo, hi]
    diff = np.bincount(lo + 1, minlength=width + 1) - np.bincount(hi + 1, minlength=width + 1)
    return np.cumsum(diff)[1:width] > 0


def hidden_blocks(layers: list[tuple[torch.Tensor, torch.Tensor]]) -> list[tuple[int, int]]:
    """Ranges ``[(start, stop)]`` of hidden units that no hidden W×W matrix of ``layers`` (ω folded in, as
    :meth:`~neural_bake.nets.siren.Siren.affine_layers`) links to another range; ``[(0, W)]`` when the network
    does not split (one block, no hidden matrix, blocks that save less than :data:`MIN_SAVING`)."""
    width = int(layers[0][0].shape[0])
    hidden = [w for w, _ in layers[1:-1]]
    if not hidden or width < 2 * MIN_BLOCK or any(tuple(w.shape) != (width, width) for w in hidden):
        return [(0, width)]
    if any(bool(w[0, -1] != 0) or bool(w[-1, 0] != 0) for w in hidden):  # a dense network: its corners link all
        return [(0, width)]
    free = np.flatnonzero(~_crossed(hidden, width)).tolist()
    bounds = [0]
    for j in (j + 1 for j in free):  # boundary j lies between units j − 1 and j
        if j - bounds[-1] >= MIN_BLOCK and width - j >= MIN_BLOCK:
            bounds.append(j)
    bounds.append(width)
    blocks = list(zip(bounds[:-1], bounds[1:]))
    if len(blocks) < 2 or sum((b - a) ** 2 for a, b in blocks) > (1.0 - MIN_SAVING) * width * width:
        return [(0, width)]
    return blocks


def split_layers(layers: list[tuple[torch.Tensor, torch.Tensor]],
                 blocks: list[tuple[int, int]]) -> list[list[tuple[torch.Tensor, torch.Tensor]]]:
    """The layers of each block's own network (contiguous copies); their outputs add up to the network's. The
    output bias goes to the first block, zeros to the others. One block: ``[layers]`` itself."""
    if len(blocks) < 2:
        return [layers]
    (w0, b0), *mid, (wn, bn) = layers
    parts = []
    for k, (a, b) in enumerate(blocks):
        part = [(w0[a:b].contiguous(), b0[a:b].contiguous())]
        part += [(w[a:b, a:b].contiguous(), bias[a:b].contiguous()) for w, bias in mid]
        part.append((wn[:, a:b].contiguous(), bn if k == 0 else torch.zeros_like(bn)))
        parts.append(part)
    return parts
