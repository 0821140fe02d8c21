"""Full-batch L-BFGS polish of a network after its stochastic (Adam) training.

Adam on small random batches stalls at a noise floor set by its learning rate and the batch's variance; a
small network that is short of capacity, not of steps, stops there well above the minimum it could reach
(three times the steps do not lower its Hausdorff distance: docs/findings.md). L-BFGS with a strong-Wolfe
line search on one large fixed batch takes curvature-aware steps without that noise. The polish is kept
only if the loss on a second, held-out batch went down (so it cannot over-fit its batch unnoticed) and
every weight is finite; otherwise the weights are restored exactly.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import asdict, dataclass
from typing import Callable, Sequence

import torch

from ..constants import MIN_SECONDS
from ..errors import FitError, NeuralBakeWarning
from .training import _all_finite

__all__ = ["PolishResult", "lbfgs_polish"]

#: L-BFGS iterations per ``step()`` call: between calls the polish checks its evaluation count and deadline
#: (each call re-evaluates its starting point once, so a call of 25 iterations wastes ~3 % of the evaluations;
#: near a deadline a call gets only the evaluations that fit before it, at the rate measured so far).
CHUNK_ITERATIONS = 25


@dataclass
class PolishResult:
    """What a polish did (all losses on the polish's own loss function)."""

    evals: int
    """Loss evaluations with gradient on the polish batch (line-search evaluations included)."""
    seconds: float
    """Wall time, the two held-out evaluations included."""
    loss_before: float
    """Loss on the polish batch at the start."""
    loss_after: float
    """Loss on the polish batch at the end (before any restore)."""
    check_before: float
    """Loss on the held-out batch at the start."""
    check_after: float
    """Loss on the held-out batch at the end (before any restore)."""
    kept: bool
    """Whether the polished weights were kept (else the model holds its weights from before the polish)."""
    reason: str
    """"kept", "held-out loss rose", "non-finite weights or loss" or "no time left"."""

    def to_dict(self) -> dict:
        """JSON-able (non-finite losses become None)."""
        return {k: ((round(v, 9) if math.isfinite(v) else None) if isinstance(v, float) else v)
                for k, v in asdict(self).items()}


class _NonFinite(Exception):
    """A polish evaluation returned a non-finite loss."""


def lbfgs_polish(model: torch.nn.Module, loss_fn: Callable[[Sequence[torch.Tensor]], torch.Tensor],
                 fit_batch: Sequence[torch.Tensor], check_batch: Sequence[torch.Tensor], *, evals: int,
                 deadline: float | None = None, clock: Callable[[], float] = time.perf_counter,
                 history_size: int = 50, progress: bool = False, desc: str = "polish") -> PolishResult:
    """Polish ``model``'s trainable parameters with L-BFGS on ``fit_batch``, in place.

    Args:
        model: the trained network (its parameters with ``requires_grad`` are optimised).
        loss_fn: ``loss_fn(batch)`` → the batch's loss (a scalar tensor; it may be detached) after leaving the
            loss's gradient in the parameters' ``.grad`` (which the polish sets to None before each call),
            e.g. by calling ``backward()`` itself, in parts if it likes.
        fit_batch: the fixed batch the polish minimises the loss on.
        check_batch: a held-out batch: the polish is kept only if its loss went down.
        evals: the number of ``loss_fn(fit_batch)`` calls to spend (≥ 1).
        deadline: a ``clock()`` value after which no new L-BFGS call starts (None: none).
        clock: the seconds the deadline and the result's ``seconds`` are measured in.
        history_size: L-BFGS's number of curvature pairs.
        progress: show a progress bar over the evaluations.

    Returns:
        A :class:`PolishResult`. The parameters' ``.grad`` are None on return.
    """
    if int(evals) != evals or evals < 1:
        raise FitError(f"{desc}: evals must be a positive integer, got {evals!r}")
    params = [p for p in model.parameters() if p.requires_grad]
    if not params:
        raise FitError(f"{desc}: the model has no trainable parameters")
    t0 = clock()
    saved = [p.detach().clone() for p in params]

    def value(batch) -> float:
        for p in params:
            p.grad = None
        return float(loss_fn(batch))

    check_before = value(check_batch)
    per_eval = clock() - t0  # the rate until the polish has measured its own
    count = 0
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=int(evals), desc=desc, leave=False, dynamic_ncols=True)

    def closure():
        nonlocal count
        count += 1
        if bar is not None:
            bar.update(1)
        for p in params:
            p.grad = None
        loss = loss_fn(fit_batch)
        if not math.isfinite(float(loss)):  # torch's line search cannot bracket a NaN: stop here
            raise _NonFinite
        return loss

    opt = torch.optim.LBFGS(params, lr=1.0, max_iter=CHUNK_ITERATIONS, history_size=history_size,
                            line_search_fn="strong_wolfe")
    loss_before = math.nan
    diverged = False
    try:
        t_run = clock()
        while count < evals:
            budget = min(int(evals) - count, CHUNK_ITERATIONS * 5 // 4)
            if deadline is not None:
                now = clock()
                if now >= deadline:
                    break
                if count:
                    per_eval = (now - t_run) / count
                # no call that would run past the deadline, at the rate measured so far
                budget = min(budget, int((deadline - now) / max(per_eval, MIN_SECONDS)))
                if budget < 2:
                    break
            opt.param_groups[0]["max_eval"] = max(2, budget)
            start = count
            loss = float(opt.step(closure))  # the loss at the call's starting point
            if start == 0:
                loss_before = loss
            if count - start <= 1:  # converged: nothing left to do
                break
    except _NonFinite:
        diverged = True
    finally:
        if bar is not None:
            bar.close()
    if count == 0:
        loss_after = loss_before = value(fit_batch)
        check_after = check_before
    else:
        loss_after = value(fit_batch)
        check_after = value(check_batch)
    finite = not diverged and _all_finite(params) and math.isfinite(loss_after) and math.isfinite(check_after)
    if count == 0:
        reason = "no time left"
    elif not finite:
        reason = "non-finite weights or loss"
    elif check_after > check_before:
        reason = "held-out loss rose"
    else:
        reason = "kept"
    kept = reason == "kept"
    if not kept:
        with torch.no_grad():
            for p, s in zip(params, saved):
                p.copy_(s)
        if count:
            warnings.warn(f"{desc}: {reason} (held-out loss {check_before:.4g} -> {check_after:.4g}); "
                          "kept the weights from before the polish", NeuralBakeWarning, stacklevel=2)
    for p in params:
        p.grad = None
    return PolishResult(evals=count, seconds=clock() - t0, loss_before=loss_before,
                        loss_after=loss_after, check_before=check_before, check_after=check_after, kept=kept,
                        reason=reason)
