"""TOML settings files: read (``tomllib``, one line naming the file on a syntax error) and write (flat tables of
scalars and arrays, which is all a settings file of this toolkit holds)."""

from __future__ import annotations

import json
import math
import os

from ..errors import NeuralBakeError

__all__ = ["read_toml", "toml_text"]


def read_toml(path: str | os.PathLike) -> dict:
    """The table of TOML file ``path``; NeuralBakeError naming the file for a missing or invalid one."""
    import tomllib

    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise NeuralBakeError(f"{path}: no such config file") from None
    except IsADirectoryError:
        raise NeuralBakeError(f"{path}: is a folder, not a config file") from None
    except tomllib.TOMLDecodeError as exc:
        raise NeuralBakeError(f"{path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError:
        raise NeuralBakeError(f"{path}: not a text file") from None


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return json.dumps(str(v), ensure_ascii=False)  # a TOML basic string is a JSON string


def _tables(v) -> bool:
    """Whether ``v`` is written as an array of tables (``[[name]]``): a non-empty list of dicts."""
    return isinstance(v, (list, tuple)) and bool(v) and all(isinstance(x, dict) for x in v)


def toml_text(table: dict, comments: dict | None = None) -> str:
    """TOML of ``{key: scalar or array, …, section: {…}, name: [{…}, …]}`` (sections and arrays of tables
    nest); None is written as the string "none" (TOML has no null; the readers of settings files take "none"
    as None). ``comments[key]`` / ``comments[section][key]``: a comment line above the key."""
    lines: list[str] = []

    def emit(d: dict, notes: dict, prefix: str):
        for k, v in d.items():
            if isinstance(v, dict) or _tables(v):
                continue
            if notes.get(k):
                lines.append(f"# {notes[k]}")
            lines.append(f'{k} = "none"' if v is None else f"{k} = {_value(v)}")
        for k, v in d.items():
            name = f"{prefix}{k}"
            if isinstance(v, dict):
                lines.extend(["", f"[{name}]"])
                emit(v, notes.get(k) or {}, name + ".")
            elif _tables(v):
                for item in v:
                    lines.extend(["", f"[[{name}]]"])
                    emit(item, {}, name + ".")

    emit(table, comments or {}, "")
    return "\n".join(lines) + "\n"
