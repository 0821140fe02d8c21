"""Entry point of the `neural-bake` command.

Verbs are loaded lazily (``name -> module:attribute``) so ``neural-bake --help`` stays fast and each verb
imports only the library parts it needs. Every user mistake and every OS failure surfaces as one line on
stderr, ``neural-bake: error: <file>: <problem>`` — never a Python traceback — with exit code 2 for user input
and 1 for the environment (see :mod:`neural_bake.errors`). SIGTERM is handled like SIGINT: the run cleans up
(staging removed, locks released, outputs as they were), prints one line and exits 143 (130 for SIGINT).
"""

from __future__ import annotations

import contextlib
import importlib
import os
import signal
import sys
import warnings

import click

from neural_bake import __version__
from neural_bake.errors import NeuralBakeError, NeuralBakeWarning, os_error

__all__ = ["main", "LazyGroup", "cli_message", "usage_message", "OPTIONS"]

#: The CLI option of a library parameter whose option is not ``--`` and the name with dashes (``max_boxes`` →
#: ``--max-boxes``); errors about a parameter's value name the option instead of the parameter.
OPTIONS: dict[str, str] = {"tolerance_deg": "--tolerance"}


class LazyGroup(click.Group):
    """A click group whose sub-commands are imported on first use."""

    def __init__(self, *args, lazy: dict[str, tuple[str, str]] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy = dict(lazy or {})

    def list_commands(self, ctx):
        return sorted(set(super().list_commands(ctx)) | set(self.lazy))

    def get_command(self, ctx, name):
        if name in self.lazy:
            module, attr = self.lazy[name]
            return getattr(importlib.import_module(module), attr)
        return super().get_command(ctx, name)

    def format_commands(self, ctx, formatter):
        rows = []
        for name in self.list_commands(ctx):
            try:
                cmd = self.get_command(ctx, name)
            except ImportError:  # a verb whose module is not there yet must not break --help
                continue
            help_text = cmd.get_short_help_str(70) if cmd else ""
            rows.append((name, help_text))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


COMMANDS = {
    "samples": ("neural_bake.cli.samples", "command"),
    "inspect": ("neural_bake.cli.inspect", "command"),
    "import": ("neural_bake.cli.import_weights", "command"),
    "fit": ("neural_bake.cli.fit", "group"),
    "bake": ("neural_bake.cli.bake", "command"),
    "bake-frames": ("neural_bake.cli.bake_frames", "command"),
    "batch": ("neural_bake.cli.batch", "command"),
    "compare": ("neural_bake.cli.compare", "command"),
    "bench": ("neural_bake.cli.bench", "group"),
    "demo": ("neural_bake.cli.demo", "command"),
    "render": ("neural_bake.cli.render", "command"),
    "view": ("neural_bake.cli.view", "command"),
}


@click.group(cls=LazyGroup, lazy=COMMANDS, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="neural-bake")
@click.option("--threads", metavar="N|auto", default=None,
              help="CPU threads of fits, bakes and renders: auto (default) times the work with 1 … cores threads "
                   "and keeps the fastest, following the machine's load; N fixes it (also NEURAL_BAKE_THREADS).")
def cli(threads):
    """Neural normal and texture baking: fit neural fields to a mesh, bake them onto a coarse mesh.

    \b
    Typical run:
      neural-bake samples -o samples/
      neural-bake inspect samples/bumpy_sphere.obj
      neural-bake fit sdf samples/bumpy_sphere.obj -o bumpy.sdf
      neural-bake bake samples/bumpy_sphere.obj --sdf bumpy.sdf --coarse decimate:2000 -o out/
    """
    if threads is not None:
        from neural_bake.errors import NeuralBakeError
        from neural_bake.nets.threads import ENV_THREADS, fixed_threads

        try:
            fixed_threads(threads)
        except NeuralBakeError:
            raise NeuralBakeError(f"--threads {threads!r}: must be auto or a thread count from 1 to 4096") from None
        os.environ[ENV_THREADS] = threads.strip().lower()  # child processes (batch workers) follow it too


def _format_warning(message, category, filename, lineno, line=None):
    return f"neural-bake: warning: {message}\n"


class Terminated(BaseException):
    """Raised in the main thread by SIGTERM, so ``finally`` blocks and context managers clean up."""


def _on_sigterm(signum, frame):
    raise Terminated()


@contextlib.contextmanager
def _sigterm_raises():
    """SIGTERM raises :class:`Terminated` for the body (only in the main thread; elsewhere unchanged)."""
    try:
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 1 environment or failed work, 2 user input, 130 SIGINT,
    143 SIGTERM)."""
    warnings.formatwarning = _format_warning
    warnings.simplefilter("always", NeuralBakeWarning)
    try:
        with _sigterm_raises():
            code = cli.main(args=argv, prog_name="neural-bake", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("neural-bake: aborted", err=True)
        return 130
    except click.exceptions.ClickException as exc:  # usage errors: click's message on one line, exit 2
        if isinstance(exc, getattr(click.exceptions, "NoArgsIsHelpError", ())):  # a bare group: its help
            exc.show()
            return exc.exit_code
        click.echo(f"neural-bake: error: {usage_message(exc)}", err=True)
        return exc.exit_code
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except NeuralBakeError as exc:
        click.echo(f"neural-bake: error: {cli_message(exc)}", err=True)
        return exc.exit_code
    except OSError as exc:  # a read or write the machine refused: one line naming the path
        err = os_error(exc)
        click.echo(f"neural-bake: error: {err}", err=True)
        return err.exit_code
    except KeyboardInterrupt:
        click.echo("neural-bake: interrupted", err=True)
        return 130
    except Terminated:
        click.echo("neural-bake: terminated", err=True)
        return 143
    return code if isinstance(code, int) else 0  # a verb's click.exceptions.Exit(code), else 0


def cli_message(exc: NeuralBakeError) -> str:
    """The error's message as the CLI says it: a leading library parameter name becomes its option."""
    message, name = str(exc), getattr(exc, "parameter", None)
    if not name or not message.startswith(name):
        return message
    return OPTIONS.get(name, "--" + name.replace("_", "-")) + message[len(name):]


def usage_message(exc: click.exceptions.ClickException) -> str:
    """Click's message for a usage error, on one line, without click's closing full stop."""
    message = " ".join(exc.format_message().split())
    return message[:-1] if message.endswith(".") and not message.endswith("..") else message


def entry() -> None:  # pragma: no cover - console script wrapper
    code = main()
    finish(code)


def finish(code: int) -> None:
    """End the process with ``code`` once its work is written. The interpreter's own teardown after a bake takes
    about half a second (freeing torch's and open3d's modules and objects) and saves nothing: when no other
    thread runs, the streams are flushed and the exit handlers run (logging, multiprocessing, weakref
    finalizers, torch's), then the process ends at once (``os._exit``). With other threads alive, the usual
    ``sys.exit``, which waits for them."""
    import atexit
    import threading

    if threading.active_count() > 1:
        sys.exit(code)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (`| head`) or stream: nothing more to say
            pass
    atexit._run_exitfuncs()
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    entry()
