"""The batch on a real local Ray instance (``ray.init`` on this machine; Ray is in the test extras)."""

import json

import pytest

from neural_bake.pipelines.batch import BatchConfig, run_batch

ray = pytest.importorskip("ray", reason="Ray is an optional extra: pip install -e '.[ray]'")


def test_batch_on_local_ray(tmp_path, tiny):
    from neural_bake.samples.generate import write_sample
    from neural_bake.samples.shapes import get_sample

    sphere = write_sample(get_sample("sphere").mesh(resolution=400, texture_size=64), tmp_path, "sphere")
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps([{"mesh": str(sphere), "name": "ball"},
                                    {"mesh": str(sphere), "name": "bad", "bake": {"padding": "smear"}}]))
    out = tmp_path / "out"
    events = []
    summary = run_batch(manifest, out, BatchConfig(stages=tiny(), executor="ray", workers=2),
                        log=lambda m: None, on_event=lambda kind, name, **info: events.append((kind, name)))
    assert not ray.is_initialized()  # the instance it started is shut down
    assert summary["executor"] == "ray" and (summary["ok"], summary["failed"]) == (1, 1)
    ball = summary["assets"]["ball"]
    assert set(s["status"] for s in ball["stages"].values()) == {"done"}
    assert ball["metrics"]["bake"]["normal_deg_vs_gradient"]["median"] < 1.0
    assert (out / "ball" / "bake" / "asset.glb").is_file()
    # an error inside a task is the asset's one-line reason, as on the local pool
    assert summary["assets"]["bad"]["status"] == "failed" and "padding" in summary["assets"]["bad"]["reason"]
    assert ("start", "ball") in events and ("end", "ball") in events
    # the same batch again on Ray: every stage skipped
    again = run_batch(manifest, out, BatchConfig(stages=tiny(), executor="ray", workers=2), log=lambda m: None)
    assert set(s["status"] for s in again["assets"]["ball"]["stages"].values()) == {"cached"}
