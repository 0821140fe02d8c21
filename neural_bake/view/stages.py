"""A bake's time by stage as a tree that sums to the run's wall time, and its picture (an inline SVG).

A bake's ``report.json`` lists stage times flat (``seconds``), but they nest: the Baker's set-up
(``prepare``) holds the unwrap, the tangents and, when the texels are cached, their rasterisation; the
bake itself (``bake``) holds the network evaluations (``sdf``, ``texture``), the adaptive bookkeeping,
the precision check, the map accumulation (``maps``, which holds the hybrid decision) and the padding,
and a streamed bake's rasterisation. :func:`stage_tree` puts each time inside its parent, adds the time a
parent spent outside its listed children as "other", and adds the run's own "other" (export of the report,
the baseline, vertex maps …) so the top row sums to ``seconds_total``.
"""

from __future__ import annotations

import html
from dataclasses import dataclass, field

__all__ = ["StageNode", "stage_tree", "stage_bar_svg", "STAGE_PARENTS", "OTHER"]

#: The parents a stage may sit in, tried in order (a stage goes into the first whose room holds it,
#: within STAGE_FIT_TOL; else it is a top-level stage). A stage not listed is a top-level stage.
STAGE_PARENTS: dict[str, tuple[str, ...]] = {
    "unwrap": ("prepare",), "tangents": ("prepare",), "rasterize": ("prepare", "bake"),
    "sdf": ("bake",), "texture": ("bake",), "adaptive": ("bake",), "check": ("bake",), "maps": ("bake",),
    "padding": ("bake",), "hybrid": ("maps",),
    "rays": ("bake",), "closest": ("bake",), "shade": ("bake",),  # the classical bake's (bake.classical)
}
#: The order of a bake run's top-level stages (others follow in the report's order).
RUN_ORDER = ("load", "coarse", "prepare", "bake", "write")
#: Name of the time a parent (or the run) spent outside its listed children.
OTHER = "other"
#: Relative slack when fitting children into a parent (timers read at slightly different instants).
STAGE_FIT_TOL = 0.02


@dataclass
class StageNode:
    """One stage: ``name``, ``seconds`` (wall), ``children`` (their seconds sum to ours, "other" included)."""

    name: str
    seconds: float
    children: list["StageNode"] = field(default_factory=list)

    def find(self, name: str) -> "StageNode | None":
        """The first stage called ``name`` in this subtree (depth first), or None."""
        if self.name == name:
            return self
        for c in self.children:
            hit = c.find(name)
            if hit is not None:
                return hit
        return None

    def rows(self) -> list[list[tuple["StageNode", float]]]:
        """Per depth below this node, (node, start seconds from this node's start) of every stage."""
        out: list[list[tuple[StageNode, float]]] = []

        def walk(node: StageNode, start: float, depth: int) -> None:
            t = start
            for c in node.children:
                while len(out) <= depth:
                    out.append([])
                out[depth].append((c, t))
                walk(c, t, depth + 1)
                t += c.seconds

        walk(self, 0.0, 0)
        return out


def _number(v) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and v == v and v >= 0 else None


def stage_tree(seconds: dict, total: float | None = None) -> StageNode:
    """The stage tree of a report's ``seconds`` (``{stage: seconds}``) under a root "run" of ``total``
    seconds (default: ``seconds["total"]``, else the sum of the top-level stages).

    Each parent's children are its listed stages (:data:`STAGE_PARENTS`) plus "other" for the rest of its
    time; the root's children sum to ``total`` exactly (a run whose stages add up to more than ``total`` gets
    a root of their sum). Non-numeric and negative entries are skipped; zero-time stages are dropped."""
    times = {k: t for k, v in (seconds or {}).items() if k != "total" and (t := _number(v)) is not None}
    if total is None:
        total = _number((seconds or {}).get("total"))
    nodes = {k: StageNode(k, t) for k, t in times.items()}
    room = dict(times)
    parent_of: dict[str, str | None] = {}
    # the innermost stages first, so a parent's room is known before its own parent takes it
    order = sorted(times, key=lambda k: -_depth(k))
    for k in order:
        parent_of[k] = None
        for p in STAGE_PARENTS.get(k, ()):
            if p in room and times[k] <= room[p] + STAGE_FIT_TOL * times[p]:
                parent_of[k] = p
                room[p] = max(0.0, room[p] - times[k])
                break
    for k in times:  # in the report's order
        p = parent_of[k]
        if p is not None and times[k] > 0:
            nodes[p].children.append(nodes[k])
    top = [nodes[k] for k in times if parent_of[k] is None and times[k] > 0]
    top.sort(key=lambda n: RUN_ORDER.index(n.name) if n.name in RUN_ORDER else len(RUN_ORDER))
    for node in nodes.values():
        _close(node)
    used = sum(n.seconds for n in top)
    wall = used if total is None else max(float(total), used)
    root = StageNode("run", wall, top)
    if wall - used > 0:
        root.children.append(StageNode(OTHER, wall - used))
    return root


