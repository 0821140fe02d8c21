"""Config dataclasses as the one source of settings: each field's help is the docstring line under it.

A stage's settings are one dataclass (defaults and a docstring line per field). From it come the command line
options (:mod:`neural_bake.cli.config_options`), the TOML settings files (:func:`read_config`,
:func:`config_table`) and the help text (:func:`field_help`); values from text (a flag, a CSV cell) and from
TOML are converted and checked against the field's type here (:func:`convert`).
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import textwrap
import types
import typing
from functools import lru_cache

from .errors import NeuralBakeError

__all__ = ["field_docs", "field_help", "field_types", "convert", "type_name", "read_config", "config_table"]


def preset_config(cls, presets: dict, preset: str | None, overrides: dict, *, what: str,
                  error: type[NeuralBakeError] = NeuralBakeError):
    """``cls()`` with the fields of ``presets[preset]`` (when a preset is named), then ``overrides``; ``error``
    names an unknown preset or an unknown field (``what``: the stage the message names)."""
    cfg = cls()
    if preset is not None:
        if preset not in presets:
            raise error(f"preset: unknown preset {preset!r} (choose from {', '.join(presets)})")
        cfg = dataclasses.replace(cfg, **presets[preset])
    unknown = sorted(set(overrides) - {f.name for f in dataclasses.fields(cls)})
    if unknown:
        raise error(f"{what}: unknown setting(s) {', '.join(unknown)}")
    return dataclasses.replace(cfg, **overrides)


@lru_cache(maxsize=None)
def field_docs(cls) -> dict[str, str]:
    """``{field: help}`` of a dataclass: the string literal under each field, whitespace collapsed; fields of
    base classes included. Empty where the source is not available (a frozen install)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):
            continue
        body = tree.body[0].body  # type: ignore[attr-defined]  # a class definition's body
        for a, b in zip(body, body[1:]):
            if (isinstance(a, ast.AnnAssign) and isinstance(a.target, ast.Name) and isinstance(b, ast.Expr)
                    and isinstance(b.value, ast.Constant) and isinstance(b.value.value, str)):
                docs[a.target.id] = " ".join(b.value.value.split())
    return docs


def field_help(cls, name: str) -> str:
    """The first sentence of field ``name``'s docstring line (the one-line help of its option)."""
    doc = field_docs(cls).get(name, "")
    head, dot, _ = doc.partition(". ")
    return head + "." if dot else doc


@lru_cache(maxsize=None)
def field_types(cls) -> dict[str, object]:
    """``{field: type hint}`` of a dataclass, forward references resolved."""
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls)}


def _union_args(hint) -> tuple:
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return typing.get_args(hint)
    return (hint,)


def type_name(hint) -> str:
    """A short name of a field type for messages and metavars: ``int``, ``float or none``, ``floats``."""
    names = []
    for t in _union_args(hint):
        if t is type(None):
            names.append("none")
        elif typing.get_origin(t) is tuple:
            names.append("ints" if _item_type(t) is int else "floats")
        else:
            names.append(getattr(t, "__name__", str(t)))
    return " or ".join(names)


_TRUE, _FALSE = ("true", "yes", "on", "1"), ("false", "no", "off", "0")


def _item_type(t) -> type:
    """The item type of a ``tuple[X, ...]`` hint: int for ``tuple[int, ...]``, else float."""
    return int if typing.get_args(t)[:1] == (int,) else float


def _from_text(text: str, t):
    if t is bool:
        low = text.lower()
        if low in _TRUE:
            return True
        if low in _FALSE:
            return False
        raise ValueError(text)
    if t is int:
        return int(text)
    if t is float:
        return float(text)
    if t is str:
        return text
    if typing.get_origin(t) is tuple:
        return tuple(_item_type(t)(x) for x in text.replace(",", " ").split())
    raise ValueError(text)


def _from_native(value, t):
    if t is bool and isinstance(value, bool):
        return value
    if t is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if t is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if t is str and isinstance(value, str):
        return value
    if typing.get_origin(t) is tuple and isinstance(value, (list, tuple)):
        item = _item_type(t)
        if all(isinstance(x, (int, float)) and not isinstance(x, bool) and (item is float or int(x) == x)
               for x in value):
            return tuple(item(x) for x in value)
    raise ValueError(value)


def convert(value, hint, what: str, *, text: bool | None = None):
    """``value`` as a value of a field of type ``hint``; NeuralBakeError ``"<what>=<value>: expected <type>"``.

    ``text`` (default: whether ``value`` is a str) reads it as text — a flag, a CSV cell: ``"3"`` is an int,
    ``"yes"`` a bool, ``"1,2"`` a tuple; otherwise it must already have the type (a TOML or JSON value; an
    int is a float). ``"none"`` (any case) or None is None where the type allows it.
    """
    args = _union_args(hint)
    as_text = isinstance(value, str) if text is None else text
    if type(None) in args and (value is None or isinstance(value, str) and value.strip().lower() in ("none", "null")):
        return None
    for t in (a for a in args if a is not type(None)):
        try:
            return _from_text(value.strip(), t) if as_text and isinstance(value, str) else _from_native(value, t)
        except ValueError:
            continue
    names = " or ".join(getattr(a, "__name__", str(a)) for a in args)
    raise NeuralBakeError(f"{what}={value!r}: expected {names}")


def read_config(cls, table: dict, *, where: str, extra: typing.Iterable[str] = ()) -> dict:
    """``{field: value}`` of a settings table (a TOML file's) for dataclass ``cls``, each value checked against
    its field's type; keys in ``extra`` (e.g. ``preset``) pass as they are.

    Raises NeuralBakeError naming ``where`` (the file) and the key: ``"run.toml: unknown key 'stpes' …"``,
    ``"run.toml: steps='many': expected int"``.
    """
    hints = field_types(cls)
    extra = set(extra)
    out = {}
    for key, value in table.items():
        if key in extra:
            out[key] = value
        elif key in hints:
            out[key] = convert(value, hints[key], f"{where}: {key}", text=False)
        else:
            raise NeuralBakeError(f"{where}: unknown key {key!r} (the keys are the options' names with underscores, "
                                  f"e.g. {next(iter(hints), 'steps')}; a command's --print-config lists them)")
    return out


def config_table(config) -> tuple[dict, dict]:
    """(table, comments) of a config object for :func:`neural_bake.io.tomlio.toml_text`: every field with its
    value, and the field's one-line help as the comment above it. Read back by :func:`read_config`."""
    cls = type(config)
    table = {f.name: getattr(config, f.name) for f in dataclasses.fields(cls)}
    return table, {k: field_help(cls, k) for k in table}
