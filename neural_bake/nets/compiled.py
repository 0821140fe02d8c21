"""Optional ``torch.compile`` of the hot training functions, with a safe eager fallback.

TorchInductor fuses the element-wise work of a SIREN loss (bias, sin/cos, the gradient-stream products,
the loss terms, and all of their backward) into a few C++/OpenMP (CPU) or Triton (CUDA) kernels, leaving
the GEMMs to the BLAS (step timings: BENCHMARKS.md). Compiling costs time once per process, less when
TorchInductor's on-disk cache (``/tmp/torchinductor_<user>``) already holds the kernels; so
:func:`should_compile` turns it on by default only for runs long enough to repay it.

:class:`CompiledFn` wraps a function: the first call compiles it; if compiling fails (no C++ compiler, an
unsupported device, a dynamo error) it warns once (:class:`~neural_bake.errors.NeuralBakeWarning`) and runs
the plain function from then on, so a fit never fails because of the compiler. The wrapped functions must be
pure (no side effects), so re-running one eagerly after a failed compile is safe.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import warnings
from typing import Callable

import torch

from ..errors import NeuralBakeError, NeuralBakeWarning

__all__ = ["COMPILE_MODES", "CompiledFn", "compiler_available", "env_switch", "long_run", "should_compile"]

#: Values of the ``compile`` settings: "auto" (compile long runs where a compiler is available), "on", "off".
COMPILE_MODES = ("auto", "on", "off")

#: Setting this environment variable to 0/off/false turns compiling off everywhere (e.g. on a machine whose
#: compiler misbehaves); "auto" and "on" then mean "off".
ENV_SWITCH = "NEURAL_BAKE_COMPILE"


def env_switch(name: str) -> bool | None:
    """An on/off environment variable: True for 1/on/true/yes, False for 0/off/false/no, None when unset or
    anything else (the default behaviour)."""
    value = os.environ.get(name, "").strip().lower()
    if value in ("1", "on", "true", "yes"):
        return True
    if value in ("0", "off", "false", "no"):
        return False
    return None


def compiler_available(device: torch.device | str) -> bool:
    """Can TorchInductor build kernels for ``device`` here? CPU: a C++ compiler on PATH (``$CXX``, g++,
    clang++); CUDA: Triton importable. Other devices: no."""
    device = torch.device(device)
    if env_switch(ENV_SWITCH) is False:
        return False
    if not hasattr(torch, "compile"):
        return False
    if device.type == "cpu":
        cxx = os.environ.get("CXX")
        return any(shutil.which(c) for c in ([cxx] if cxx else []) + ["g++", "clang++", "c++"])
    if device.type == "cuda":
        try:
            import triton  # noqa: F401
        except ImportError:
            return False
        return True
    return False


def long_run(steps: int, minutes: float | None) -> bool:
    """Does a training run repay a one-off compile? A budget of at least five minutes, or, without a budget,
    at least 5,000 steps (shorter runs spend the faster steps' gain on compiling: docs/findings.md)."""
    if minutes is not None:
        return minutes >= 5.0
    return steps >= 5000


def should_compile(mode: str, device: torch.device | str, *, long_run: bool) -> bool:
    """Resolve a ``compile`` setting: "on" compiles wherever a compiler is available, "auto" only for a
    ``long_run`` (one that repays the one-off compile time), "off" never."""
    if mode not in COMPILE_MODES:
        raise NeuralBakeError(f"compile must be one of {', '.join(COMPILE_MODES)}, got {mode!r}")
    if mode == "off" or (mode == "auto" and not long_run):
        return False
    return compiler_available(device)


#: How many compiled versions (shapes, loss variants, networks) a wrapped function may collect in a process.
#: torch's default is 8 a function, after which dynamo silently runs it eagerly: a time-budgeted (256, 3)
#: fit alone needs 8 (four micro-batch counts, :class:`~neural_bake.fit.sdf_tuning.MicroBatchTuner`, × bf16 and
#: float32 GEMMs), and a process that fits several networks (a benchmark, a batch over assets) needs more.
RECOMPILE_LIMIT = 64


def _recompile_limit(limit: int):
    """Context raising dynamo's per-function recompile limit to ``limit`` (a no-op where torch lacks it)."""
    config = getattr(getattr(torch, "_dynamo", None), "config", None)
    for name in ("recompile_limit", "cache_size_limit"):  # the first is the newer name
        if config is not None and hasattr(config, name):
            return config.patch(**{name: max(int(getattr(config, name)), int(limit))})
    return contextlib.nullcontext()


class CompiledFn:
    """``fn`` compiled with ``torch.compile`` on first use, falling back to ``fn`` itself (with one
    warning naming ``desc``) when compiling or running the compiled version raises. ``enabled=False`` is
    plain ``fn``. :attr:`compiled` tells which one runs (None until the first call). ``backend`` is
    ``torch.compile``'s (TorchInductor by default)."""

    def __init__(self, fn: Callable, *, enabled: bool, desc: str, dynamic: bool = False,
                 backend: str | Callable = "inductor"):
        self.fn, self.desc, self.enabled = fn, desc, bool(enabled)
        self._compiled = torch.compile(fn, dynamic=dynamic, backend=backend) if self.enabled else None
        self.compiled: bool | None = None if self.enabled else False

    def __call__(self, *args, **kwargs):
        if self._compiled is None:
            return self.fn(*args, **kwargs)
        try:
            with _recompile_limit(RECOMPILE_LIMIT):
                out = self._compiled(*args, **kwargs)
        except NeuralBakeError:
            raise
        except Exception as exc:  # a compiler or dynamo failure: never fatal, the eager function is the same math
            self._compiled = None
            self.compiled = False
            root = exc  # dynamo wraps the compiler's error (BackendCompilerFailed, InductorError): name the cause
            while (inner := getattr(root, "inner_exception", None) or root.__cause__) is not None:
                root = inner
            first = (str(root).strip().splitlines() or [""])[0][:200]
            warnings.warn(f"{self.desc}: torch.compile failed ({type(root).__name__}: {first}); running "
                          f"without it", NeuralBakeWarning, stacklevel=2)
            return self.fn(*args, **kwargs)
        self.compiled = True
        return out
