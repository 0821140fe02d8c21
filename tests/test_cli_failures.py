"""Every failure a writing verb can meet gives one line and the right exit code, and loses nothing.

In process: outputs held by another writer (every writing verb), bad numbers and degenerate inputs refused
before any work. In a subprocess of the console script: permission denied (as root, the CLI runs without the
capability that overrides permissions) and a full disk (a tiny tmpfs when mounting is allowed; a file-size limit always).
"""

import os
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
import torch

from neural_bake.cli.main import main
from neural_bake.io.mesh_io import load_mesh
from neural_bake.io.outdir import OutputLock
from neural_bake.fields import save_model
from neural_bake.nets.siren import Siren
from neural_bake.samples.shapes import get_sample

EXE = Path(sys.executable).with_name("neural-bake")
TINY_BAKE = ["--coarse", "decimate:100", "--size", "16", "--maps", "normal", "--no-baseline", "--force"]  # untrained SDF
TINY_FIT = ["--preset", "64x1", "--steps", "2", "--batch", "64", "--no-metrics", "--no-progress", "--compile", "off",
            "--micro-batches", "1", "--polish-evals", "0"]


@pytest.fixture(scope="module")
def files():
    """Inputs in a world-readable folder (the permission tests run the CLI without permission overrides)."""
    d = Path(tempfile.mkdtemp(prefix="nb-failures-"))
    os.chmod(d, 0o755)
    from neural_bake.samples.generate import write_sample

    obj = write_sample(get_sample("sphere").mesh(resolution=200, texture_size=32), d, "sphere")
    mesh = load_mesh(obj)
    sdf = save_model(Siren(16, 1, generator=torch.Generator().manual_seed(0)), d / "s.sdf", kind="sdf",
                     frame=mesh.frame.to_dict())
    text = obj.read_text().splitlines()
    (d / "huge.obj").write_text("\n".join(
        "v " + " ".join(repr(float(x) * 1e300) for x in line.split()[1:]) if line.startswith("v ") else line
        for line in text) + "\n")
    (d / "flatuv.obj").write_text("\n".join("vt 0 0" if line.startswith("vt ") else line for line in text) + "\n")
    for p in d.iterdir():
        os.chmod(p, 0o644)
    yield {"obj": str(obj), "sdf": str(sdf), "dir": d, "huge": str(d / "huge.obj"), "flatuv": str(d / "flatuv.obj")}
    shutil.rmtree(d, ignore_errors=True)


