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
        "fit morph": (tmp_path / "mo.sdf", ["fit", "morph", files["obj"], files["obj"], "-o", str(tmp_path / "mo.sdf"),
                                            "--steps", "2"]),
        "fit sequence": (tmp_path / "sq.sdf", ["fit", "sequence", files["obj"], files["obj"], "-o",
                                               str(tmp_path / "sq.sdf"), "--steps", "2"]),
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


def test_view_of_a_write_protected_bake_folder_names_the_folder(files, tmp_path):
    bake = tmp_path / "out"
    assert run_cli(["bake", files["obj"], "--sdf", files["sdf"], *TINY_BAKE, "-o", bake]).returncode == 0
    before = sorted(p.name for p in bake.iterdir())
    os.chmod(bake, 0o555)
    try:
        r = run_cli(["view", bake, "--no-open", "--views", "1", "--size", "16"], unprivileged=True)
    finally:
        os.chmod(bake, 0o755)
    assert r.returncode == 1 and r.stderr == f"neural-bake: error: {bake}: Permission denied\n"
    assert sorted(p.name for p in bake.iterdir()) == before and sorted(p.name for p in tmp_path.iterdir()) == ["out"]


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


#: (verb, bytes left free): "no room for its lock" leaves less than the lock file's first block;
#: "render an image" fails inside OpenImageIO's writer, which gives no reason of its own
FULL_DISK_CASES = [("bake", 8192), ("fit sdf", 8192), ("fit sdf, no room for its lock", 0), ("render an image", 1024),
                   ("render a JPEG", 1024)]


@pytest.mark.parametrize("verb, leave", FULL_DISK_CASES, ids=[v for v, _ in FULL_DISK_CASES])
def test_full_disk_is_one_line_naming_the_users_output(files, full_disk, verb, leave):
    if verb == "bake":
        out = full_disk / "out"
        args = ["bake", files["obj"], "--sdf", files["sdf"], *TINY_BAKE, "-o", out]
    elif verb.startswith("render"):
        out = full_disk / ("shot.jpg" if verb.endswith("JPEG") else "shot.exr")
        args = ["render", files["sdf"], "--size", "128", "-o", out]
    else:
        out = full_disk / "m.sdf"
        args = ["fit", "sdf", files["obj"], "-o", out, *TINY_FIT]
    fill(full_disk, leave)
    r = run_cli(args)
    assert r.returncode == 1, r.stderr
    line = one_line(r.stderr)
    assert line.startswith(str(out)) and line.endswith("No space left on device"), line
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]  # no staging, temporary or lock file


# ---------------------------------------------------------------- every size a user can type is capped
@pytest.fixture(scope="module")
def timed(files):
    """A space-time SDF (kind spacetime_sdf, times [0, 1]) and one whose header's time extent is 1e308."""
    from neural_bake.fields import SpaceTimeField
    from neural_bake.types import Frame

    d = files["dir"]
    net = Siren(8, 1, in_dim=4, generator=torch.Generator().manual_seed(0))
    st = SpaceTimeField(net, frame=Frame(), time_range=(0.0, 1.0), time_extent=1.0).save(d / "st.sdf")
    huge = save_model(net, d / "huge-extent.sdf", kind="spacetime_sdf", frame=Frame().to_dict(),
                      time_range=[0.0, 1.0], time_extent=1e308)
    return {"st": str(st), "huge": str(huge)}


SCENE_CAPS = {
    "camera width": ("[camera]\nwidth = 100000\nheight = 8\n",
                     "camera: camera width 100000: must be a whole number in 1..16384"),
    "camera pixels": ("[camera]\nwidth = 16384\nheight = 16384\n", "camera: camera 16384x16384: 268435456 pixels"),
    "trace iterations": ("[trace]\niterations = [1000000000]\n", "trace: trace iterations: at most 100000 per level"),
    "trace chunk": ("[trace]\nchunk = 1000000000000\n", "trace: trace chunk: expected a whole number in 1..4194304"),
    "ambient occlusion samples": ("[ambient_occlusion]\nsamples = 1000000\n",
                                  "ambient_occlusion: ambient_occlusion samples"),
    "lights": ("[[lights]]\ndirection = [0, 0, -1]\n" * 65, "lights: at most 64, got 65"),
    "skip depth": ("skip_depth = 40\n", "skip_depth: expected a whole number in 1..8"),
}


