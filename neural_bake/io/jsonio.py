"""JSON for reports, benchmark results and model headers: one encoder for numpy/torch values and NaN."""

from __future__ import annotations

import json

__all__ = ["json_default", "finite", "dumps"]


def json_default(o):
    """``json.dumps(default=...)``: arrays and tensors as lists, scalars as numbers, ``to_dict()`` objects."""
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    if hasattr(o, "to_dict"):
        return o.to_dict()
    return str(o)


def finite(o):
    """JSON has no NaN or infinity: such floats become None (e.g. the PSNR of identical colours)."""
    if isinstance(o, float):
        return o if o == o and abs(o) != float("inf") else None
    if isinstance(o, dict):
        return {k: finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [finite(v) for v in o]
    return o


def dumps(o, *, indent: int | None = 2) -> str:
    """Indented JSON text of ``o`` with non-finite floats as null, ending in a newline."""
    return json.dumps(finite(o), indent=indent, default=json_default) + "\n"
