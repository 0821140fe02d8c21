"""Fault injection on the real `neural-bake` process: the output guarantees (outputs that never lose data).

Each run is a subprocess of the installed console script on a tiny bake (a low-resolution sphere sample, an
untrained 16x1 network, 16² maps, no baseline). ``NEURAL_BAKE_FAULT=STEP[#N]:SIGNAL`` makes the process send
itself SIGNAL at a named step of its writes (:mod:`neural_bake.io.faults`); after every kill the output folder
holds the complete old set or the complete new set, and no staging is left once the next run has started.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from neural_bake.io.mesh_io import load_mesh
from neural_bake.io.outdir import MANIFEST, NO_EXCHANGE_ENV, OutputLock
from neural_bake.fields import save_model
from neural_bake.nets.siren import Siren
from neural_bake.samples.shapes import get_sample

EXE = Path(sys.executable).with_name("neural-bake")
TINY = ["--coarse", "decimate:200", "--size", "16", "--no-baseline", "--force"]  # --force: an untrained SDF
OLD_MAPS = ["--maps", "normal,vertex"]  # the old set has vertex.glb/.ply, the new one does not
NEW_MAPS = ["--maps", "normal"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("outputs_cli")
    from neural_bake.samples.generate import write_sample

    obj = write_sample(get_sample("sphere").mesh(resolution=200, texture_size=32), d, "sphere")
    frame = load_mesh(obj).frame.to_dict()
    sdf = save_model(Siren(16, 1, generator=torch.Generator().manual_seed(0)), d / "s.sdf", kind="sdf", frame=frame)
    return {"obj": str(obj), "sdf": str(sdf), "dir": d}


def cli(*args, fault=None, two_renames=False, timeout=180, **kw):
    env = dict(os.environ)
    env.pop("NEURAL_BAKE_FAULT", None)
    if fault:
        env["NEURAL_BAKE_FAULT"] = fault
    if two_renames:
        env[NO_EXCHANGE_ENV] = "1"
    return subprocess.run([str(EXE), *map(str, args)], capture_output=True, text=True, timeout=timeout, env=env, **kw)


def bake(files, out, maps, **kw):
    return cli("bake", files["obj"], "--sdf", files["sdf"], *TINY, *maps, "-o", out, **kw)


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def which_set(out: Path, old: dict[str, bytes]) -> str:
    """"old" if ``out`` is byte for byte the old set, "new" if it is a complete new set; fails otherwise."""
    now = snapshot(out)
    if now == old:
        return "old"
    manifest = json.loads(now[MANIFEST])
    assert set(now) - {MANIFEST} == set(manifest["files"]), "a mixed folder"
    if "report.json" in now:  # a bake: its report lists the same files
        report = json.loads(now["report.json"])
        assert report["maps"] == ["normal"] and set(report["files"]) == set(manifest["files"]), "a mixed folder"
    else:  # samples: the new set is the sphere alone
        assert set(manifest["files"]) == {"sphere.obj", "sphere.mtl", "sphere.png"}, "a mixed folder"
    return "new"


def leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


def samples(out, names, **kw):
    return cli("samples", "--names", names, "--resolution", "32", "--texture-size", "8", "--out", out, **kw)


@pytest.fixture(scope="module")
def baked_old_set(files):
    out = files["dir"] / "old_bake"
    r = bake(files, out, OLD_MAPS)
    assert r.returncode == 0, r.stderr
    assert "vertex.glb" in {p.name for p in out.iterdir()}
    return out


@pytest.fixture()
def old_set(baked_old_set, tmp_path):
    """A copy of a committed bake (normal + vertex maps) in this test's own folder, and its bytes."""
    out = tmp_path / "out"
    shutil.copytree(baked_old_set, out)
    return out, snapshot(out)


@pytest.fixture()
def old_samples(tmp_path):
    out = tmp_path / "out"
    r = samples(out, "sphere,torus")
    assert r.returncode == 0, r.stderr
    return out, snapshot(out)


# (step, the set the folder holds after a kill there); "moved-old" exists only in the two-rename commit
KILL_POINTS = [("locked", "old"), ("file-renamed#1", "old"), ("file-renamed#4", "old"), ("staged", "old"),
               ("moved-old", "old"), ("exchanged", "new"), ("removing-old", "new"), ("cleaned", "new")]


