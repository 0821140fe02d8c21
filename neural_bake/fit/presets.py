"""One naming scheme for the SDF and texture presets: ``quick``, ``default`` and ``high``.

Each kind keeps its own preset table (:data:`neural_bake.fit.sdf.PRESETS` by architecture "WxD",
:data:`neural_bake.fit.texture.PRESETS` by name); the shared names are aliases onto them, and the texture
presets' earlier names (fast, medium, fine) stay as aliases too.
"""

from __future__ import annotations

__all__ = ["PRESET_NAMES", "SDF_ALIASES", "TEXTURE_ALIASES", "REFERENCE_STEPS", "resolve_preset"]

#: The shared preset names, cheapest first.
PRESET_NAMES = ("quick", "default", "high")

#: SDF preset names onto the architecture presets: none (``quick``, ``default`` and ``high`` are presets of
#: their own, (192, 3), (192, 3) and (256, 4) Sirens for 2, 5 and 10 minutes: :data:`neural_bake.fit.sdf.PRESETS`).
SDF_ALIASES: dict[str, str] = {}

#: Earlier texture preset names onto the shared ones.
TEXTURE_ALIASES = {"fast": "quick", "medium": "default", "fine": "high"}

#: Adam steps each preset makes in its time budget (the Adam part: a 64x1 fit sets a quarter aside for its
#: polish) on the quiet reference machine, the step count a ``budget="steps"`` fit runs; keys as
#: :data:`~neural_bake.fit.budget.STEP_COST`'s. Derived, not counted: budget seconds × the reference rate the
#: step costs were measured at (BENCHMARKS.md, "Honest budgets") / STEP_COST, rounded down.
REFERENCE_STEPS: dict[str, int] = {
    "quick": 2190,
    "quick/coarse": 1931,
    "quick/fine": 3168,
    "default": 7230,
    "default/coarse": 4325,
    "default/fine": 7073,
    "high": 8057,
    "high/coarse": 2724,
    "high/fine": 8781,
    "64x1": 11432,
    "128x2": 19315,
    "256x2": 11480,
    "256x3": 11486,
    "texture:quick": 8952,
    "texture:default": 30080,
    "texture:high": 40000,
}


def resolve_preset(name: str, aliases: dict[str, str], known) -> str | None:
    """The key of ``known`` that ``name`` means (itself or its alias), or None when it means none."""
    key = aliases.get(name, name)
    return key if key in known else None
