"""The manifest of a batch run: which meshes to bake, under which output names, with which overrides.

A manifest is one of:

- a CSV file (``.csv``): a header row with a ``mesh`` column, optional ``name`` and ``texture`` columns and
  option columns ``STAGE.FIELD`` (``sdf.minutes``, ``bake.size``, …); an empty cell keeps the batch's value;
- a JSON file (``.json``): a list of assets, or ``{"assets": [...]}``; each asset is a mesh path or an object
  with ``mesh``, optional ``name``, ``texture`` and per-stage objects (``{"bake": {"size": 512}}``) or
  ``"STAGE.FIELD"`` keys;
- a text file (any other existing file): one mesh path per line; blank lines and ``#`` comments skipped;
- a glob (not an existing file; ``*``, ``?``, ``[``, ``**`` for any depth), matched from the working folder.

Relative paths in a file are relative to the manifest's folder. The output name of an asset defaults to the
mesh file's stem; names are relative paths checked by :func:`neural_bake.io.paths.check_relative_name`.
Refused with one :class:`ManifestError` line (exit 2, before any work): an unreadable or empty manifest, an
unknown column or key (also a ``STAGE.FIELD`` that is no setting of its stage, naming the close match if
any), a row without a mesh, the same mesh (with the same texture and options) twice, and two
assets with the same output name. A mesh file that does not exist is *not* refused here: that asset fails on
its own in the batch and the others run.
"""

from __future__ import annotations

import csv
import glob
import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from neural_bake.errors import NeuralBakeError
from neural_bake.io.paths import check_relative_name

__all__ = ["AssetSpec", "ManifestError", "read_manifest", "STAGE_NAMES", "BASE_KEYS"]

#: The per-asset stages, in the order they run; option keys in a manifest are ``STAGE.FIELD``.
STAGE_NAMES = ("sdf", "nested", "texture", "coarse", "bake")

#: Keys of an asset that are not stage options.
BASE_KEYS = ("mesh", "name", "texture")


class ManifestError(NeuralBakeError):
    """A manifest that cannot be run as written (exit 2, nothing started)."""


@dataclass
class AssetSpec:
    """One asset of a manifest.

    - ``mesh``: absolute path of the mesh file (may not exist: the asset then fails alone).
    - ``name``: the output name, a relative POSIX path (the asset's folder is OUT/name).
    - ``texture``: absolute path of a base-colour image replacing the one the mesh names, or None.
    - ``options``: ``{stage: {field: value}}`` overrides; values are strings where the manifest gave text
      (CSV cells, text files) and are converted by the stage configs.
    - ``where``: the manifest position, for messages (``"rows.csv:3"``).
    """

    mesh: str
    name: str
    texture: str | None = None
    options: dict[str, dict] = field(default_factory=dict)
    where: str = ""


def read_manifest(manifest: str | os.PathLike) -> list[AssetSpec]:
    """The assets of ``manifest`` (a file or a glob; module docstring), in manifest order.

    Raises :class:`ManifestError` naming the manifest (and row) for every refused case.
    """
    text = os.fspath(manifest)
    p = Path(text)
    if p.is_dir():
        raise ManifestError(f"{text}: is a folder (give a manifest file or a glob such as '{text}/*.obj')")
    if p.is_file():
        try:
            raw = p.read_text(encoding="utf-8-sig")
        except (OSError, UnicodeDecodeError) as exc:
            raise ManifestError(f"{text}: cannot read the manifest ({getattr(exc, 'strerror', None) or exc})") from None
        base = p.resolve().parent
        suffix = p.suffix.lower()
        if suffix == ".csv":
            rows = _csv_rows(raw, text)
        elif suffix == ".json":
            rows = _json_rows(raw, text)
        else:
            rows = _text_rows(raw, text)
    elif any(c in text for c in "*?["):
        base = Path.cwd()
        matches = sorted(glob.glob(text, recursive=True))
        rows = [(f"{text}[{i}]", {"mesh": m}) for i, m in enumerate(matches) if Path(m).is_file()]
        if not rows:
            raise ManifestError(f"{text}: the glob matches no file")
    else:
        raise ManifestError(f"{text}: no such manifest file (nor a glob: no * ? or [ in it)")
    if not rows:
        raise ManifestError(f"{text}: the manifest lists no asset")
    assets = [_asset(where, row, base) for where, row in rows]
    _check_unique(assets)
    return assets


def _csv_rows(raw: str, name: str) -> list[tuple[str, dict]]:
    reader = csv.DictReader(io.StringIO(raw))
    header = [h.strip() for h in (reader.fieldnames or [])]
    if not header:
        return []
    if "mesh" not in header:
        raise ManifestError(f"{name}: the CSV header has no 'mesh' column (found: {', '.join(header)})")
    for h in header:
        _check_key(h, f"{name}:{reader.line_num}: column")
    rows = []
    for row in reader:
        i = reader.line_num  # blank lines are skipped by the reader but counted here
        if None in row:
            raise ManifestError(f"{name}:{i}: more cells than header columns")
        cells = {k.strip(): (v.strip() if isinstance(v, str) else v) for k, v in row.items()}
        if not any(cells.values()):
            continue  # a blank line
        rows.append((f"{name}:{i}", {k: v for k, v in cells.items() if v not in ("", None)}))
    return rows


