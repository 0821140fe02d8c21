"""Output paths from input files cannot leave their root: '..', absolute paths, hidden names, symlinks."""

import os

import pytest

from neural_bake.errors import NeuralBakeError
from neural_bake.io.paths import check_relative_name, inside


def test_plain_names(tmp_path):
    assert inside(tmp_path, "a") == tmp_path / "a"
    assert inside(tmp_path, "chars/hero") == tmp_path / "chars" / "hero"
    assert str(check_relative_name("x/y.z")) == "x/y.z"


@pytest.mark.parametrize("name,message", [
    ("", "empty"), ("/abs", "relative path"), ("../x", "'..'"), ("a/./b", "'.'"), ("a/", "empty"),
    (".stage", "reserved"), ("a/.b", "reserved"), ("a\\b", "backslashes"), ("a\nb", "control"), ("D:/x", "relative"),
])
def test_refused_names(tmp_path, name, message):
    with pytest.raises(NeuralBakeError, match=message):
        inside(tmp_path, name)


def test_symlinks_out_of_the_root_are_refused(tmp_path):
    root, other = tmp_path / "out", tmp_path / "elsewhere"
    root.mkdir()
    other.mkdir()
    os.symlink(other, root / "link")
    with pytest.raises(NeuralBakeError, match="outside the output folder"):
        inside(root, "link")
    with pytest.raises(NeuralBakeError, match="outside the output folder"):
        inside(root, "link/asset")
    os.symlink(root / "real", root / "alias")  # a symlink that stays inside is fine
    assert inside(root, "alias/x") == root / "alias" / "x"
    os.symlink("/", root / "top")
    with pytest.raises(NeuralBakeError, match="outside"):
        inside(root, "top")
