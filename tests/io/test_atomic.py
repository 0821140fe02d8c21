"""atomic_path and friends: a failed writer leaves the old file intact and no temporary file behind."""

import os
import stat

import pytest

from neural_bake.io.atomic import atomic_path, atomic_write_bytes, atomic_write_text


def test_write_and_replace(tmp_path):
    p = tmp_path / "a.bin"
    atomic_write_bytes(p, b"one")
    assert p.read_bytes() == b"one"
    atomic_write_bytes(p, b"two")
    assert p.read_bytes() == b"two"
    assert [q.name for q in tmp_path.iterdir()] == ["a.bin"]


def test_text(tmp_path):
    p = atomic_write_text(tmp_path / "t.txt", "héllo\n")
    assert p.read_text(encoding="utf-8") == "héllo\n"


def test_failing_writer_keeps_old_file_and_cleans_up(tmp_path):
    p = tmp_path / "model.png"
    p.write_bytes(b"good")
    with pytest.raises(RuntimeError, match="disk on fire"):
        with atomic_path(p) as tmp:
            tmp.write_bytes(b"half-writ")
            raise RuntimeError("disk on fire")
    assert p.read_bytes() == b"good"
    assert [q.name for q in tmp_path.iterdir()] == ["model.png"]


def test_interrupt_also_cleans_up(tmp_path):
    p = tmp_path / "x.obj"
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(p) as tmp:
            tmp.write_text("v 0 0 0\n")
            raise KeyboardInterrupt
    assert not list(tmp_path.iterdir())


def test_empty_output_is_an_error_for_binary_files(tmp_path):
    p = tmp_path / "m.glb"
    p.write_bytes(b"old")
    with pytest.raises(OSError, match="writer produced no data"):
        with atomic_path(p):
            pass  # writer wrote nothing
    assert p.read_bytes() == b"old"
    assert [q.name for q in tmp_path.iterdir()] == ["m.glb"]
    atomic_write_text(tmp_path / "empty.json", "")  # text formats may be empty
    assert (tmp_path / "empty.json").read_text() == ""


def test_writer_that_removes_the_temporary_file(tmp_path):
    p = tmp_path / "a.ply"
    with pytest.raises(OSError, match="writer produced no data"):
        with atomic_path(p) as tmp:
            tmp.unlink()
    assert not list(tmp_path.iterdir())


def test_temporary_keeps_suffix_and_folder(tmp_path):
    with atomic_path(tmp_path / "map.exr") as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".exr"
        tmp.write_bytes(b"x")
    with atomic_path(tmp_path / "map.exr", suffix=".png") as tmp:
        assert tmp.suffix == ".png"
        tmp.write_bytes(b"y")
    assert (tmp_path / "map.exr").read_bytes() == b"y"


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
def test_permissions_follow_umask_or_replaced_file(tmp_path):
    umask = os.umask(0o022)
    try:
        p = atomic_write_bytes(tmp_path / "new.bin", b"1")
        assert stat.S_IMODE(p.stat().st_mode) == 0o644  # not mkstemp's private 0600
        q = tmp_path / "old.bin"
        q.write_bytes(b"0")
        q.chmod(0o640)
        atomic_write_bytes(q, b"1")
        assert stat.S_IMODE(q.stat().st_mode) == 0o640
    finally:
        os.umask(umask)


def test_missing_folder_raises_and_writes_nothing(tmp_path):
    with pytest.raises(FileNotFoundError):
        atomic_write_bytes(tmp_path / "no" / "a.bin", b"1")
    assert not list(tmp_path.iterdir())


def test_a_symlinked_destination_is_written_at_its_target_and_stays_a_link(tmp_path):
    from neural_bake.errors import OutputError

    target = tmp_path / "models" / "m.sdf"
    target.parent.mkdir()
    target.write_bytes(b"old")
    link = tmp_path / "m.sdf"
    link.symlink_to("models/m.sdf")
    atomic_write_bytes(link, b"new")
    assert link.is_symlink() and os.readlink(link) == "models/m.sdf" and target.read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.sdf", "models"]
    assert sorted(p.name for p in target.parent.iterdir()) == ["m.sdf"]
    dangling = tmp_path / "d.sdf"
    dangling.symlink_to("models/made.sdf")
    atomic_write_bytes(dangling, b"made")
    assert dangling.is_symlink() and (target.parent / "made.sdf").read_bytes() == b"made"
    (tmp_path / "l1").symlink_to("l2")
    (tmp_path / "l2").symlink_to("l1")
    with pytest.raises(OutputError, match="l1: a symlink loop"):
        atomic_write_bytes(tmp_path / "l1", b"x")
