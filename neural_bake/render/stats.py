"""Counters of network evaluations per network and per effect (what ``--stats`` writes).

Every evaluation the renderer makes goes through an :class:`EvalCounter`: ``points[network][effect]`` is the
number of points a network was evaluated at (a value or a value-and-gradient evaluation each count one
point; ``gradients`` counts the latter again on their own) and ``boxes[network][effect]`` the number of
range bounds over boxes. Effects: ``trace`` (primary rays), ``normals``, ``texture``, ``shadows``,
``ambient_occlusion``, ``guaranteed``, ``hole_map``, ``skip_octree``.
"""

from __future__ import annotations

from collections import defaultdict

import torch

__all__ = ["EvalCounter"]


class EvalCounter:
    """Counts evaluations; wraps a level's or texture's evaluators so that nothing is evaluated uncounted."""

    def __init__(self):
        self.points: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
        self.gradients: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
        self.boxes: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
        self.calls: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))

    def value(self, level, effect: str, points: torch.Tensor) -> torch.Tensor:
        """``level.value(points)``, counted."""
        self._count(level.name, effect, points.shape[0])
        if points.shape[0] == 0:
            return points.new_zeros((0,))
        return level.value(points).reshape(-1)

    def value_and_gradient(self, level, effect: str, points: torch.Tensor):
        """``level.value_and_gradient(points)``, counted."""
        n = points.shape[0]
        self._count(level.name, effect, n)
        self.gradients[level.name][effect] += n
        if n == 0:
            return points.new_zeros((0,)), points.new_zeros((0, 3))
        v, g = level.value_and_gradient(points)
        return v.reshape(-1), g.reshape(-1, 3)

    def bound(self, level, effect: str, centers: torch.Tensor, axes: torch.Tensor):
        """``level.bound(centers, axes)``, counted in boxes."""
        self.boxes[level.name][effect] += int(centers.shape[0])
        self.calls[level.name][effect] += 1
        if centers.shape[0] == 0:
            e = centers.new_zeros((0,))
            return e, e.clone()
        lo, hi = level.bound(centers, axes)
        return lo.reshape(-1).to(centers.dtype), hi.reshape(-1).to(centers.dtype)

    def color(self, texture, effect: str, points: torch.Tensor, normals: torch.Tensor | None = None) -> torch.Tensor:
        """``texture.color(points, normals)``, counted (``normals``: unit surface normals there, read by a colour
        field with normal inputs)."""
        self._count(texture.name, effect, points.shape[0])
        if points.shape[0] == 0:
            return points.new_zeros((0, 3))
        out = texture.color(points, normals) if getattr(texture, "normal_inputs", False) else texture.color(points)
        return out.reshape(points.shape[0], -1)[:, :3]

    def _count(self, name: str, effect: str, n: int) -> None:
        self.points[name][effect] += int(n)
        self.calls[name][effect] += 1

    def merge(self, other: "EvalCounter") -> None:
        for mine, theirs in ((self.points, other.points), (self.gradients, other.gradients),
                             (self.boxes, other.boxes), (self.calls, other.calls)):
            for net, effects in theirs.items():
                for eff, n in effects.items():
                    mine[net][eff] += n

    def total(self, effect: str | None = None, network: str | None = None) -> int:
        """Points evaluated, summed over networks (or one) and effects (or one)."""
        return sum(n for net, effects in self.points.items() if network in (None, net)
                   for eff, n in effects.items() if effect in (None, eff))

    def effects(self) -> set[str]:
        """Effects that evaluated at least one point or box."""
        out = {eff for effects in self.points.values() for eff, n in effects.items() if n}
        return out | {eff for effects in self.boxes.values() for eff, n in effects.items() if n}

    def to_dict(self) -> dict:
        """``{"points": {net: {effect: n}}, "gradients": …, "boxes": …, "totals": {effect: n}}`` (plain ints)."""
        def plain(d):
            return {net: {eff: int(n) for eff, n in sorted(effects.items()) if n}
                    for net, effects in sorted(d.items()) if any(effects.values())}

        totals: dict[str, int] = defaultdict(int)
        for effects in self.points.values():
            for eff, n in effects.items():
                totals[eff] += int(n)
        return {"points": plain(self.points), "gradients": plain(self.gradients), "boxes": plain(self.boxes),
                "totals": {k: v for k, v in sorted(totals.items()) if v}}
