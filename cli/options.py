"""What every writing verb checks before any work: numbers in range, outputs locked for this run alone."""

from __future__ import annotations

import math

import click

__all__ = ["refuse_nonpositive", "key_values", "lock_outputs", "output_option", "verbosity_options", "verbosity", "say"]


def refuse_nonpositive(**options) -> None:
    """NeuralBakeError naming the first option (``max_boxes`` -> ``--max-boxes``) set to a non-positive or
    non-finite number; options left unset (None) are skipped."""
    from neural_bake.errors import NeuralBakeError

    for name, value in options.items():
        if value is not None and not (math.isfinite(value) and value > 0):
            raise NeuralBakeError(f"--{name.replace('_', '-')} {value}: must be a positive number")


def key_values(values, *, form: str, example: str, param_hint: str | None = None) -> list[tuple[str, str]]:
    """``KEY=VALUE`` option values as ``(key, value)`` pairs, both stripped; click's BadParameter (one line,
    exit 2) for an item without ``=`` or without a key, naming the ``form`` expected and an ``example`` (and the
    option, ``param_hint``, when called from a verb's body rather than the option's callback)."""
    pairs = []
    for item in values:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise click.BadParameter(f"{item!r}: expected {form}, e.g. {example}", param_hint=param_hint)
        pairs.append((key.strip(), value.strip()))
    return pairs


def lock_outputs(*paths) -> None:
    """Lock the output files ``paths`` (None skipped) until the verb ends: a second run writing any of them
    fails at once naming this one, and temporary files of killed runs are removed (see neural_bake.io.outdir)."""
    from neural_bake.io.outdir import locked_outputs

    click.get_current_context().with_resource(locked_outputs(*paths))


def output_option(help: str, *, folder: bool = False, required: bool = True, old_spelling: bool = False):
    """``-o/--output PATH`` (parameter ``output``); ``old_spelling`` keeps ``--out`` as a hidden alias for
    command lines written before every verb spelled it ``-o/--output``."""
    import functools

    kind = dict(file_okay=False) if folder else dict(dir_okay=False)

    def deco(fn):
        inner = fn
        if old_spelling:
            @functools.wraps(inner)
            def fn(*args, out_alias=None, **kwargs):
                if out_alias is not None:
                    if kwargs.get("output") not in (None, out_alias):
                        raise click.UsageError("give -o/--output once (--out is its older spelling)")
                    kwargs["output"] = out_alias
                if required and kwargs.get("output") is None:
                    raise click.UsageError("missing option -o/--output")
                return inner(*args, **kwargs)

            fn = click.option("--out", "out_alias", type=click.Path(**kind), default=None, hidden=True)(fn)
        return click.option("-o", "--output", "output", type=click.Path(**kind), default=None,
                            required=required and not old_spelling, help=help)(fn)

    return deco


def verbosity_options(fn):
    """``-q/--quiet`` (no progress bars, only warnings, errors and the output asked for) and ``-v/--verbose``
    (also the resolved settings and each step's details); the verb reads them with :func:`say`."""
    import functools

    inner = fn

    @functools.wraps(inner)
    def fn(*args, quiet=False, verbose=False, **kwargs):
        if quiet and verbose:
            raise click.UsageError("give --quiet or --verbose, not both")
        click.get_current_context().meta["neural_bake.verbosity"] = -1 if quiet else 1 if verbose else 0
        return inner(*args, **kwargs)

    fn = click.option("-v", "--verbose", is_flag=True, help="Also print the resolved settings and details.")(fn)
    return click.option("-q", "--quiet", is_flag=True,
                        help="No progress bars; print only warnings, errors and what was asked for.")(fn)


def verbosity() -> int:
    """-1 quiet, 0 normal, 1 verbose (of the running verb; 0 outside one)."""
    ctx = click.get_current_context(silent=True)
    return ctx.find_root().meta.get("neural_bake.verbosity", 0) if ctx else 0


def say(message: str, level: int = 0) -> None:
    """Print ``message`` when the verbosity is at least ``level`` (0: normal lines, 1: --verbose details)."""
    if verbosity() >= level:
        click.echo(message)