def _json_rows(raw: str, name: str) -> list[tuple[str, dict]]:
    try:
        data = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise ManifestError(f"{name}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if isinstance(data, dict):
        unknown = sorted(set(data) - {"assets"})
        if unknown or "assets" not in data:
            raise ManifestError(f"{name}: a JSON manifest object needs an 'assets' list (found keys: "
                                f"{', '.join(map(str, data)) or 'none'})")
        data = data["assets"]
    if not isinstance(data, list):
        raise ManifestError(f"{name}: a JSON manifest is a list of assets or {{\"assets\": [...]}}")
    rows = []
    for i, item in enumerate(data):
        where = f"{name}[{i}]"
        if isinstance(item, str):
            item = {"mesh": item}
        if not isinstance(item, dict):
            raise ManifestError(f"{where}: an asset is a mesh path or an object, got {type(item).__name__}")
        flat: dict = {}
        for k, v in item.items():
            if k in STAGE_NAMES and isinstance(v, dict):
                for fk, fv in v.items():
                    flat[f"{k}.{fk}"] = fv
            else:
                flat[k] = v
        for k in flat:
            _check_key(k, f"{where}: key")
        rows.append((where, flat))
    return rows


def _text_rows(raw: str, name: str) -> list[tuple[str, dict]]:
    rows = []
    for i, line in enumerate(raw.splitlines(), start=1):
        s = line.strip()
        if s and not s.startswith("#"):
            rows.append((f"{name}:{i}", {"mesh": s}))
    return rows


def _check_key(key: str, what: str) -> None:
    if key in BASE_KEYS:
        return
    stage, dot, fld = str(key).partition(".")
    if not dot or stage not in STAGE_NAMES or not fld:
        raise ManifestError(f"{what} {key!r}: unknown (expected {', '.join(BASE_KEYS)} or STAGE.FIELD with "
                            f"STAGE one of {', '.join(STAGE_NAMES)})")
    from .stages import unknown_setting

    problem = unknown_setting(stage, fld)
    if problem:
        raise ManifestError(f"{what} {key!r}: {problem}")


def _asset(where: str, row: dict, base: Path) -> AssetSpec:
    mesh = row.get("mesh")
    if not isinstance(mesh, str) or not mesh.strip():
        raise ManifestError(f"{where}: no mesh path")
    mesh_path = _resolve(mesh.strip(), base)
    texture = row.get("texture")
    if texture is not None and (not isinstance(texture, str) or not texture.strip()):
        raise ManifestError(f"{where}: texture must be an image path, got {texture!r}")
    name = row.get("name")
    if name is None:
        name = Path(mesh_path).stem
    if not isinstance(name, str):
        raise ManifestError(f"{where}: name must be text, got {name!r}")
    try:
        check_relative_name(name, what="name")
    except NeuralBakeError as exc:
        raise ManifestError(f"{where}: {exc}") from None
    options: dict[str, dict] = {}
    for k, v in row.items():
        if k in BASE_KEYS:
            continue
        stage, _, fld = k.partition(".")
        options.setdefault(stage, {})[fld] = v
    return AssetSpec(mesh=mesh_path, name=name, texture=_resolve(texture.strip(), base) if texture else None,
                     options=options, where=where)


def _resolve(path: str, base: Path) -> str:
    p = Path(os.path.expanduser(path))
    return os.path.normpath(p if p.is_absolute() else base / p)


def _check_unique(assets: list[AssetSpec]) -> None:
    seen_asset: dict[str, AssetSpec] = {}
    seen_name: dict[str, AssetSpec] = {}
    for a in assets:
        ident = json.dumps([os.path.realpath(a.mesh), a.texture, a.options], sort_keys=True, default=str)
        if ident in seen_asset:
            raise ManifestError(f"{a.where}: duplicate asset: {a.mesh} is already listed at "
                                f"{seen_asset[ident].where} with the same texture and options")
        seen_asset[ident] = a
        key = a.name.casefold()  # two names differing only in case are one folder on some file systems
        if key in seen_name:
            raise ManifestError(f"{a.where}: output name {a.name!r} is also the name of {seen_name[key].where} "
                                f"(set a distinct 'name' for one of them)")
        seen_name[key] = a
    names = {a.name for a in assets}
    for a in assets:  # "a" and "a/b" cannot both be asset folders
        parts = a.name.split("/")
        for i in range(1, len(parts)):
            if "/".join(parts[:i]) in names:
                raise ManifestError(f"{a.where}: output name {a.name!r} lies inside the folder of asset "
                                    f"{'/'.join(parts[:i])!r}")