@pytest.mark.parametrize("two_renames", [False, True], ids=["exchange", "two-renames"])
@pytest.mark.parametrize("step, expected", KILL_POINTS, ids=[s for s, _ in KILL_POINTS])
def test_sigkill_at_every_step_keeps_one_whole_set(old_samples, step, expected, two_renames):
    """SIGKILL at every step of the commit (the lightest writing verb, `samples`, drives the same commit)."""
    if step == "moved-old" and not two_renames:
        pytest.skip("the exchange has no step between two renames")
    out, old = old_samples
    r = samples(out, "sphere", fault=f"{step}:KILL", two_renames=two_renames)
    assert r.returncode == -signal.SIGKILL, r.stderr
    if step == "moved-old":  # killed between the renames: no folder until the next run moves the old set back
        assert not out.exists()
    else:
        assert which_set(out, old) == expected
    with OutputLock(out):  # what every next run for this output does first
        pass
    assert which_set(out, old) == expected
    assert leftovers(out.parent) == []


TERM_POINTS = [("locked", "old"), ("file-renamed#2", "old"), ("staged", "old"), ("moved-old", "new"),
               ("exchanged", "new"), ("removing-old", "new")]


@pytest.mark.parametrize("step, expected", TERM_POINTS, ids=[s for s, _ in TERM_POINTS])
def test_sigterm_cleans_up_says_one_line_and_exits_143(old_samples, step, expected):
    """SIGTERM is handled like SIGINT; signals that arrive during the renames wait for their end."""
    out, old = old_samples
    r = samples(out, "sphere", fault=f"{step}:TERM", two_renames=step == "moved-old")
    assert r.returncode == 143, r.stderr
    assert r.stderr.splitlines()[-1] == "neural-bake: terminated" and "Traceback" not in r.stderr
    assert which_set(out, old) == expected
    assert leftovers(out.parent) == []  # cleaned up by the run itself, not only by the next one


@pytest.mark.parametrize("fault, code, expected", [("staged:KILL", -signal.SIGKILL, "old"),
                                                   ("exchanged:KILL", -signal.SIGKILL, "new"),
                                                   ("file-renamed#2:TERM", 143, "old")])
def test_bake_killed_before_and_after_its_commit(files, old_set, fault, code, expected):
    out, old = old_set
    r = bake(files, out, NEW_MAPS, fault=fault)
    assert r.returncode == code, r.stderr
    assert which_set(out, old) == expected
    with OutputLock(out):
        pass
    assert which_set(out, old) == expected and leftovers(out.parent) == []


def test_sigint_cleans_up_too(old_samples):
    out, old = old_samples
    r = samples(out, "sphere", fault="staged:INT")
    assert r.returncode == 130 and r.stderr.splitlines()[-1] in ("neural-bake: interrupted", "neural-bake: aborted")
    assert which_set(out, old) == "old" and leftovers(out.parent) == []


def test_next_real_run_removes_what_a_killed_run_left(files, old_set):
    out, old = old_set
    r = bake(files, out, NEW_MAPS, fault="staged:KILL")
    assert r.returncode == -signal.SIGKILL
    assert any(".stage-" in n for n in leftovers(out.parent))  # the dead run's staging and lock file
    r = bake(files, out, NEW_MAPS)
    assert r.returncode == 0, r.stderr
    assert which_set(out, old) == "new" and leftovers(out.parent) == []
    # the next run after a kill between two renames finds no folder, restores the old set, then commits
    r = bake(files, out, OLD_MAPS, fault="moved-old:KILL", two_renames=True)
    assert r.returncode == -signal.SIGKILL and not out.exists()
    r = bake(files, out, NEW_MAPS)
    assert r.returncode == 0, r.stderr
    assert which_set(out, old) == "new" and leftovers(out.parent) == []


