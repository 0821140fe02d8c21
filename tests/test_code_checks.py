"""The maintainers' checks, run with the suite (so `make test` and CI run them): ruff's lint rules and
mypy's type check of the library, both configured in pyproject.toml, and the import rules of docs/design.md,
import-linter contracts in .importlinter."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(module: str, *args: str) -> subprocess.CompletedProcess:
    if importlib.util.find_spec(module) is None:
        pytest.fail(f"{module} is not installed: it is in the test extras, rerun `make setup`")
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=900)


def test_ruff_lint_passes():
    res = _run("ruff", "check", "--no-cache", ".")
    assert res.returncode == 0, res.stdout + res.stderr


def test_mypy_type_check_of_the_library_passes():
    res = _run("mypy")  # files and settings: [tool.mypy] in pyproject.toml
    assert res.returncode == 0, res.stdout + res.stderr
    assert "Success" in res.stdout


def _installed_layout(root: Path) -> Path:
    """A folder holding ``neural_bake`` as it is installed (pyproject.toml package-dir): the library's entries,
    with cli/, pipelines/ and samples/ as its subpackages, all symbolic links to the checkout."""
    pkg = root / "neural_bake"
    pkg.mkdir()
    for entry in (ROOT / "neural_bake").iterdir():
        if entry.name != "__pycache__":
            (pkg / entry.name).symlink_to(entry)
    for name in ("cli", "pipelines", "samples"):
        (pkg / name).symlink_to(ROOT / name)
    return root


def test_import_contracts_of_the_design_hold(tmp_path):
    if importlib.util.find_spec("importlinter") is None:
        pytest.fail("import-linter is not installed: it is in the test extras, rerun `make setup`")
    layout = _installed_layout(tmp_path)
    # lint-imports puts its working folder first on sys.path: run it in the layout so the package found is the
    # one laid out there, whose cli, pipelines and samples are where the installed package has them
    code = ("import sys; from importlinter.cli import lint_imports; "
            "sys.exit(lint_imports(config_filename=sys.argv[1], no_cache=True))")
    res = subprocess.run([sys.executable, "-c", code, str(ROOT / ".importlinter")], cwd=layout,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "0 broken" in res.stdout, res.stdout
