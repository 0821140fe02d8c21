"""The coarse mesh a bake targets: parsed from a spec ("decimate:2000", "march:128", "level:0:256", "keep") and
made by decimation, marching cubes of an SDF network, or the mesh itself."""

from __future__ import annotations

import math
import time

from ..errors import NeuralBakeError
from ..types import Mesh

__all__ = ["COARSE_KINDS", "parse_coarse", "coarse_mesh"]

COARSE_KINDS = ("decimate", "march", "level", "keep")
_COARSE_USAGE = "expected decimate:FACES, decimate:RATIO, march:RESOLUTION, level:I:RESOLUTION or keep"


def parse_coarse(spec: str) -> tuple[str, float | int | tuple[int, int] | None]:
    """Parse a coarse-mesh spec: ``"decimate:2000"`` (faces), ``"decimate:0.1"`` (ratio), ``"march:64"``
    (grid resolution), ``"level:0:256"`` (marching cubes of a nested sequence's level 0 at 256³; value
    ``(0, 256)``) or ``"keep"``. Raises :class:`NeuralBakeError` naming the
    parameter ``coarse`` otherwise."""
    kind, _, arg = str(spec).partition(":")
    usage = _COARSE_USAGE
    if kind not in COARSE_KINDS:
        raise NeuralBakeError(f"coarse {spec!r}: unknown kind {kind!r} ({usage})", parameter="coarse")
    if kind == "keep":
        if arg:
            raise NeuralBakeError(f"coarse {spec!r}: keep takes no value ({usage})", parameter="coarse")
        return kind, None
    if kind == "level":
        level, _, res = arg.partition(":")
        try:
            level, res = int(level), int(res)
        except ValueError:
            raise NeuralBakeError(f"coarse {spec!r}: level needs LEVEL:RESOLUTION, e.g. level:0:256",
                                  parameter="coarse") from None
        if level < 0 or not 4 <= res <= 1024:
            raise NeuralBakeError(f"coarse {spec!r}: level needs a level >= 0 and a resolution in [4, 1024]",
                                  parameter="coarse")
        return kind, (level, res)
    try:
        value = float(arg)
    except ValueError:
        raise NeuralBakeError(f"coarse {spec!r}: {kind} needs a number ({usage})", parameter="coarse") from None
    if not math.isfinite(value):
        raise NeuralBakeError(f"coarse {spec!r}: {kind} needs a finite number ({usage})", parameter="coarse")
    if kind == "decimate" and 0 < value < 1:
        return kind, value
    if value != int(value) or (kind == "decimate" and value < 4) or (kind == "march" and not 4 <= value <= 1024):
        limits = "a face count >= 4 or a ratio in (0, 1)" if kind == "decimate" else "a resolution in [4, 1024]"
        raise NeuralBakeError(f"coarse {spec!r}: {kind} needs {limits}", parameter="coarse")
    return kind, int(value)


def coarse_mesh(mesh: Mesh | None, spec: str, sdf=None) -> tuple[Mesh, dict]:
    """The coarse mesh a bake targets, from a :func:`parse_coarse` spec; returns (mesh, info).

    ``decimate``: quadric edge collapse of ``mesh`` (UVs dropped: the Baker unwraps). ``march``: marching
    cubes of ``sdf`` (a Siren field, or a nested sequence's fine f; cost-aware range pruning,
    ``pruned="auto"``) at that resolution, in the field's frame; ``level:I:RES``: the same of level I of a
    nested sequence (the paper's coarse surface: its zero set lies in f's band δ_I), then :func:`~neural_bake.mesh.cleanup.clean_mesh` (weld duplicate vertices, drop
    degenerate and duplicate faces and components under 1% of the largest one's faces; non-manifold and
    boundary edges are counted, not repaired). ``keep``: ``mesh`` itself (its own UVs, if any, are kept).
    ``mesh`` may be None for ``march`` and ``level`` (the field's frame is used).

    ``info``: ``spec``, ``faces``, ``vertices``, ``seconds``; for ``march`` also ``march`` (the stats of
    :func:`~neural_bake.mesh.marching.march`) and ``cleanup`` (the clean-up report).
    """
    kind, value = parse_coarse(spec)
    nested = hasattr(sdf, "levels") and hasattr(sdf, "level")  # a nested sequence (fields.NestedSequence)
    t0 = time.perf_counter()
    info: dict = {"spec": spec}
    if kind == "keep":
        out = mesh
    elif kind == "decimate":
        from .decimate import decimate

        out = decimate(mesh, **({"ratio": value} if isinstance(value, float) else {"faces": value}))
    else:
        from .cleanup import clean_mesh
        from .marching import march

        if kind == "level":
            if not nested:
                raise NeuralBakeError(f"coarse {spec!r}: level needs a nested-sequence SDF file (fit nested)",
                                      parameter="coarse")
            level, value = value
            field = sdf.level(level)  # NeuralBakeError naming the levels there are
            info["level"] = {"index": field.metadata["level"], "delta": field.delta}
        else:
            field = sdf.finest if nested else sdf
        if getattr(field, "model", None) is None:
            raise NeuralBakeError(f"coarse {spec!r}: march needs an SDF model (a Siren)", parameter="coarse")
        out, stats = march(field.model, value, pruned="auto",
                           frame=field.frame or (mesh.frame if mesh is not None else None))
        info["march"] = stats
        if out.n_faces == 0:
            raise NeuralBakeError(f"coarse {spec!r}: the SDF has no surface at resolution {value}", parameter="coarse")
        out, info["cleanup"] = clean_mesh(out)
    info.update(faces=out.n_faces, vertices=out.n_vertices, seconds=time.perf_counter() - t0)
    return out, info
