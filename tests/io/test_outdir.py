"""OutputFolder / OutputLock in process: a folder committed as a unit, one writer, leftovers of dead runs removed.

The same guarantees under SIGKILL / SIGTERM of the real CLI process are in tests/test_cli_outputs.py.
"""

import errno
import json
import os

import pytest

from neural_bake.errors import NeuralBakeError, OutputBusyError, OutputError, WriteError
from neural_bake.io.atomic import atomic_write_text
from neural_bake.io.outdir import MANIFEST, NO_EXCHANGE_ENV, OutputFolder, OutputLock, locked_outputs, record_in_set

DEAD_PID = 4_194_305  # above Linux's largest pid_max (2**22): never a living process


def files_of(folder):
    return {p.name: p.read_text() for p in folder.iterdir()}


def write_set(out, files):
    with OutputFolder(out) as stage:
        for name, text in files.items():
            atomic_write_text(stage / name, text)


@pytest.fixture(params=["exchange", "two renames"])
def commit_way(request, monkeypatch):
    if request.param == "two renames":
        monkeypatch.setenv(NO_EXCHANGE_ENV, "1")
    return request.param


def test_commit_new_folder_then_replace_the_set_as_a_whole(tmp_path, commit_way):
    out = tmp_path / "out"
    write_set(out, {"a.txt": "one", "b.txt": "one"})
    assert files_of(out) == {"a.txt": "one", "b.txt": "one", MANIFEST: (out / MANIFEST).read_text()}
    assert json.loads((out / MANIFEST).read_text())["files"] == ["a.txt", "b.txt"]
    umask = os.umask(0)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o777 & ~umask  # a folder's usual mode, not a staging folder's 0700
    os.chmod(out, 0o750)
    write_set(out, {"a.txt": "two"})  # b.txt is not part of the new set: it goes with the old one
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "a.txt"]
    assert (out / "a.txt").read_text() == "two" and out.stat().st_mode & 0o777 == 0o750  # the mode is kept
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging, old set or lock file left


