"""bake/preload.py: the source mesh read, decimated and unwrapped in a forked process, the same as here.

Forking is only safe in a process that has not imported torch, so the forking tests run in a fresh interpreter
(``python -c``), as the CLI does; the bake end to end with and without the preload is in tests/test_cli_bake.py.
"""

import json
import subprocess
import sys

import numpy as np
import pytest

from neural_bake.bake import preload
from neural_bake.bake.job import coarse_of_source
from neural_bake.io.asset import read_asset
from neural_bake.io.mesh_io import load_mesh
from neural_bake.mesh.unwrap import unwrap
from neural_bake.samples.shapes import get_sample


@pytest.fixture(scope="module")
def obj(tmp_path_factory):
    from neural_bake.samples.generate import write_sample

    d = tmp_path_factory.mktemp("preload")
    return str(write_sample(get_sample("sphere").mesh(resolution=400, texture_size=32), d, "sphere"))


def _same_mesh(a, b) -> None:
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    assert (a.uv is None) == (b.uv is None) and (a.uv is None or np.array_equal(a.uv, b.uv))
    assert a.frame.to_dict() == b.frame.to_dict() and a.warnings == b.warnings


def test_load_source_makes_what_the_bake_makes_itself(obj):
    got = preload.load_source(obj, coarse="decimate:200", layout_size=64)
    fine = load_mesh(obj)
    _same_mesh(got.fine, fine)
    assert got.reference is got.fine and read_asset(obj, fine).corner_normals is None
    coarse, info = coarse_of_source(fine, "decimate:200", mesh_path=obj)
    _same_mesh(got.coarse[0], coarse)
    assert got.coarse[1]["faces"] == info["faces"] and got.coarse[0].uv is None
    _same_mesh(got.layout, unwrap(coarse, resolution=64))
    assert got.layout_size == 64 and set(got.seconds) == {"load", "coarse", "unwrap"}
    assert got.made(got.coarse[0]) and not got.made(coarse)
    # no decimation asked (keep, or a march that needs the model): the mesh only
    for spec in ("keep", "march:32", None):
        only = preload.load_source(obj, coarse=spec, layout_size=64)
        assert only.coarse is None and only.layout is None and set(only.seconds) == {"load"}


def test_no_fork_in_a_process_that_imported_torch_or_when_switched_off(monkeypatch, obj):
    import torch  # noqa: F401 - the condition under test

    assert "torch is imported" in preload.can_fork()
    assert preload.start(obj, coarse="decimate:200") is None
    monkeypatch.setenv(preload.ENV_SWITCH, "0")
    assert preload.can_fork() == f"{preload.ENV_SWITCH}=0"


_SCRIPT = r"""
import json, os, sys, threading, time
import numpy as np
from neural_bake.bake import preload

obj, bad, big = sys.argv[1], sys.argv[2], sys.argv[3]
out = {}
pre = preload.start(obj, coarse="decimate:200", layout_size=64)
got = pre.result()
here = preload.load_source(obj, coarse="decimate:200", layout_size=64)
out["same"] = all(np.array_equal(getattr(a, k), getattr(b, k))
                  for a, b in ((got.fine, here.fine), (got.coarse[0], here.coarse[0]), (got.layout, here.layout))
                  for k in ("vertices", "faces")) and np.array_equal(got.layout.uv, here.layout.uv)
out["summary"] = pre.summary()
out["again"] = pre.result() is got  # waited for once
# a file the loader refuses: no result, the failure kept, the bake then reads the file itself
failed = preload.start(bad, coarse="decimate:200")
out["failed"] = [failed.result() is None, failed.failure]
# a child that dies before it answers
dead = preload.start(obj, coarse="decimate:200")
dead._process.kill()
out["dead"] = [dead.result() is None, dead.failure]
# Ctrl-C reaches the child too: it goes on (the parent handles it); a termination ends it quietly
import signal
calm = preload.start(obj, coarse="decimate:200")
os.kill(calm._process.pid, signal.SIGINT)
out["sigint"] = calm.result() is not None
ended = preload.start(obj, coarse="decimate:200")
os.kill(ended._process.pid, signal.SIGTERM)
out["sigterm"] = [ended.result() is None, ended.failure]
# a parent that stops listening: the child ends without a word, even with more to send than a pipe holds
gone = preload.start(big, coarse="decimate:200", layout_size=64)
gone._conn.close()
gone._process.join(timeout=120)
out["gone"] = gone._process.exitcode
out["torch"] = "torch" in sys.modules
# a pool's worker (a daemonic process) may not have children: it does the work itself
import multiprocessing as mp
def probe(conn):
    conn.send([preload.can_fork(), preload.start(obj) is None])
    conn.close()
here, there = mp.get_context("fork").Pipe(duplex=False)
worker = mp.get_context("fork").Process(target=probe, args=(there,), daemon=True)
worker.start()
out["daemon"] = here.recv()
worker.join()
stop = threading.Event()
t = threading.Thread(target=stop.wait)
t.start()
out["thread"] = [preload.can_fork(), preload.start(obj) is None]
stop.set()
t.join()
print(json.dumps(out))
"""


def test_a_forked_child_makes_the_same_meshes_and_its_failures_fall_back(obj, tmp_path):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    env = {k: v for k, v in __import__("os").environ.items() if k != preload.ENV_SWITCH}
    from neural_bake.samples.generate import write_sample

    big = write_sample(get_sample("sphere").mesh(resolution=20000), tmp_path, "big")
    r = subprocess.run([sys.executable, "-c", _SCRIPT, obj, str(bad), str(big)], capture_output=True, text=True,
                       timeout=300, env=env)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["same"] and out["again"] and not out["torch"]  # the whole preload is torch-free
    s = out["summary"]
    assert s["failure"] is None and set(s["seconds"]) == {"load", "coarse", "unwrap"} and s["waited"] >= 0
    assert out["failed"][0] and out["failed"][1].startswith("the preloading process failed: MeshError: ")
    assert str(bad) in out["failed"][1]
    assert out["dead"] == [True, "the preloading process died"]
    assert out["sigint"] and out["sigterm"] == [True, "the preloading process died"] and out["gone"] == 0
    assert "Traceback" not in r.stderr and "KeyboardInterrupt" not in r.stderr
    assert out["thread"] == ["another thread runs", True]
    assert out["daemon"] == ["a daemonic process (a pool's worker) cannot have children", True]


def test_the_load_warnings_the_child_did_not_show_are_issued_here(obj, tmp_path):
    from neural_bake.errors import NeuralBakeWarning

    open_mesh = tmp_path / "open.obj"
    open_mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n")
    with pytest.warns(NeuralBakeWarning) as seen:
        fine = load_mesh(open_mesh)
    assert fine.warnings and [str(w.message) for w in seen] == fine.warnings
    with pytest.warns(NeuralBakeWarning) as again:
        preload.reissue_warnings(fine)
    assert [str(w.message) for w in again] == fine.warnings
