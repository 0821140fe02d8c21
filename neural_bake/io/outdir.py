"""Outputs that never lose data: folders committed as a unit, one writer per output, leftovers removed.

An output folder OUT is built in a staging folder beside it (``.OUT.stage-PID-XXXX``, same parent, so the
same file system) and committed by exchanging the two names in one system call (Linux
``renameat2(RENAME_EXCHANGE)``): whenever the process dies, a reader of OUT sees the whole old set or the whole
new set. The old set, now under the staging name, is removed only after the exchange. The new set holds only
this run's files; a folder holding files that no neural-bake run wrote is refused, never replaced.

Why a swap and not a versioned subfolder behind a pointer: OUT stays a plain folder holding the files
themselves (no symlink to follow, copy or archive, and no pointer convention for readers to know), and the
exchange is as atomic as a pointer replacement. Where the exchange is not available (not Linux, or a file
system without it) two renames do it: OUT -> ``.OUT.old-PID-XXXX``, stage -> OUT. A process killed between
them leaves no OUT for a moment; the next run for OUT moves the old set back before anything else. SIGINT
and SIGTERM arriving during the renames are held until they are done.

One writer per output: :class:`OutputLock` holds an ``fcntl.flock`` on ``.OUT.lock`` beside the output (a
file or a folder), which names the holder's pid; a second run fails at once naming it. Under the lock, the
leftovers of runs that died (staging folders, old sets, atomic temporary files, all named with the pid that
made them) are removed once their pid is gone — and, since only the lock holder writes, any other pid's.

An output that is a symlink is followed (:func:`~neural_bake.io.atomic.link_target`): the lock, the staging
folder and the leftovers live beside the link's target, the commit happens at the target, and the link stays a
link to the new set; messages name the user's path. Nothing here follows a symlink into a tree to delete it: a
link found among the files to remove is unlinked, never walked.

Each step of the commit calls :func:`~neural_bake.io.faults.fault_point` with a name from
:data:`COMMIT_STEPS`, so the fault-injection tests can kill the process at any of them.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import json
import os
import re
import shutil
import signal
import stat
import sys
import tempfile
from pathlib import Path
from typing import Iterator

from ..errors import OutputBusyError, OutputError, WriteError, os_error
from .atomic import atomic_write_text, link_target, replacement_mode
from .faults import fault_point

__all__ = ["OutputFolder", "OutputLock", "locked_outputs", "record_in_set", "MANIFEST", "COMMIT_STEPS", "NO_EXCHANGE_ENV"]

#: The file inside a committed folder that lists its set (JSON: format, files, pid).
MANIFEST = ".neural-bake-set.json"
MANIFEST_FORMAT = "neural_bake.output_set.v1"

#: Named steps of a folder commit, in order (fault-injection points; "moved-old" only in the two-rename way).
COMMIT_STEPS = ("locked", "staged", "moved-old", "exchanged", "removing-old", "cleaned")

#: Set (to anything) to commit with two renames even where the atomic exchange exists (tests of that path).
NO_EXCHANGE_ENV = "NEURAL_BAKE_NO_EXCHANGE"

_AT_FDCWD = -100
_RENAME_NOREPLACE = 1
_RENAME_EXCHANGE = 2


def _renameat2(src: Path, dst: Path, flags: int) -> bool:
    """Linux renameat2; False where the call or the flag is not supported (the caller falls back)."""
    if os.environ.get(NO_EXCHANGE_ENV) or not sys.platform.startswith("linux"):
        return False
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):  # a C library without the wrapper (glibc < 2.28, musl)
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), flags) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(dst))


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _is_real_dir(path: Path) -> bool:
    """A folder and not a symlink to one (a link is an entry to unlink, never a tree to walk)."""
    try:
        return stat.S_ISDIR(os.lstat(path).st_mode)
    except OSError:
        return False


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def _signals_deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back for the body, then let the handlers in force act on them.

    Python-level handlers (not a thread signal mask): a process-directed signal may be delivered to any
    thread, but Python runs its handler in the main thread, between two renames if it were not held here.
    Outside the main thread handlers cannot be changed and the body runs as it is.
    """
    caught: list[int] = []
    previous: dict = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda signum, frame: caught.append(signum))
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(caught):
            signal.raise_signal(sig)