def test_failed_body_leaves_the_old_set_and_nothing_else(tmp_path, commit_way):
    out = tmp_path / "out"
    write_set(out, {"a.txt": "one"})
    before = files_of(out)
    with pytest.raises(RuntimeError, match="bake failed"):
        with OutputFolder(out) as stage:
            atomic_write_text(stage / "a.txt", "half")
            raise RuntimeError("bake failed")
    assert files_of(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    # a failed first run into a new folder creates nothing
    with pytest.raises(KeyboardInterrupt):
        with OutputFolder(tmp_path / "new") as stage:
            atomic_write_text(stage / "a.txt", "x")
            raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_folder_with_foreign_files_is_refused_untouched(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match=r"mine: holds files no neural-bake run wrote there \(notes.txt\)") as e:
        with OutputFolder(out):
            pytest.fail("the body must not run")
    assert e.value.exit_code == 2
    assert files_of(out) == {"notes.txt": "mine"} and sorted(p.name for p in tmp_path.iterdir()) == ["mine"]
    # a file added next to a committed set is foreign too
    write_set(tmp_path / "set", {"a.txt": "1"})
    (tmp_path / "set" / "extra.txt").write_text("user's")
    with pytest.raises(OutputError, match=r"\(extra.txt\)"):
        write_set(tmp_path / "set", {"a.txt": "2"})
    assert (tmp_path / "set" / "a.txt").read_text() == "1"


def test_bad_output_paths(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputError, match="f: exists and is not a folder"):
        write_set(tmp_path / "f", {"a": "1"})
    with pytest.raises(OutputError, match=r"b: folder .*nope does not exist"):
        write_set(tmp_path / "nope" / "b", {"a": "1"})
    with pytest.raises(OutputError, match="is a folder"):
        with locked_outputs(tmp_path):
            pass
    with pytest.raises(OutputError, match="does not exist"):
        with locked_outputs(tmp_path / "nope" / "m.sdf"):
            pass


def test_second_writer_fails_at_once_naming_the_holder(tmp_path):
    out = tmp_path / "out"
    with OutputFolder(out) as stage:
        atomic_write_text(stage / "a.txt", "1")
        with pytest.raises(OutputBusyError, match=rf"out: another neural-bake run \(pid {os.getpid()}\) is writing it"):
            with OutputFolder(out):
                pass
        assert stage.is_dir()  # the refused writer removed nothing of the first one
    assert (out / "a.txt").read_text() == "1"
    with locked_outputs(tmp_path / "m.sdf", None):
        with pytest.raises(OutputBusyError) as e:
            with OutputLock(tmp_path / "m.sdf"):
                pass
        assert e.value.exit_code == 1
    with OutputLock(tmp_path / "m.sdf"):  # released: free again
        pass


def test_leftovers_of_dead_runs_are_removed_and_others_kept(tmp_path):
    out = tmp_path / "out"
    write_set(out, {"a.txt": "1"})
    dead_stage = tmp_path / f".out.stage-{DEAD_PID}-x1"
    dead_old = tmp_path / f".out.old-{DEAD_PID}-x2"
    for d in (dead_stage, dead_old):
        d.mkdir()
        (d / "f").write_text("x")
    dead_tmp = tmp_path / f".m.sdf.{DEAD_PID}.abc123.tmp.sdf"
    dead_tmp.write_text("x")
    alike = [tmp_path / ".outer.stage-1-x", tmp_path / f".out.b.{DEAD_PID}.x.tmp", tmp_path / "other.txt"]
    for p in alike:  # names of other outputs and the user's files: untouched
        p.write_text("keep")
    write_set(out, {"a.txt": "2"})
    with OutputLock(tmp_path / "m.sdf"):
        pass
    assert not dead_stage.exists() and not dead_old.exists() and not dead_tmp.exists()
    assert all(p.read_text() == "keep" for p in alike)
    assert (out / "a.txt").read_text() == "2"


def test_cut_between_two_renames_is_rolled_back(tmp_path):
    """A two-rename commit killed between its renames: OUT missing, the old set aside, the stage complete.
    The next run for OUT (any lock of it) puts the old set back and drops the stage."""
    out = tmp_path / "out"
    write_set(out, {"a.txt": "old"})
    stage = tmp_path / f".out.stage-{DEAD_PID}-s"
    stage.mkdir()
    (stage / "a.txt").write_text("new")
    os.rename(out, tmp_path / f".out.old-{DEAD_PID}-o")
    with OutputLock(out):
        assert (out / "a.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    # after the second rename (no stage of that pid left) the old set is a leftover, not restored
    old = tmp_path / f".out.old-{DEAD_PID}-o"
    old.mkdir()
    (old / "a.txt").write_text("older")
    with OutputLock(out):
        pass
    assert (out / "a.txt").read_text() == "old" and not old.exists()


def test_entries_added_later_join_the_set(tmp_path):
    """A report written into a committed bake folder (neural-bake view) is recorded, so the next run
    replaces it with the rest instead of refusing the folder."""
    out = tmp_path / "out"
    write_set(out, {"a.txt": "1"})
    (out / "report").mkdir()
    (out / "report" / "index.html").write_text("<html>")
    record_in_set(out, "report")
    assert json.loads((out / MANIFEST).read_text())["files"] == ["a.txt", "report"]
    write_set(out, {"a.txt": "2"})
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "a.txt"]
    plain = tmp_path / "plain"
    plain.mkdir()
    record_in_set(plain, "x")  # not a committed set: nothing written
    assert list(plain.iterdir()) == []


def test_os_errors_name_the_output_never_the_stage(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(WriteError) as e:
        with OutputFolder(out) as stage:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(stage / "normal.png"))
    assert str(e.value) == f"{out}/normal.png: No space left on device" and e.value.exit_code == 1
    assert ".stage-" not in str(e.value) and not out.exists()
    with pytest.raises(NeuralBakeError) as e:
        with OutputFolder(out) as stage:
            raise NeuralBakeError(f"{stage / 'asset.glb'}: cannot write image")
    assert str(e.value) == f"{out}/asset.glb: cannot write image"


# ----------------------------------------------------------------------------------------------- symlinks
@pytest.mark.usefixtures("commit_way")
def test_a_symlinked_output_commits_at_its_target_and_stays_a_link(tmp_path):
    real, links = tmp_path / "real", tmp_path / "links"
    links.mkdir()
    write_set(real, {"a.txt": "old", "b.txt": "old"})
    link = links / "out"
    link.symlink_to("../real")
    write_set(link, {"a.txt": "new"})
    assert link.is_symlink() and os.readlink(link) == "../real"
    assert files_of(real) == {"a.txt": "new", MANIFEST: files_of(real)[MANIFEST]}
    assert sorted(p.name for p in links.iterdir()) == ["out"]  # no staging, lock or old set beside the link
    assert sorted(p.name for p in tmp_path.iterdir()) == ["links", "real"]


def test_a_dangling_symlink_output_creates_its_target_a_loop_is_refused(tmp_path):
    link = tmp_path / "out"
    link.symlink_to("made")
    write_set(link, {"a.txt": "1"})
    assert link.is_symlink() and (tmp_path / "made" / "a.txt").read_text() == "1"
    nowhere = tmp_path / "nowhere"
    nowhere.symlink_to("missing/made")
    with pytest.raises(OutputError, match=rf"^{nowhere}: a symlink to {tmp_path / 'missing' / 'made'}, whose "
                                          rf"folder does not exist$"):
        write_set(nowhere, {"a.txt": "1"})
    (tmp_path / "loop1").symlink_to("loop2")
    (tmp_path / "loop2").symlink_to("loop1")
    with pytest.raises(OutputError, match=r"loop1: a symlink loop"):
        write_set(tmp_path / "loop1", {"a.txt": "1"})
    with pytest.raises(OutputError, match=r"loop1: a symlink loop"):
        with locked_outputs(tmp_path / "loop1"):
            pass
    assert not (tmp_path / "missing").exists()


def test_removing_the_old_set_or_leftovers_never_follows_a_symlink(tmp_path):
    """Symlinks inside a replaced set or among a dead run's leftovers are unlinked; what they point to stays."""
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "keep.txt").write_text("keep")
    out = tmp_path / "out"
    write_set(out, {"a.txt": "1"})
    (out / "sub").symlink_to(precious)  # a link inside the old set (as a later step could add)
    (out / "f").symlink_to(precious / "keep.txt")
    record_in_set(out, "sub", "f")
    dead_stage = tmp_path / f".out.stage-{DEAD_PID}-x1"  # a leftover that is a link to someone's folder
    dead_stage.symlink_to(precious)
    write_set(out, {"a.txt": "2"})
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "a.txt"]
    assert not os.path.lexists(dead_stage)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "precious"]  # the old set went, links and all
    old_as_link = tmp_path / f".out.stage-{os.getpid()}-x2"  # an old set that is a link is unlinked, not walked
    old_as_link.symlink_to(precious)
    OutputFolder(out)._remove_old(old_as_link)
    assert not os.path.lexists(old_as_link)
    assert sorted(p.name for p in precious.iterdir()) == ["keep.txt"] and (precious / "keep.txt").read_text() == "keep"