def _depth(name: str) -> int:
    d, seen = 0, {name}
    parents = STAGE_PARENTS.get(name, ())
    while parents:
        d += 1
        p = parents[0]
        if p in seen:
            break
        seen.add(p)
        parents = STAGE_PARENTS.get(p, ())
    return d


def _close(node: StageNode) -> None:
    """Add "other" to a parent whose children do not fill it; scale them down if they overfill it."""
    if not node.children:
        return
    s = sum(c.seconds for c in node.children)
    if s > node.seconds > 0:  # within the fit tolerance: timers read at different instants
        for c in node.children:
            _scale(c, node.seconds / s)
    elif node.seconds - s > 0:
        node.children.append(StageNode(OTHER, node.seconds - s))


def _scale(node: StageNode, f: float) -> None:
    node.seconds *= f
    for c in node.children:
        _scale(c, f)


_PALETTE = ("#4a7fb5", "#e08a3c", "#5aa469", "#c95b5b", "#8c6bb1", "#8c8c3c", "#3caab4", "#d47fb0",
            "#7f7f7f", "#b5954a")


def stage_colour(name: str) -> str:
    """A fixed colour per stage name (the same stage has the same colour in every chart)."""
    if name == OTHER:
        return "#d0d0d0"
    h = 0
    for ch in name:
        h = (h * 31 + ord(ch)) % 1_000_003
    return _PALETTE[h % len(_PALETTE)]


def stage_bar_svg(tree: StageNode, *, width: int = 900, row: int = 22, scale_seconds: float | None = None,
                  label: str | None = None) -> str:
    """An SVG of ``tree``: the top row is the run, one segment per stage in order, widths ∝ seconds, summing
    to the run's wall time; each stage's children are drawn under it, inside its span. ``scale_seconds``:
    the seconds the full width stands for (default the run's; several charts on one scale compare)."""
    span = float(scale_seconds or tree.seconds or 1.0)
    px = (width - 2) / span
    rows = tree.rows()
    head = 16 if label else 0
    height = head + row * max(1, len(rows)) + 18
    out = [f"<svg class='stages' width='{width}' height='{height}' "
           f"font-family='system-ui,sans-serif' font-size='11'>"]
    if label:
        out.append(f"<text x='1' y='12' font-weight='bold'>{html.escape(label)}</text>")
    for d, items in enumerate(rows):
        y = head + d * row
        for node, start in items:
            x, w = 1 + start * px, node.seconds * px
            if w <= 0:
                continue
            tip = f"{node.name}: {node.seconds:.2f} s"
            out.append(f"<g><title>{html.escape(tip)}</title><rect x='{x:.2f}' y='{y}' width='{w:.2f}' "
                       f"height='{row - 2}' fill='{stage_colour(node.name)}' stroke='#fff' stroke-width='0.5'/>")
            text = f"{node.name} {node.seconds:.1f}s"
            if w > 6.5 * len(text):
                out.append(f"<text x='{x + 3:.2f}' y='{y + row - 8}' fill='#111'>{html.escape(text)}</text>")
            out.append("</g>")
    y = head + row * max(1, len(rows)) + 12
    out.append(f"<text x='1' y='{y}' fill='#555'>0 s</text><text x='{width - 1}' y='{y}' text-anchor='end' "
               f"fill='#555'>{span:.1f} s (run wall time {tree.seconds:.1f} s)</text></svg>")
    return "".join(out)
