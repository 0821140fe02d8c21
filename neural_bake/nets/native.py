"""Small C kernels built on first use with the system's C compiler and loaded with ctypes.

A kernel is one C file beside the module that uses it. :func:`build` compiles it with ``$CC`` (else cc, gcc or
clang) into ``$XDG_CACHE_HOME/neural_bake`` (else ``~/.cache/neural_bake``, else the temp folder), named by the
file's stem and a hash of its source, the flags, the compiler and the platform, written atomically (a concurrent
process sees no file or the whole one), and loads it. Every caller keeps a pure numpy or torch path for when
no compiler is found, the build fails or its switch is off, and says which one ran.

A kernel built with ``openmp=True`` splits its loops over torch's own OpenMP team (``#pragma omp`` under
``_OPENMP``, the thread count passed in by the caller: :func:`threads`). It is compiled with ``-fopenmp`` only
where torch's parallel backend is GNU OpenMP and the process maps torch's ``libgomp.so.1`` (:func:`torch_openmp`):
the kernel's dependency on that soname then binds to the runtime already loaded, so the kernel's parallel
regions run on the worker threads torch's GEMMs leave spinning instead of starting a second pool. Elsewhere (or
when ``-fopenmp`` does not build) the same file builds without it and runs on the calling thread. Every split
is by whole outputs, so a kernel gives the same bits with any thread count.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import re
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

from ..geometry import query_threads
from .compiled import env_switch

__all__ = ["Kernel", "build", "cache_dir", "compiler", "torch_openmp", "openmp_runtimes", "threads", "FLAGS"]

#: Optimised, position independent, no errno from libm; no contraction into FMAs, so a kernel's arithmetic
#: is the same, operation by operation, as the numpy reference it replaces.
FLAGS = ("-O3", "-fPIC", "-shared", "-fno-math-errno", "-ffp-contract=off")


def cache_dir() -> Path:
    """The folder compiled kernels are kept in (created; the first writable of the module docstring's)."""
    base = os.environ.get("XDG_CACHE_HOME") or (Path.home() / ".cache")
    for d in (Path(base) / "neural_bake", Path(tempfile.gettempdir()) / f"neural_bake-{os.getuid()}"):
        try:
            d.mkdir(parents=True, exist_ok=True)
            if os.access(d, os.W_OK):
                return d
        except OSError:
            continue
    raise OSError("no writable cache folder")


_compilers: dict[tuple[str | None, str | None], str | None] = {}


def compiler() -> str | None:
    """The C compiler's path ($CC, cc, gcc, clang: the first found), or None; looked up once per $CC and $PATH."""
    key = (os.environ.get("CC"), os.environ.get("PATH"))
    if key not in _compilers:
        found = (shutil.which(c) for c in (key[0], "cc", "gcc", "clang") if c)
        _compilers[key] = next((path for path in found if path), None)
    return _compilers[key]


_openmp: dict = {}


def openmp_runtimes(names) -> list[str]:
    """The OpenMP runtimes among mapped library file ``names`` that a kernel built with ``-fopenmp`` could bind
    to. A runtime a wheel vendors under a hashed name (``libgomp-e985bcbb.so.1.0.0``: auditwheel renames it and
    its soname) is that wheel's own, and is left out."""
    return sorted(n for n in names if n.startswith(("libgomp", "libiomp", "libomp")) and not _VENDORED.match(n))


#: A runtime renamed by auditwheel: its name, a dash, eight hex digits.
_VENDORED = re.compile(r"^lib(gomp|iomp5?|omp)-[0-9a-f]{8}\.so")


def torch_openmp() -> tuple[bool, str]:
    """``(usable, why)``: whether a kernel compiled with ``-fopenmp`` shares torch's OpenMP runtime here (torch's
    parallel backend is OpenMP and the process maps a ``libgomp.so.1``, the soname ``-fopenmp`` links to, and
    no other OpenMP runtime but those wheels vendor under their own names: :func:`openmp_runtimes`). Checked once
    per process, after importing torch."""
    if "state" not in _openmp:
        import torch

        info = torch.__config__.parallel_info()
        try:
            with open("/proc/self/maps") as fh:
                names = {Path(line.split()[-1]).name for line in fh if "/" in line}
        except OSError:
            names = set()
        runtimes = openmp_runtimes(names)
        if "ATen parallel backend: OpenMP" not in info:
            state = (False, "torch's parallel backend is not OpenMP")
        elif runtimes != ["libgomp.so.1"]:
            state = (False, f"torch's OpenMP runtime is {', '.join(runtimes) or 'not found'}, not libgomp.so.1")
        else:
            state = (True, "torch's libgomp.so.1")
        _openmp["state"] = state
    return _openmp["state"]


def threads() -> int:
    """The thread count a parallel kernel call runs with: torch's (``torch.get_num_threads()``, what the thread
    probe of :mod:`neural_bake.nets.threads` or ``--threads`` set)."""
    import torch  # noqa: F401  (loaded, so query_threads reads its count)

    return query_threads()


def build(source: Path, *, switch: str, flags: tuple[str, ...] = FLAGS,
          openmp: bool = False) -> tuple[ctypes.CDLL | None, str]:
    """``(library, message)``: ``source`` compiled and loaded, or ``(None, why not)``.

    ``switch`` names the environment variable that turns the kernel off (0/off/false). ``openmp``: compiled
    with ``-fopenmp`` where :func:`torch_openmp` allows it (else, or when that build fails, without it; the
    message says which)."""
    if env_switch(switch) is False:
        return None, f"off ({switch}=0)"
    cc = compiler()
    if cc is None:
        return None, "no C compiler found"
    if openmp:
        usable, why = torch_openmp()
        if usable:
            lib, msg = build(source, switch=switch, flags=(*flags, "-fopenmp"))
            if lib is not None:
                return lib, f"{msg}, OpenMP on {why}"
            why = msg
        lib, msg = build(source, switch=switch, flags=flags)
        return lib, msg if lib is None else f"{msg}, one thread ({why})"
    src = Path(source).read_bytes()
    key = hashlib.sha256(src + " ".join(flags).encode() + cc.encode() + platform.machine().encode()).hexdigest()[:16]
    try:
        lib_path = cache_dir() / f"{Path(source).stem}-{key}.so"
        if not lib_path.is_file():
            tmp = lib_path.with_name(f".{lib_path.name}.{os.getpid()}.tmp")
            proc = subprocess.run([cc, *flags, "-o", str(tmp), str(source), "-lm"], capture_output=True,
                                  text=True, timeout=120)
            if proc.returncode != 0:
                tmp.unlink(missing_ok=True)
                first = (proc.stderr.strip().splitlines() or ["?"])[0][:200]
                return None, f"the C kernel did not build ({first})"
            os.replace(tmp, lib_path)
        return ctypes.CDLL(str(lib_path)), f"C kernel ({Path(cc).name}, {lib_path.name})"
    except (OSError, subprocess.SubprocessError) as exc:
        return None, f"the C kernel could not be built or loaded ({exc})"


class Kernel:
    """A C file built and loaded on first use (:func:`build`), once per process, thread-safe.

    ``declare(lib)`` sets the entries' ctypes signatures; ``openmp``: see :func:`build`. :meth:`lib` is the
    library or None (the caller's numpy or torch path runs); :meth:`status` says which runs and why."""

    def __init__(self, source: Path, *, switch: str, declare, openmp: bool = False):
        self.source, self.switch, self.declare, self.openmp = Path(source), switch, declare, bool(openmp)
        self._lock = threading.Lock()
        self._state: dict = {}

    def lib(self) -> ctypes.CDLL | None:
        if "lib" not in self._state:
            with self._lock:
                if "lib" not in self._state:
                    lib, msg = build(self.source, switch=self.switch, openmp=self.openmp)
                    if lib is not None:
                        try:
                            self.declare(lib)
                        except AttributeError as exc:
                            lib, msg = None, f"the C kernel could not be built or loaded ({exc})"
                    self._state.update(lib=lib, status=msg)
        return self._state["lib"]

    def status(self) -> str:
        """The C kernel (and its file) when it runs, else "numpy (why not)"."""
        lib = self.lib()
        return self._state["status"] if lib is not None else f"numpy ({self._state['status']})"