def one_line(err: str) -> str:
    assert err.startswith("neural-bake: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    return err[len("neural-bake: error: "):].rstrip("\n")


# ------------------------------------------------------------------------------------ bad numbers, bad inputs
def test_huge_mesh_is_a_clear_mesh_error(files, capsys):
    for argv in (["inspect", files["huge"]],
                 ["bake", files["huge"], "--sdf", files["sdf"], *TINY_BAKE, "-o", str(files["dir"] / "o")]):
        assert main(argv) == 2
        assert "huge.obj: vertex 0 has a coordinate of magnitude" in one_line(capsys.readouterr().err)
    assert not (files["dir"] / "o").exists()


def test_uvs_all_at_one_point_with_coarse_keep_are_refused(files, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["bake", files["flatuv"], "--sdf", files["sdf"], "--coarse", "keep", "--size", "16", "--no-baseline",
                 "--force", "-o", str(out)]) == 2
    assert one_line(capsys.readouterr().err) == (
        f"{files['flatuv']}: its UV layout covers 0 of the UV square, less than one texel of the 16x16 map; "
        f"bake with --coarse decimate or march, which unwrap a new layout")
    assert not out.exists()


def test_truth_of_another_sample_is_refused_before_the_bake(files, tmp_path, capsys):
    assert main(["bake", files["obj"], "--sdf", files["sdf"], *TINY_BAKE, "--truth", "sample:torus",
                 "-o", str(tmp_path / "o")]) == 2
    assert "--truth sample:torus: " in one_line(capsys.readouterr().err)
    assert not (tmp_path / "o").exists()


# -------------------------------------------------------------------------- one writer, for every verb
def test_every_writing_verb_refuses_an_output_another_run_holds(files, tmp_path, capsys):
    model, tex = tmp_path / "m.sdf", tmp_path / "t.tex"
    shutil.copy(files["sdf"], model)
    verbs = {
        "bake": (tmp_path / "out", ["bake", files["obj"], "--sdf", files["sdf"], *TINY_BAKE, "-o", str(tmp_path / "out")]),
        "samples": (tmp_path / "s", ["samples", "--names", "sphere", "--out", str(tmp_path / "s")]),
        "demo": (tmp_path / "d", ["demo", "--out", str(tmp_path / "d")]),
        "fit sdf": (model, ["fit", "sdf", files["obj"], "-o", str(model), *TINY_FIT]),
        "fit sdf checkpoint": (tmp_path / "c.ckpt", ["fit", "sdf", files["obj"], "-o", str(tmp_path / "n.sdf"),
                                                     "--checkpoint", str(tmp_path / "c.ckpt"), *TINY_FIT]),
        "fit texture": (tex, ["fit", "texture", files["obj"], "--sdf", files["sdf"], "-o", str(tex), "--steps", "2"]),
        "fit nested": (tmp_path / "n.nested", ["fit", "nested", files["sdf"], "-o", str(tmp_path / "n.nested"),
                                               "--steps", "2"]),
        "bench --json": (tmp_path / "b.json", ["bench", "normals", "--quick", "--json", str(tmp_path / "b.json")]),
    }
    before = model.read_bytes()
    for name, (held, argv) in verbs.items():
        with OutputLock(held):
            assert main(argv) == 1, name
            assert one_line(capsys.readouterr().err) == (
                f"{held}: another neural-bake run (pid {os.getpid()}) is writing it; wait for it to finish or "
                f"choose another output"), name
    assert model.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.sdf"]  # nothing written, no lock file left


def test_outputs_in_missing_folders_are_refused_before_any_work(files, tmp_path, capsys):
    nope = tmp_path / "nope"
    for argv in (["fit", "texture", files["obj"], "--sdf", files["sdf"], "-o", str(nope / "t.tex")],
                 ["fit", "nested", files["sdf"], "-o", str(nope / "n.nested")],
                 ["bench", "normals", "--quick", "--json", str(nope / "b.json")]):
        assert main(argv) == 2
        assert one_line(capsys.readouterr().err).endswith(f": folder {nope} does not exist")


# ------------------------------------------------------------------------ the environment refuses: exit 1
#: root passes permission checks: the permission tests run the CLI as root without that capability
NO_OVERRIDE = ["setpriv", "--inh-caps=-dac_override,-dac_read_search", "--bounding-set=-dac_override,-dac_read_search"]


def run_cli(args, *, unprivileged=False, fsize=None, timeout=300):
    def limit():
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    prefix = []
    if unprivileged and os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv: no way to be refused a write")
        prefix = NO_OVERRIDE
    env = dict(os.environ)
    env.pop("NEURAL_BAKE_FAULT", None)
    return subprocess.run([*prefix, str(EXE), *map(str, args)], capture_output=True, text=True, timeout=timeout,
                          env=env, preexec_fn=limit)


@pytest.fixture()
def locked_folder():
    """A folder the CLI may not write into (mode 0555)."""
    d = Path(tempfile.mkdtemp(prefix="nb-readonly-"))
    os.chmod(d, 0o555)
    yield d
    os.chmod(d, 0o755)
    shutil.rmtree(d, ignore_errors=True)


@pytest.mark.parametrize("verb", ["bake", "fit sdf", "bake into an existing folder"])
def test_permission_denied_is_one_line_and_exit_1(files, locked_folder, verb):
    if verb == "fit sdf":
        target = locked_folder / "m.sdf"
        args = ["fit", "sdf", files["obj"], "-o", target, *TINY_FIT]
    else:
        target = locked_folder / "out"
        if verb == "bake into an existing folder":  # the folder itself writable, its parent not
            os.chmod(locked_folder, 0o755)
            target.mkdir()
            os.chmod(target, 0o777)
            os.chmod(locked_folder, 0o555)
        args = ["bake", files["obj"], "--sdf", files["sdf"], *TINY_BAKE, "-o", target]
    r = run_cli(args, unprivileged=True)
    assert r.returncode == 1, r.stderr
    assert r.stderr == f"neural-bake: error: {target}: Permission denied\n"
    assert sorted(p.name for p in locked_folder.iterdir()) == (["out"] if verb.endswith("folder") else [])


@pytest.mark.parametrize("verb", ["bake", "fit sdf"])
def test_file_size_limit_is_one_line_naming_the_users_file(files, tmp_path, verb):
    """A write the system refuses half-way (here: over RLIMIT_FSIZE, EFBIG) names the user's file, exit 1,
    and leaves the earlier good output and no temporary file."""
    if verb == "bake":
        out = tmp_path / "out"
        assert run_cli(["bake", files["obj"], "--sdf", files["sdf"], *TINY_BAKE, "-o", out]).returncode == 0
        args = ["bake", files["obj"], "--sdf", files["sdf"], *TINY_BAKE, "-o", out]
    else:
        out = tmp_path / "m.sdf"
        shutil.copy(files["sdf"], out)
        args = ["fit", "sdf", files["obj"], "-o", out, *TINY_FIT]
    before = {p.name: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} if verb == "bake" else out.read_bytes()
    r = run_cli(args, fsize=4096)
    assert r.returncode == 1, r.stderr
    line = one_line(r.stderr)
    assert line.startswith(str(out)) and line.endswith(": File too large") and ".stage-" not in line
    assert ".tmp" not in line
    after = {p.name: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} if verb == "bake" else out.read_bytes()
    assert after == before


@pytest.fixture()
def full_disk():
    """A 256 KiB tmpfs filled but for a few KiB (skipped where mounting is not allowed)."""
    d = Path(tempfile.mkdtemp(prefix="nb-full-"))
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k,mode=0755", "tmpfs", str(d)], capture_output=True)
    if r.returncode != 0:
        d.rmdir()
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
    try:
        yield d
    finally:
        subprocess.run(["umount", str(d)], check=False)
        shutil.rmtree(d, ignore_errors=True)


def fill(folder: Path, leave: int) -> None:
    st = os.statvfs(folder)
    (folder / "filler").write_bytes(b"\0" * max(0, st.f_bavail * st.f_frsize - leave))


@pytest.mark.parametrize("verb", ["bake", "fit sdf"])
def test_full_disk_is_one_line_naming_the_users_output(files, full_disk, verb):
    if verb == "bake":
        out = full_disk / "out"
        args = ["bake", files["obj"], "--sdf", files["sdf"], *TINY_BAKE, "-o", out]
    else:
        out = full_disk / "m.sdf"
        args = ["fit", "sdf", files["obj"], "-o", out, *TINY_FIT]
    fill(full_disk, 8192)
    r = run_cli(args)
    assert r.returncode == 1, r.stderr
    line = one_line(r.stderr)
    assert line.startswith(str(out)) and line.endswith("No space left on device"), line
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]  # no staging, temporary or lock file
