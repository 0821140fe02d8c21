"""Config dataclasses as the one source of settings: each field's help is the docstring line under it."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import textwrap
from functools import lru_cache

__all__ = ["field_docs"]


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