@pytest.mark.parametrize("case", ["size", "size pixels", "t count", "frames", "time range", "time outside",
                                  "header time extent", "bake supersample", "bake supersample alone",
                                  "batch workers", "batch threads", "bake-frames t", "bake-frames resolution",
                                  *(f"scene {k}" for k in SCENE_CAPS)])
def test_cap(files, timed, tmp_path, capsys, monkeypatch, case):
    """Each size a user can type beyond its cap (neural_bake.constants) is one line, exit 2, naming the option
    or file, before anything of that size is allocated."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    png, gif = str(tmp_path / "x.png"), str(tmp_path / "x.gif")
    if case.startswith("scene "):
        text, want = SCENE_CAPS[case[len("scene "):]]
        scene = tmp_path / "scene.toml"
        scene.write_text(text)
        argv, want = ["render", files["sdf"], "-o", png, "--scene", str(scene)], f"{scene}: {want}"
    else:
        bake = ["bake", files["obj"], "--sdf", files["sdf"], "-o", str(tmp_path / "o"), "--no-baseline", "--force"]
        argv, want = {
            "size": (["render", files["sdf"], "-o", png, "--size", "100000"],
                     "--size 100000: must be a whole number in 1..16384"),
            "size pixels": (["render", files["sdf"], "-o", png, "--size", "8192x4096"],
                            "--size 8192x4096: 33554432 pixels, more than the 16777216"),
            "t count": (["render", timed["st"], "-o", gif, "--t", "0:1:1000000000"],
                        "--t: '0:1:1000000000' asks for 1000000000 times, more than 10000"),
            "frames": (["render", timed["st"], "-o", gif, "--frames", "1000000000"],
                       "--frames 1000000000: must be a whole number in 1..10000"),
            "time range": (["render", timed["st"], "-o", gif, "--time-range", "0,1e300"],
                           "--time-range 1e+300: must be a finite number within ±1e+30"),
            "time outside": (["render", timed["st"], "-o", gif, "--time-range", "0,5", "--frames", "3"],
                             "--time-range: t = 5 is outside the fitted time range [0, 1]"),
            "header time extent": (["render", timed["huge"], "-o", gif],
                                   f"{timed['huge']}: time_extent = 1e+308 is larger than 1e+30"),
            "bake supersample": ([*bake, "--size", "8192", "--supersample", "4"],
                                 "--supersample 4: a 8192x8192 map with 4x4 samples per texel has 32768 samples"),
            "bake supersample alone": ([*bake, "--size", "16", "--supersample", "100000"],
                                       "--supersample 100000: must be a whole number in 1..16384"),
            "batch workers": (["batch", files["obj"], "-o", str(tmp_path / "b"), "--workers", "100000"],
                              "--workers 100000: must be a whole number in 0..1024 (0: auto)"),
            "batch threads": (["batch", files["obj"], "-o", str(tmp_path / "b"), "--threads", "100000"],
                              "--threads 100000: must be a whole number in 0..1024 (0: auto)"),
            "bake-frames t": (["bake-frames", timed["st"], "--t", "0:1:1000000000", "-o", str(tmp_path / "f")],
                              "--t: '0:1:1000000000' asks for 1000000000 times, more than 10000"),
            "bake-frames resolution": (["bake-frames", timed["st"], "--t", "0:1:2", "--resolution", "100000",
                                        "-o", str(tmp_path / "f")],
                                       "--resolution 100000: must be a whole number in 2..1024"),
        }[case]
    assert main(argv) == 2
    assert one_line(capsys.readouterr().err).startswith(want)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name not in ("cache", "scene.toml")) == []


def test_times_on_a_static_model_are_refused(files, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    for option, value in (("--t", "0:1:3"), ("--time-range", "0,1"), ("--frames", "3")):
        assert main(["render", files["sdf"], "-o", str(tmp_path / "x.png"), option, value]) == 2
        assert one_line(capsys.readouterr().err) == (
            f"{option}: MODEL {files['sdf']} is a static SDF and has no time (it takes x, y, z); times are for a "
            f"space-time model")
    assert not (tmp_path / "x.png").exists()


# ------------------------------------------------------- a texture model of another object is refused
@pytest.fixture(scope="module")
def textured(tmp_path_factory, fit_sphere_siren):
    """The sphere and torus samples (one frame: both centred, longest side 1.8), a fitted SDF of the sphere,
    texture models fitted (briefly) on the sphere and on the torus, and the sphere's moved to another frame."""
    from neural_bake.fields import load_field, save_field
    from neural_bake.samples.generate import write_sample
    from neural_bake.types import Frame

    d = tmp_path_factory.mktemp("textured")
    obj = {n: write_sample(get_sample(n).mesh(resolution=1000, texture_size=16), d, n) for n in ("sphere", "torus")}
    sdf = save_model(fit_sphere_siren(r=0.9, width=32, steps=250), d / "sphere.sdf", kind="sdf",
                     frame=load_mesh(obj["sphere"]).frame.to_dict())
    tiny = ["--steps", "2", "--width", "16", "--depth", "0", "--no-progress", "--no-metrics"]
    for n in ("sphere", "torus"):
        assert main(["fit", "texture", str(obj[n]), "--sdf", str(sdf), "-o", str(d / f"{n}.tex"), *tiny]) == 0
    moved = load_field(d / "sphere.tex")
    moved.frame = Frame((0.0, 0.0, 0.0), 1.5)
    save_field(moved, d / "moved.tex")
    return {"obj": str(obj["sphere"]), "sdf": str(sdf), "dir": d,
            **{n: str(d / f"{n}.tex") for n in ("sphere", "torus", "moved")}}


