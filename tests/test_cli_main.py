"""cli/main.py: help, version, exit codes and the one-line error format."""

import subprocess
import sys
from pathlib import Path

import click
import pytest

from neural_bake import __version__
from neural_bake.cli import main as main_module
from neural_bake.cli.main import _format_warning, main
from neural_bake.errors import MeshError, NeuralBakeWarning

EXE = Path(sys.executable).with_name("neural-bake")


def test_help_lists_verbs(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("Usage: neural-bake [OPTIONS] COMMAND [ARGS]...")
    assert "Commands:" in out and "inspect" in out and "Typical run:" in out
    assert main(["-h"]) == 0
    assert capsys.readouterr().out == out


def test_no_arguments_shows_help(capsys):
    assert main([]) == 2  # click: a group without a command shows its help, usage exit code
    assert "Commands:" in capsys.readouterr().err  # as a usage error: on stderr


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"neural-bake, version {__version__}"


def test_unknown_verb_and_missing_argument(capsys):
    assert main(["frobnicate"]) == 2
    assert "No such command 'frobnicate'" in capsys.readouterr().err
    assert main(["inspect"]) == 2
    assert "Missing argument 'MESH'" in capsys.readouterr().err
    assert main(["inspect", "--bogus", "x.obj"]) == 2
    assert "No such option '--bogus'" in capsys.readouterr().err


@pytest.mark.parametrize("argv, problem", [
    (["bake"], "missing --sdf, --output (needed unless --print-config)"),
    (["inspect"], "Missing argument 'MESH'"),
    (["inspect", "--bogus", "x.obj"], "No such option '--bogus'"),
    (["frobnicate"], "No such command 'frobnicate'"),
    (["samples", "--resolution", "many"], "Invalid value for '--resolution': 'many' is not a valid integer"),
])
def test_usage_errors_are_one_line_exit_2(capsys, argv, problem):
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.err == f"neural-bake: error: {problem}\n" and captured.out == ""


def test_verb_help(capsys):
    assert main(["inspect", "--help"]) == 0
    out = capsys.readouterr().out
    assert "Usage: neural-bake inspect [OPTIONS] MESH" in out and "--json" in out


def test_user_error_is_one_line_exit_2(capsys, monkeypatch):
    @click.command()
    def boom():
        raise MeshError("cow.obj: face index 812 out of range\n(mesh has 400 vertices)")

    monkeypatch.setitem(main_module.cli.lazy, "boom", ("neural_bake.cli.main", "_boom_for_test"))
    monkeypatch.setattr(main_module, "_boom_for_test", boom, raising=False)
    assert main(["boom"]) == 2
    captured = capsys.readouterr()
    assert captured.err == "neural-bake: error: cow.obj: face index 812 out of range (mesh has 400 vertices)\n"
    assert captured.out == ""


def test_keyboard_interrupt_exit_130(capsys, monkeypatch):
    @click.command()
    def stop():
        raise KeyboardInterrupt

    monkeypatch.setitem(main_module.cli.lazy, "stop", ("neural_bake.cli.main", "_stop_for_test"))
    monkeypatch.setattr(main_module, "_stop_for_test", stop, raising=False)
    assert main(["stop"]) == 130
    assert capsys.readouterr().err.strip() == "neural-bake: aborted"  # click turns Ctrl-C into Abort


def test_warning_format():
    assert _format_warning("a.obj: mesh is open", NeuralBakeWarning, "x.py", 1) == "neural-bake: warning: a.obj: mesh is open\n"


@pytest.mark.skipif(not EXE.exists(), reason="console script not installed")
def test_console_script(tmp_path):
    r = subprocess.run([str(EXE), "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "inspect" in r.stdout
    r = subprocess.run([str(EXE), "inspect", str(tmp_path / "none.obj")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == f"neural-bake: error: {tmp_path / 'none.obj'}: no such file\n"


@pytest.mark.parametrize("other_thread", [False, True])
def test_finish_flushes_runs_exit_handlers_and_keeps_the_code(other_thread):
    # the console script's end: buffered output and exit handlers survive the fast exit; a thread still running
    # is waited for (the usual exit)
    code = "\n".join([
        "import atexit, sys, threading, time",
        "from neural_bake.cli.main import finish",
        "atexit.register(lambda: print('handler ran'))",
        "sys.stdout.write('x' * 200000 + '\\n')",
        "t = threading.Thread(target=lambda: (time.sleep(0.3), print('thread done', flush=True)))",
        "t.start()" if other_thread else "",
        "finish(3)",
    ])
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 3, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "x" * 200000 and "handler ran" in lines
    assert ("thread done" in lines) == other_thread


def test_library_errors_name_parameters_and_the_cli_names_its_options(monkeypatch, tmp_path, capsys):
    from neural_bake.mesh.coarse import parse_coarse
    from neural_bake.cli.main import OPTIONS, cli_message
    from neural_bake.errors import NeuralBakeError
    from neural_bake.fit.nested import parse_levels

    for call, name in ((lambda: parse_coarse("melt:3"), "coarse"), (lambda: parse_levels("8by0"), "levels")):
        with pytest.raises(NeuralBakeError) as info:
            call()
        assert info.value.parameter == name and str(info.value).startswith(name) and "--" not in str(info.value)
        assert cli_message(info.value) == "--" + str(info.value)
    assert cli_message(NeuralBakeError("max_boxes 3: too few", parameter="max_boxes")) == "--max-boxes 3: too few"
    monkeypatch.setitem(OPTIONS, "max_boxes", "--boxes")
    assert cli_message(NeuralBakeError("max_boxes 3: too few", parameter="max_boxes")) == "--boxes 3: too few"
    # no parameter, or a message that does not start with it: the message as it is
    assert cli_message(NeuralBakeError("levels.txt: missing")) == "levels.txt: missing"
    assert cli_message(NeuralBakeError("bad levels", parameter="levels")) == "bad levels"
    # end to end: the verb's error names its option
    model = tmp_path / "m.sdf"
    model.write_bytes(b"")
    assert main(["fit", "nested", str(model), "-o", str(tmp_path / "o"), "--levels", "8by0"]) == 2
    assert "neural-bake: error: --levels: '8by0' is not WIDTHxDEPTH" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["0", "many", "-2"])
def test_bad_threads_is_one_line(capsys, monkeypatch, value):
    monkeypatch.setenv("NEURAL_BAKE_THREADS", "1")
    assert main(["--threads", value, "inspect", "nosuch.obj"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--threads" in err and value in err


def test_threads_option_fixes_the_count_for_the_run(capsys, monkeypatch, tmp_path):
    """--threads N reaches the library (and child processes) through NEURAL_BAKE_THREADS."""
    import os

    from neural_bake.nets.threads import fixed_threads

    monkeypatch.setenv("NEURAL_BAKE_THREADS", "auto")
    assert main(["--threads", "2", "inspect", str(tmp_path / "nosuch.obj")]) == 2  # the verb's own error
    assert os.environ["NEURAL_BAKE_THREADS"] == "2" and fixed_threads() == 2