class OutputLock:
    """One writer per output: an exclusive ``flock`` on ``.NAME.lock`` beside ``path`` (file or folder).

    ``with OutputLock(path):`` takes the lock without waiting — :class:`OutputBusyError` naming the holder's
    pid if another process has it — then removes the leftovers of dead runs for ``path`` (and, for a folder
    committed with two renames, moves an old set back into place). The lock file is removed on release.
    A symlink ``path`` is locked at its target (``target``), so every path to one output takes one lock.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.target = link_target(self.path)
        self.parent = self.target.parent if str(self.target.parent) else Path(".")
        self.lock_path = self.parent / f".{self.target.name}.lock"
        self._fd: int | None = None

    def __enter__(self) -> "OutputLock":
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def acquire(self) -> None:
        while True:
            try:
                fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise os_error(exc, self.path) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 64).decode(errors="replace").strip() or "unknown"
                os.close(fd)
                raise OutputBusyError(f"{self.path}: another neural-bake run (pid {holder}) is writing it; wait for "
                                      f"it to finish or choose another output") from None
            # the holder before us may have unlinked the file while we waited to open it: lock the one on disk
            try:
                same = os.stat(self.lock_path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except OSError as exc:  # a full disk, say: the lock file goes, the error names the output
            with contextlib.suppress(OSError):
                os.unlink(self.lock_path)
            os.close(fd)
            raise os_error(exc, self.path) from None
        self._fd = fd
        try:
            self._recover()
            fault_point("locked")
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        if self._fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.lock_path)  # while still holding it: a waiter re-checks the inode and retries
        os.close(self._fd)
        self._fd = None

    # ------------------------------------------------------------------------------------------ leftovers
    def _leftovers(self) -> list[tuple[str, int, Path]]:
        """(kind, pid, path) of every staging folder, old set and temporary file of this output."""
        name = re.escape(self.target.name)
        pattern = re.compile(rf"^\.{name}\.(?:(stage|old)-(\d+)-[^/]+|(\d+)\.[^.]+\.tmp.*)$")
        found = []
        try:
            entries = list(os.scandir(self.parent))
        except OSError as exc:
            raise os_error(exc, self.path) from None
        for entry in entries:
            m = pattern.match(entry.name)
            if m:
                kind = m.group(1) or "tmp"
                found.append((kind, int(m.group(2) or m.group(3)), Path(entry.path)))
        return found

    def _recover(self) -> None:
        """Under the lock: undo a two-rename commit cut between its renames, then remove dead runs' files.

        Only the lock holder writes, so no other living run owns any of them; the pid check keeps this safe
        even for a process that holds leftovers and never took the lock.
        """
        me = os.getpid()
        found = [f for f in self._leftovers() if f[1] != me and not _pid_alive(f[1])]
        olds = sorted((p for kind, _, p in found if kind == "old" and _is_real_dir(p)),
                      key=lambda p: p.lstat().st_mtime)
        if olds and not os.path.lexists(self.target):
            # OUT missing beside an old set: a two-rename commit cut between its renames; the old set goes back
            os.rename(olds[-1], self.target)
            _fsync_dir(self.parent)
        for _, _, p in found:
            if _is_real_dir(p):
                shutil.rmtree(p, ignore_errors=True)  # unlinks the symlinks inside, never follows them
            else:
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()


@contextlib.contextmanager
def locked_outputs(*paths: str | os.PathLike | None) -> Iterator[None]:
    """Lock every given output file path (None entries skipped) for the body; check their folders exist.

    For verbs that write single files atomically (model files, checkpoints, JSON): a second run writing any of
    them fails at once, and the temporary files of killed runs are removed.
    """
    with contextlib.ExitStack() as stack:
        for p in dict.fromkeys(Path(p).absolute() for p in paths if p is not None):
            if p.is_dir():
                raise OutputError(f"{p}: is a folder (expected a file path)")
            if not p.parent.is_dir():
                raise OutputError(f"{p}: folder {p.parent} does not exist")
            stack.enter_context(OutputLock(p))
        yield


class OutputFolder:
    """An output folder written as a unit: ``with OutputFolder(out) as stage:`` write files into ``stage``.

    On entry: checks ``out`` (its parent exists, it is not a file, it holds only a set an earlier run
    committed), takes the lock (:class:`OutputLock`), creates the staging folder. A body that returns commits
    (the new set replaces the old one in one exchange; the old set is removed after); a body that raises
    removes the staging folder and leaves ``out`` as it was. An OSError of the body or of the commit becomes
    one :class:`~neural_bake.errors.WriteError` line naming ``out`` (never the staging folder); a
    NeuralBakeError whose message names a staging path is re-worded to name the output instead.

    A symlink ``out`` is followed: the set is committed at the folder it points to (``target``), which a
    dangling link's target becomes; the link stays.

    ``out``: the folder (str or path). ``stage``: a :class:`pathlib.Path`, empty on entry.
    """

    def __init__(self, out: str | os.PathLike):
        self.out = Path(out)
        self.stage: Path | None = None
        self._lock = OutputLock(self.out)
        self.target = self._lock.target

    # ---------------------------------------------------------------------------------------- entering
    def __enter__(self) -> Path:
        out = self.out
        if out.exists() and not out.is_dir():
            raise OutputError(f"{out}: exists and is not a folder")
        if not self._lock.parent.is_dir():
            raise OutputError(f"{out}: folder {self._lock.parent} does not exist")
        self._lock.acquire()
        try:
            self._check_foreign()
            try:
                self.stage = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.stage-{os.getpid()}-",
                                                   dir=self._lock.parent))
                # mkdtemp's 0700 would become the output's mode
                os.chmod(self.stage, replacement_mode(self.target, 0o777))
            except OSError as exc:
                raise os_error(exc, out) from None
        except BaseException:
            self._lock.release()
            raise
        return self.stage

    def _check_foreign(self) -> None:
        """Refuse an existing folder holding anything that is not a committed set's file."""
        if not self.target.is_dir():
            return
        try:
            names = set(os.listdir(self.target))
        except OSError as exc:
            raise os_error(exc, self.out) from None
        listed: set[str] = set()
        if MANIFEST in names:
            try:
                listed = set(json.loads((self.target / MANIFEST).read_text(encoding="utf-8"))["files"])
            except (OSError, ValueError, KeyError, TypeError):
                listed = set()
        foreign = sorted(names - listed - {MANIFEST})
        if foreign:
            shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
            raise OutputError(f"{self.out}: holds files no neural-bake run wrote there ({shown}); an output "
                              f"folder is replaced as a whole, so choose an empty or new folder")

    # ----------------------------------------------------------------------------------------- leaving
    def __exit__(self, exc_type, exc, tb) -> bool:
        stage = self.stage
        try:
            if exc_type is None:
                self._commit(stage)
                return False
            self._discard()
            if isinstance(exc, OSError):
                raise self._os_error(exc, stage) from None
            self._reword(exc, stage)
            return False
        finally:
            self._lock.release()

    def _discard(self) -> None:
        if self.stage is not None:
            shutil.rmtree(self.stage, ignore_errors=True)
            self.stage = None

    def shown(self, path, stage: Path | None = None) -> str:
        """``path`` as the user will see it: a path inside the staging folder as the same path inside ``out``."""
        where, stage = os.fspath(path), stage if stage is not None else self.stage
        if stage is not None and where.startswith(os.fspath(stage)):
            return str(self.out) + where[len(os.fspath(stage)):]
        return where

    def _os_error(self, exc: OSError, stage: Path | None) -> WriteError:
        """The one-line error for ``exc``, naming ``out`` (or the same file inside it), never the stage."""
        where = self.shown(exc.filename, stage) if exc.filename is not None else str(self.out)
        return os_error(exc, where if where.startswith(str(self.out)) else self.out)

    def _reword(self, exc: BaseException, stage: Path | None) -> None:
        """A NeuralBakeError naming the staging folder names ``out`` instead."""
        from ..errors import NeuralBakeError

        if isinstance(exc, NeuralBakeError) and stage is not None and os.fspath(stage) in str(exc):
            exc.args = (str(exc).replace(os.fspath(stage), str(self.out)),)

    def _commit(self, stage: Path) -> None:
        out, old, committed = self.target, None, False
        try:
            files = sorted(os.listdir(stage))
            atomic_write_text(stage / MANIFEST, json.dumps({"format": MANIFEST_FORMAT, "files": files,
                                                            "pid": os.getpid()}, indent=1) + "\n")
            _fsync_dir(stage)
            fault_point("staged")
            with _signals_deferred():
                old = self._swap(stage, out)
                committed, self.stage = True, None  # the staging name now holds the old set, or nothing
                _fsync_dir(self._lock.parent)
                fault_point("exchanged")
            if old is not None:
                self._remove_old(old)
            fault_point("cleaned")
        except BaseException as exc:
            # before the exchange the stage holds the new set, after it the old one: either way it goes
            if committed and old is not None:
                self._remove_old(old)
            self._discard()
            if isinstance(exc, OSError):
                raise self._os_error(exc, stage) from None
            raise

    def _swap(self, stage: Path, out: Path) -> Path | None:
        """Put ``stage`` at ``out``; return where the old set now is (None: there was none)."""
        if not os.path.lexists(out):
            if not _renameat2(stage, out, _RENAME_NOREPLACE):
                os.rename(stage, out)
            return None
        if _renameat2(stage, out, _RENAME_EXCHANGE):
            return stage
        old = Path(tempfile.mktemp(prefix=f".{out.name}.old-{os.getpid()}-", dir=self._lock.parent))
        os.rename(out, old)
        try:
            fault_point("moved-old")
            os.rename(stage, out)
        except BaseException:
            os.rename(old, out)  # put the old set back: the commit did not happen
            raise
        return old

    def _remove_old(self, old: Path) -> None:
        """Remove the replaced set file by file (a kill in between leaves a leftover the next run removes).

        Symlinks are unlinked, never followed: only the entries of ``old`` itself go."""
        if not _is_real_dir(old):
            with contextlib.suppress(FileNotFoundError):
                os.unlink(old)
            return
        first = True
        for root, dirs, files in os.walk(old, topdown=False, followlinks=False):
            for f in files + [d for d in dirs if os.path.islink(os.path.join(root, d))]:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(os.path.join(root, f))
                if first:
                    fault_point("removing-old")
                    first = False
            for d in dirs:
                with contextlib.suppress(OSError):
                    os.rmdir(os.path.join(root, d))
        with contextlib.suppress(OSError):
            os.rmdir(old)


def record_in_set(folder: str | os.PathLike, *names: str, locked: bool = False) -> None:
    """Add entries ``names`` (top-level names inside ``folder``) that a later step wrote into a committed
    folder to its set, so the next run into ``folder`` replaces them with the rest instead of refusing them as
    foreign. A folder that is not a committed set is left as it is. ``locked``: the caller already holds the
    folder's :class:`OutputLock` (taken here otherwise)."""
    folder = Path(folder)
    manifest = folder / MANIFEST
    if not manifest.is_file():
        return
    with contextlib.nullcontext() if locked else OutputLock(folder):
        try:
            data = json.loads(manifest.read_text(encoding="utf-8"))
            data["files"] = sorted(set(data["files"]) | set(names))
        except (ValueError, KeyError, TypeError):
            return
        atomic_write_text(manifest, json.dumps(data, indent=1) + "\n")