def test_texture_records_the_surface_it_was_fitted_on(textured):
    import numpy as np

    from neural_bake.constants import TEXTURE_SURFACE_SAMPLES
    from neural_bake.fields import load_field

    surface = np.asarray(load_field(textured["torus"]).fitted_against["surface"])
    assert surface.shape == (TEXTURE_SURFACE_SAMPLES, 3)
    torus = get_sample("torus")
    rho = np.hypot(surface[:, 0], surface[:, 1])  # on the torus: (ρ − R)² + z² = r²
    np.testing.assert_allclose(np.hypot(rho - torus.major, surface[:, 2]), torus.minor, atol=0.02)


BAKE_TINY = ["--coarse", "decimate:100", "--size", "16", "--maps", "normal,albedo", "--no-baseline"]


@pytest.mark.parametrize("verb", ["bake", "render"])
@pytest.mark.parametrize("texture,problem", [("torus", "fitted on another surface than sphere.sdf: median |f| at "
                                                         "the texture's 256 surface points is "),
                                             ("moved", "fitted in another frame than sphere.sdf: the frames differ by")])
def test_a_texture_of_another_object_is_refused(textured, tmp_path, capsys, monkeypatch, verb, texture, problem):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    out = tmp_path / ("o" if verb == "bake" else "x.png")
    if verb == "bake":
        argv = ["bake", textured["obj"], "--sdf", textured["sdf"], "--texture-model", textured[texture], *BAKE_TINY]
    else:
        argv = ["render", textured["sdf"], "--texture", textured[texture], "--size", "16"]
    assert main([*argv, "-o", str(out)]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"{texture}.tex: {problem}") and line.endswith(
        "; give the texture model fitted with this SDF, or --force uses it anyway"), line
    assert not out.exists()
    from neural_bake.errors import NeuralBakeWarning

    with pytest.warns(NeuralBakeWarning) as caught:  # forced: made, with a warning
        assert main([*argv, "-o", str(out), "--force"]) == 0, capsys.readouterr().err
    said = [str(w.message) for w in caught if str(w.message).startswith(f"{texture}.tex: ")]
    assert len(said) == 1 and said[0].startswith(f"{texture}.tex: {problem}"), said
    assert said[0].endswith("used anyway (--force)")
    assert out.exists()


