"""The benches' shared helpers: the bytecode written before timed commands run."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest


@pytest.fixture
def package(tmp_path, monkeypatch):
    """A two-level package ``bcpkg`` (with ``bcpkg.sub``) on sys.path, imported."""
    root = tmp_path / "bcpkg"
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text("X = 1\n")
    (root / "mod.py").write_text("Y = 2\n")
    (root / "sub" / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)  # the import writes none: compile_bytecode must
    importlib.invalidate_caches()
    importlib.import_module("bcpkg")
    yield root
    for name in [n for n in sys.modules if n == "bcpkg" or n.startswith("bcpkg.")]:
        del sys.modules[name]


def _pycs(root: Path) -> set[str]:
    return {p.name.split(".")[0] for p in root.rglob("*.pyc")}


def test_compile_bytecode_writes_every_module_once(package):
    from neural_bake.bench.common import compile_bytecode

    assert _pycs(package) == set()
    note = compile_bytecode(("bcpkg",))
    assert "was written" in note
    assert _pycs(package) == {"__init__", "mod"}  # both __init__ files share the stem
    assert len(list(package.rglob("*.pyc"))) == 3
    stamp = {p: p.stat().st_mtime_ns for p in package.rglob("*.pyc")}
    compile_bytecode(("bcpkg",))  # up to date: nothing rewritten
    assert {p: p.stat().st_mtime_ns for p in package.rglob("*.pyc")} == stamp


def test_compile_bytecode_names_a_folder_it_cannot_write(package):
    from neural_bake.bench.common import compile_bytecode

    (package / "__pycache__").write_text("a file where the cache folder goes")
    note = compile_bytecode(("bcpkg",))
    assert "could not be written" in note and str(package.resolve()) in note


def test_the_commands_packages_are_compiled():
    """The package list covers the folders pyproject.toml maps under the namespace (cli, pipelines, samples)."""
    from neural_bake.bench.common import PACKAGES

    folders = {Path(p).resolve().name for name in PACKAGES for p in importlib.import_module(name).__path__}
    assert {"neural_bake", "cli", "pipelines", "samples"} <= folders
