"""The record every fit returns: the network, the frame it lives in, its settings and how it was trained.

:class:`FitRecord` holds what every fitter (SDF, space-time) reports of its training loop; a fitter's result
class derives from it and adds its own fields. :meth:`FitRecord.training` is the ``training`` table of the
model file's metadata, and :meth:`FitRecord.training_fields` reads it back.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..nets.siren import Siren
from ..types import Frame
from .training import LoopSettings

__all__ = ["FitRecord"]

#: History rows a model file keeps (the last ones).
HISTORY_KEPT = 200


@dataclass
class FitRecord:
    """A fitted network with its frame, settings and training record (the shape every fit result shares)."""

    model: Siren
    """The fitted network (unit-frame inputs; its input and output are the fitter's)."""
    frame: Frame
    """Source ↔ unit frame transform of what it was fitted to."""
    history: list[dict] = field(default_factory=list)
    """Logged steps: ``step``, ``seconds``, ``lr``, ``loss`` and each loss term."""
    steps: int = 0
    """Optimiser steps done."""
    seconds: float = 0.0
    """Training wall time (pool sampling included)."""
    config: LoopSettings = field(default_factory=LoopSettings)
    """The settings used (the fitter's config class)."""
    stopped_reason: str = "steps"
    """"steps", "time budget" or "resumed finished run"."""
    restarts: int = 0
    """Divergence recoveries (learning-rate halvings)."""
    threads: dict | None = None
    """The CPU threads the steps ran with (:meth:`~neural_bake.nets.threads.ThreadTuner.summary`: the count in
    force, every count that ran, each measured decision); None when not recorded."""

    def training(self) -> dict:
        """The ``training`` table of the model file: steps, seconds, why it stopped, restarts, the last logged
        row (``final``), the last :data:`HISTORY_KEPT` rows and the threads."""
        return {"steps": self.steps, "seconds": round(self.seconds, 3), "stopped_reason": self.stopped_reason,
                "restarts": self.restarts, "final": self.history[-1] if self.history else {},
                "history": self.history[-HISTORY_KEPT:], "threads": self.threads}

    @staticmethod
    def training_fields(training) -> dict:
        """The :class:`FitRecord` fields of a model file's ``training`` table (anything not a dict: none)
        (TypeError or ValueError for a value of the wrong kind)."""
        t = training if isinstance(training, dict) else {}
        return {"history": list(t.get("history", [])), "steps": int(t.get("steps", 0)),
                "seconds": float(t.get("seconds", 0.0)), "stopped_reason": str(t.get("stopped_reason", "")),
                "restarts": int(t.get("restarts", 0)),
                "threads": t.get("threads") if isinstance(t.get("threads"), dict) else None}