def test_the_right_texture_bakes_and_renders(textured, tmp_path, capsys, monkeypatch):
    import json

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert main(["bake", textured["obj"], "--sdf", textured["sdf"], "--texture-model", textured["sphere"], *BAKE_TINY,
                 "-o", str(tmp_path / "o")]) == 0
    check = json.loads((tmp_path / "o" / "report.json").read_text())["sdf_check"]["texture"]
    assert check["passed"] and check["frame_mismatch"] == 0 and check["median_abs_f"] < 0.02
    assert main(["render", textured["sdf"], "--texture", textured["sphere"], "--size", "16",
                 "-o", str(tmp_path / "x.png")]) == 0
    assert "warning" not in capsys.readouterr().err


def test_bake_frames_refuses_a_texture_of_another_frame(textured, timed, tmp_path, capsys):
    out = tmp_path / "f"
    assert main(["bake-frames", timed["st"], "--t", "0:1:2", "--resolution", "8", "--texture", textured["moved"],
                 "-o", str(out)]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith("moved.tex: fitted in another frame than st.sdf: the frames differ by 0.5"), line
    assert not out.exists()


# ---------------------------------------------- a file's kind fixes its networks' inputs, for every verb
@pytest.mark.parametrize("verb", ["fit nested", "fit texture", "render", "bake", "bake-frames"])
def test_a_four_input_network_labelled_static_is_refused_by_every_verb(files, tmp_path, capsys, monkeypatch, verb):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    bad = save_model(Siren(8, 1, in_dim=4, generator=torch.Generator().manual_seed(0)), tmp_path / "st4.sdf",
                     kind="sdf", frame=load_mesh(files["obj"]).frame.to_dict())
    out = tmp_path / "out"
    argv = {"fit nested": ["fit", "nested", bad, "-o", out, "--steps", "2"],
            "fit texture": ["fit", "texture", files["obj"], "--sdf", bad, "-o", out, "--steps", "2"],
            "render": ["render", bad, "-o", tmp_path / "out.gif", "--size", "8", "--frames", "2"],
            "bake": ["bake", files["obj"], "--sdf", bad, *TINY_BAKE, "-o", out],
            "bake-frames": ["bake-frames", bad, "--t", "0:1:2", "--resolution", "8", "-o", out]}[verb]
    assert main([str(a) for a in argv]) == 2
    assert one_line(capsys.readouterr().err) == (
        f"{bad}: kind 'sdf' is a static SDF mapping R^3 (x, y, z) to R, this network maps R^4 to R^1 (a space-time "
        f"SDF is kind 'spacetime_sdf', with its time range)")
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "cache") == ["st4.sdf"]


@pytest.mark.parametrize("argv, want", [(["--size", "100000"], "--size 100000: must be a whole number in 16..4096"),
                                        (["--views", "100000"], "--views 100000: must be a whole number in 1..720"),
                                        (["--views", "0"], "--views 0: must be a whole number in 1..720")])
def test_view_sizes_are_capped(capsys, tmp_path, argv, want):
    """`view`'s image size and view count are refused in one line before anything is rendered or written."""
    assert main(["view", str(tmp_path / "bake"), "--no-open", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.endswith(want) and list(tmp_path.iterdir()) == []