def test_kill_during_the_bake_at_a_random_moment(files, old_set):
    """Killed while its staging folder fills (not at a named step): the old set stays whole."""
    out, old = old_set
    env = dict(os.environ)
    proc = subprocess.Popen([str(EXE), "bake", files["obj"], "--sdf", files["sdf"], *TINY, *NEW_MAPS, "-o", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        stages = [p for p in out.parent.iterdir() if ".stage-" in p.name]
        if stages and any(stages[0].iterdir()):
            break
        time.sleep(0.005)
    proc.kill()
    proc.wait()
    assert which_set(out, old) in ("old", "new")
    with OutputLock(out):
        pass
    assert leftovers(out.parent) == []


def test_second_writer_fails_at_once_naming_the_first(files, old_set):
    out, old = old_set
    first = subprocess.Popen([str(EXE), "bake", files["obj"], "--sdf", files["sdf"], *TINY, *NEW_MAPS, "-o", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env={**os.environ, "NEURAL_BAKE_FAULT": "locked:STOP"})
    try:
        deadline = time.monotonic() + 120
        while not (out.parent / ".out.lock").exists() or (out.parent / ".out.lock").read_text().strip() != str(first.pid):
            assert time.monotonic() < deadline and first.poll() is None
            time.sleep(0.01)
        second = bake(files, out, NEW_MAPS)
        assert second.returncode == 1
        assert second.stderr == (f"neural-bake: error: {out}: another neural-bake run (pid {first.pid}) is writing "
                                 f"it; wait for it to finish or choose another output\n")
        # a run refused for its options does not touch the folder either (--truth sample:bogus)
        bogus = cli("bake", files["obj"], "--sdf", files["sdf"], *TINY, "--truth", "sample:bogus", "-o", out)
        assert bogus.returncode == 2 and "--truth sample:bogus: unknown sample 'bogus'" in bogus.stderr
        assert which_set(out, old) == "old"
    finally:
        first.send_signal(signal.SIGCONT)
    _, err = first.communicate(timeout=180)
    assert first.returncode == 0, err
    assert which_set(out, old) == "new" and leftovers(out.parent) == []


def test_failed_run_into_a_new_folder_deletes_nothing_another_run_made(files, tmp_path):
    """A run that fails while another commits the same new folder must not remove its result."""
    out = tmp_path / "fresh"
    r = cli("bake", files["obj"], "--sdf", files["sdf"], *TINY, "--truth", "sample:bogus", "-o", out)
    assert r.returncode == 2 and not out.exists()
    assert bake(files, out, NEW_MAPS).returncode == 0
    good = snapshot(out)
    # a failure in the middle of the work (a field without a surface to march) leaves the good result
    flat_model = Siren(4, 0, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        flat_model.layers[-1].weight.zero_()
        flat_model.layers[-1].bias.fill_(1.0)
    flat = save_model(flat_model, tmp_path / "flat.sdf", kind="sdf", frame={"center": [0, 0, 0], "scale": 1.0})
    r = cli("bake", files["obj"], "--sdf", flat, "--coarse", "march:8", "--size", "16", "--no-baseline", "-o", out)
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert snapshot(out) == good and leftovers(tmp_path) == []


FIT = ["--preset", "64x1", "--steps", "3", "--batch", "64", "--no-metrics", "--no-progress", "--compile", "off",
       "--micro-batches", "1", "--polish-evals", "0"]


def test_fit_sdf_killed_between_checkpoint_and_model_then_resumed(files, tmp_path):
    """fit sdf writes its checkpoint, then its model, each atomically: killed between them the old model is
    intact and the checkpoint whole; SIGTERM leaves no temporary file; --resume then finishes the run."""
    from neural_bake.fit.training import load_checkpoint

    model, ckpt = tmp_path / "m.sdf", tmp_path / "m.sdf.ckpt"
    shutil.copy(files["sdf"], model)
    old = model.read_bytes()
    args = ["fit", "sdf", files["obj"], "-o", model, *FIT]
    r = cli(*args, "--checkpoint", ckpt, fault="file-temp#2:TERM")  # the model's temporary file is complete
    assert r.returncode == 143 and r.stderr.splitlines()[-1] == "neural-bake: terminated"
    assert model.read_bytes() == old and sorted(p.name for p in tmp_path.iterdir()) == ["m.sdf", "m.sdf.ckpt"]
    r = cli(*args, "--checkpoint", ckpt, fault="file-temp#2:KILL")
    assert r.returncode == -signal.SIGKILL
    assert model.read_bytes() == old and load_checkpoint(ckpt)[2]["step"] == 3
    assert any(p.name.startswith(".m.sdf.") and ".tmp" in p.name for p in tmp_path.iterdir())  # the dead run's
    r = cli(*args, "--resume")  # the default checkpoint OUTPUT.ckpt, finished: writes the model
    assert r.returncode == 0, r.stderr
    assert model.read_bytes() != old and "resumed finished run" in r.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.sdf", "m.sdf.ckpt"]  # leftovers removed


# -------------------------------------------------------------------------------- outputs through a symlink
def linked(target: Path) -> Path:
    """A symlink ``links/out`` beside ``target`` pointing to it (relatively)."""
    links = target.parent / "links"
    links.mkdir(exist_ok=True)
    link = links / "out"
    link.symlink_to(Path("..") / target.name)
    return link


def test_bake_through_a_symlink_replaces_the_targets_set_and_keeps_the_link(files, old_set):
    """-o naming a symlink to an earlier bake: the new set is committed at the link's target (nothing of the
    old set left, nothing else deleted) and the link stays a link to it."""
    out, old = old_set
    link = linked(out)
    r = bake(files, link, NEW_MAPS)
    assert r.returncode == 0, r.stderr
    assert link.is_symlink() and os.readlink(link) == "../out"
    assert which_set(out, old) == "new" and "vertex.glb" not in snapshot(out)
    assert f"wrote {link}/:" in r.stdout and ".stage-" not in r.stdout + r.stderr
    assert leftovers(out.parent) == [] and sorted(p.name for p in link.parent.iterdir()) == ["out"]


@pytest.mark.parametrize("two_renames", [False, True], ids=["exchange", "two-renames"])
@pytest.mark.parametrize("step, expected", KILL_POINTS, ids=[s for s, _ in KILL_POINTS])
def test_sigkill_at_every_step_through_a_symlink_keeps_one_whole_set_and_the_link(old_samples, step, expected,
                                                                                  two_renames):
    if step == "moved-old" and not two_renames:
        pytest.skip("the exchange has no step between two renames")
    out, old = old_samples
    link = linked(out)
    r = samples(link, "sphere", fault=f"{step}:KILL", two_renames=two_renames)
    assert r.returncode == -signal.SIGKILL, r.stderr
    assert link.is_symlink() and os.readlink(link) == "../out"
    if step != "moved-old":
        assert which_set(out, old) == expected
    with OutputLock(link):  # what every next run through the link does first
        pass
    assert which_set(out, old) == expected and link.is_symlink()
    assert leftovers(out.parent) == [] and sorted(p.name for p in link.parent.iterdir()) == ["out"]


@pytest.mark.parametrize("fault, code, expected", [("staged:KILL", -signal.SIGKILL, "old"),
                                                   ("removing-old:KILL", -signal.SIGKILL, "new")])
def test_bake_through_a_symlink_killed_around_its_commit(files, old_set, fault, code, expected):
    out, old = old_set
    link = linked(out)
    r = bake(files, link, NEW_MAPS, fault=fault)
    assert r.returncode == code, r.stderr
    assert which_set(out, old) == expected and link.is_symlink()
    r = bake(files, link, NEW_MAPS)  # the next real run through the link removes what the killed one left
    assert r.returncode == 0, r.stderr
    assert which_set(out, old) == "new" and link.is_symlink() and leftovers(out.parent) == []


def test_symlinked_outputs_that_lead_nowhere(tmp_path):
    """A dangling link: its target is created (its folder exists) or one line, exit 2; a loop: one line, exit 2."""
    made = tmp_path / "made"
    link = tmp_path / "dangling"
    link.symlink_to("made")
    r = samples(link, "sphere")
    assert r.returncode == 0, r.stderr
    assert link.is_symlink() and (made / "sphere.obj").is_file()
    nowhere = tmp_path / "nowhere"
    nowhere.symlink_to("missing/made")
    (tmp_path / "loop1").symlink_to("loop2")
    (tmp_path / "loop2").symlink_to("loop1")
    for path, problem in ((nowhere, f"a symlink to {tmp_path / 'missing' / 'made'}, whose folder does not exist"),
                          (tmp_path / "loop1", "a symlink loop (the link never reaches a file or folder)")):
        r = samples(path, "sphere")
        assert r.returncode == 2 and r.stderr == f"neural-bake: error: {path}: {problem}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dangling", "loop1", "loop2", "made", "nowhere"]


def test_fit_sdf_through_a_symlinked_model_file(files, tmp_path):
    """A model file -o that is a symlink: the new model is written at its target and the link stays; killed
    before the rename, the target holds the old model."""
    models = tmp_path / "models"
    models.mkdir()
    target, link = models / "m.sdf", tmp_path / "m.sdf"
    shutil.copy(files["sdf"], target)
    link.symlink_to("models/m.sdf")
    old = target.read_bytes()
    args = ["fit", "sdf", files["obj"], "-o", link, "--checkpoint", tmp_path / "c.ckpt", *FIT]
    r = cli(*args, fault="file-temp#2:KILL")
    assert r.returncode == -signal.SIGKILL
    assert link.is_symlink() and target.read_bytes() == old
    r = cli(*args)
    assert r.returncode == 0, r.stderr
    assert link.is_symlink() and os.readlink(link) == "models/m.sdf" and target.read_bytes() != old
    assert sorted(p.name for p in models.iterdir()) == ["m.sdf"]  # the killed run's temporary file removed


BATCH = ["--set", "sdf.width=16", "--set", "sdf.depth=1", "--set", "sdf.steps=3", "--set", "sdf.minutes=none",
         "--set", "sdf.pool_surface=2000", "--set", "sdf.pool_near=2000", "--set", "sdf.pool_uniform=500",
         "--set", "sdf.batch=256", "--set", "sdf.batch_near=256", "--set", "sdf.batch_uniform=64",
         "--set", "sdf.polish_evals=0", "--set", "sdf.compile=off", "--set", "sdf.micro_batches=1",
         "--set", "nested.levels=none", "--set", "texture.width=16", "--set", "texture.depth=1",
         "--set", "texture.steps=3", "--set", "texture.minutes=none", "--set", "texture.pool=2000",
         "--set", "coarse.spec=decimate:200", "--set", "bake.size=16", "--set", "bake.baseline=false",
         "--set", "bake.force=true", "--workers", "1", "-q"]


@pytest.mark.slow
def test_concurrent_batches_into_one_folder(files, tmp_path):
    """A batch held at its lock: a second batch into the same folder fails at once naming it and changes
    nothing; the first killed there, the next batch takes the folder and keeps the earlier batch's asset."""
    one, other = tmp_path / "one.csv", tmp_path / "other.csv"
    one.write_text(f"mesh,name\n{files['obj']},ball\n")
    other.write_text(f"mesh,name\n{files['obj']},ball2\n")
    out = tmp_path / "out"
    r = cli("batch", one, "-o", out, *BATCH)
    assert r.returncode == 0, r.stderr
    summary = (out / "batch.json").read_bytes()
    # the same batch again (every stage cached: no worker) stops holding the lock
    first = subprocess.Popen([str(EXE), "batch", str(one), "-o", str(out), *BATCH], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env={**os.environ, "NEURAL_BAKE_FAULT": "locked:STOP"})
    try:
        lock = tmp_path / ".out.lock"
        deadline = time.monotonic() + 120
        while not lock.exists() or lock.read_text().strip() != str(first.pid):
            assert time.monotonic() < deadline and first.poll() is None
            time.sleep(0.01)
        second = cli("batch", other, "-o", out, *BATCH)
        assert second.returncode == 1
        assert second.stderr == (f"neural-bake: error: {out}: another neural-bake run (pid {first.pid}) is writing "
                                 f"it; wait for it to finish or choose another output\n")
        assert (out / "batch.json").read_bytes() == summary and not (out / "ball2").exists()
    finally:
        first.kill()
        first.communicate(timeout=60)
    r = cli("batch", other, "-o", out, *BATCH)
    assert r.returncode == 0, r.stderr
    merged = json.loads((out / "batch.json").read_text())
    assert {n: (a["status"], a["run"]) for n, a in merged["assets"].items()} == {"ball": ("ok", 1), "ball2": ("ok", 2)}
    assert leftovers(tmp_path) == []
