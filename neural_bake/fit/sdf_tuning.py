"""How an SDF training step runs fast on this device: its micro-batch count (:func:`micro_batch_count`,
:class:`MicroBatchTuner`) and whether bfloat16 hidden GEMMs pay (:func:`_bf16_pays`)."""

from __future__ import annotations

import math
import time

import torch

from ..nets.cpu_gemm import gemm_route
from .sdf_config import SdfFitConfig

__all__ = ["TRAIN_CHUNK_ELEMENTS", "TUNE_EVERY", "micro_batch_count", "MicroBatchTuner"]


#: Hidden activations (points × width) per training micro-batch that ``micro_batches=0`` aims at: a
#: (256, 3) step's working set per layer then stays in a core's 1 MB L2 (step timings: docs/findings.md).
TRAIN_CHUNK_ELEMENTS = 1 << 18


def micro_batch_count(cfg: SdfFitConfig, n_points: int, device) -> int:
    """How many micro-batches a step of ``n_points`` points runs in (``cfg.micro_batches``; 0: auto)."""
    if cfg.micro_batches:
        return int(cfg.micro_batches)
    if torch.device(device).type != "cpu" or n_points * cfg.width <= TRAIN_CHUNK_ELEMENTS:
        return 1
    return 2 ** max(0, round(math.log2(n_points * cfg.width / TRAIN_CHUNK_ELEMENTS)))


#: Steps between two re-tunings of the micro-batch count of a time-budgeted run (:class:`MicroBatchTuner`).
TUNE_EVERY = 200


class MicroBatchTuner:
    """The micro-batch count of a time-budgeted CPU run (``micro_batches=0``), chosen by timing real steps.

    Which count is fastest depends on the machine and on its moment (its cache sizes, the memory traffic of
    other work on it: docs/findings.md). So the tuner runs the powers of two from 1 up to the rule's count
    (:func:`micro_batch_count`), at most four of them, in interleaved rounds on the run's own steps (``rounds``
    steps each; the first tuning of a loss variant runs one more round, untimed, which pays any compile of its
    shapes), keeps the fastest, and tunes again every ``every`` steps and whenever ``key`` (the loss variant:
    bf16 or float32 GEMMs, and the CPU thread count) changes; a change of key in the middle of a tuning drops
    that tuning (its timings would compare different settings). The steps it times are training steps like the others: the parts'
    gradients add up to the whole batch's for any count, so tuning costs only the few steps run at a slower
    count. Only for time-budgeted runs, which depend on the machine's speed anyway; a run with a step count
    keeps the rule's count so that a seed reproduces bit for bit."""

    def __init__(self, rule: int, *, rounds: int = 2, every: int = TUNE_EVERY):
        top = max(1, int(rule))
        self.candidates = [1 << i for i in range(top.bit_length()) if (1 << i) <= top][-4:]
        self.rounds, self.every = int(rounds), int(every)
        self.choice = top
        self.history: list[dict] = []  # one per tuning: the step it began at, the variant, seconds per count
        self._queue: list[tuple[int, bool]] = []  # (count, timed) of the tuning under way
        self._times: dict[int, float] = {}
        self._seen: set = set()
        self._key = None
        self._last = None

    def next(self, step: int, key=None) -> tuple[int, bool]:
        """The count for this step and whether to time it (then report with :meth:`record`)."""
        if len(self.candidates) == 1:
            return self.choice, False
        if self._queue and key != self._key:  # the key changed mid-tuning: its timings would be mixed
            self._queue, self._times = [], {}
        if not self._queue and (key != self._key or self._last is None or step - self._last >= self.every):
            self._key, self._last, self._times = key, step, {}
            warm = key not in self._seen
            self._seen.add(key)
            # (count, timed): the warm-up round of a new variant is not timed
            self._queue = [(k, r >= warm) for r in range(self.rounds + warm) for k in self.candidates]
        return self._queue.pop(0) if self._queue else (self.choice, False)

    def record(self, k: int, seconds: float) -> None:
        """A timed step's seconds; after the tuning's last step, the fastest count becomes the choice."""
        self._times[k] = min(self._times.get(k, math.inf), float(seconds))
        if not self._queue:
            self.choice = min(self._times, key=self._times.get)
            self.history.append({"step": int(self._last), "variant": str(self._key), "choice": self.choice,
                                 "seconds": {int(c): round(t, 5) for c, t in sorted(self._times.items())}})


def _bf16_pays(cfg: SdfFitConfig, device, dtype) -> bool:
    """gemm_dtype="auto": does a bf16 W×W GEMM beat a float32 one by 1.5× on this device (measured)?"""
    if cfg.depth < 1 or cfg.width < 128 or dtype != torch.float32:
        return False
    a = torch.rand(4096, cfg.width, device=device)
    w = torch.rand(cfg.width, cfg.width, device=device)
    best = {}
    with gemm_route(cfg.width, device):  # float32 as the training loop runs it (nets.cpu_gemm)
        for name, (x, y) in {"f32": (a, w), "bf16": (a.bfloat16(), w.bfloat16())}.items():
            times = []
            for _ in range(6):
                t0 = time.perf_counter()
                torch.mm(x, y).sum().item()  # .item(): waits for an asynchronous device
                times.append(time.perf_counter() - t0)
            best[name] = min(times[1:])
    return best["f32"] >= 1.5 * best["bf16"]

