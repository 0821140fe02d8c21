"""Small HTML helpers the offline pages share (the bake report, the comparison page)."""

from __future__ import annotations

import html
import math

__all__ = ["esc", "fmt"]


def esc(x) -> str:
    """``x`` as text, HTML-escaped."""
    return html.escape(str(x))


def fmt(v, nd: int = 2) -> str:
    """A figure for a table: "–" for None, "∞" for an infinity, ``nd`` decimals (scientific notation for a
    non-zero value too small for them), other values escaped as text."""
    if v is None:
        return "–"
    if isinstance(v, float):
        if math.isinf(v):
            return "∞" if v > 0 else "−∞"
        return f"{v:.{nd}f}" if abs(v) >= 10 ** -nd or v == 0 else f"{v:.2e}"
    return esc(v)
