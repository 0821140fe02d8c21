"""The layout cache: entries read back as written, keyed by content and settings, damaged entries made again,
the least recently used pruned, a cache that cannot be written costs only the entry; the mesh .npz format."""

import numpy as np
import pytest

from neural_bake.errors import MeshError
from neural_bake.io.mesh_npz import load_mesh_npz, save_mesh_npz
from neural_bake.io.mesh_io import load_mesh
from neural_bake.mesh.decimate import decimate
from neural_bake.mesh.layout_cache import LayoutCache, mesh_digest
from neural_bake.mesh.unwrap import unwrap
from neural_bake.samples.generate import sample_path


@pytest.fixture(scope="module")
def coarse():
    return decimate(load_mesh(sample_path("torus")), faces=200)


class Clock:
    def __init__(self):
        self.t = 1_000_000.0

    def __call__(self):
        self.t += 10.0
        return self.t


def assert_same_mesh(a, b):
    for name in ("vertices", "faces", "uv", "vertex_normals", "degenerate"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y), name
    assert a.frame.to_dict() == b.frame.to_dict() and a.uv_policy == b.uv_policy and a.watertight == b.watertight


def test_an_unwrapped_mesh_reads_back_as_written(coarse, tmp_path):
    layout = unwrap(coarse, resolution=64)
    save_mesh_npz(layout, tmp_path / "m.npz", {"faces": layout.n_faces, "spec": "decimate:200"})
    back, extra = load_mesh_npz(tmp_path / "m.npz")
    assert_same_mesh(layout, back)
    assert np.array_equal(back.source_vertex, layout.source_vertex)
    assert extra == {"faces": layout.n_faces, "spec": "decimate:200"}


def test_a_damaged_or_foreign_file_is_a_mesh_error_naming_it(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file")
    with pytest.raises(MeshError, match="bad.npz"):
        load_mesh_npz(bad)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(MeshError, match="other.npz"):
        load_mesh_npz(tmp_path / "other.npz")


def test_keys_follow_content_settings_and_kind(coarse, tmp_path):
    cache = LayoutCache(tmp_path)
    d0 = mesh_digest(coarse)
    assert d0 == mesh_digest(decimate(load_mesh(sample_path("torus")), faces=200))  # same content, same digest
    nudged = decimate(load_mesh(sample_path("torus")), faces=200)
    nudged.vertices = nudged.vertices.copy()
    nudged.vertices[0, 0] += 1e-12
    assert mesh_digest(nudged) != d0
    keys = {cache.key("unwrap", d0, "resolution=64"), cache.key("unwrap", d0, "resolution=128"),
            cache.key("coarse", d0, "resolution=64"), cache.key("unwrap", mesh_digest(nudged), "resolution=64")}
    assert len(keys) == 4
    assert cache.key("unwrap", d0, "resolution=64") == LayoutCache(tmp_path / "x").key("unwrap", d0, "resolution=64")


def test_get_or_make_makes_once_then_reads(coarse, tmp_path):
    cache = LayoutCache(tmp_path / "layouts")
    calls = []

    def make():
        calls.append(1)
        return unwrap(coarse, resolution=64), {"n": 1}

    key = cache.key("unwrap", mesh_digest(coarse), "resolution=64")
    first, extra1, hit1 = cache.get_or_make(key, make)
    second, extra2, hit2 = cache.get_or_make(key, make)
    assert (hit1, hit2) == (False, True) and len(calls) == 1 and extra1 == extra2 == {"n": 1}
    assert_same_mesh(first, second)


def test_a_damaged_entry_is_made_again_and_replaced(coarse, tmp_path):
    cache = LayoutCache(tmp_path)
    key = cache.key("unwrap", mesh_digest(coarse), "resolution=64")
    cache.put(key, unwrap(coarse, resolution=64))
    cache.path(key).write_bytes(b"\x00" * 100)  # a torn or damaged file
    assert cache.get(key) is None and not cache.path(key).exists()
    mesh, _, hit = cache.get_or_make(key, lambda: (unwrap(coarse, resolution=64), {}))
    assert not hit and cache.get(key) is not None


def test_least_recently_used_entries_are_pruned(coarse, tmp_path):
    cache = LayoutCache(tmp_path, max_entries=2, clock=Clock())
    keys = [cache.key("unwrap", f"mesh{i}") for i in range(3)]
    cache.put(keys[0], coarse)
    cache.put(keys[1], coarse)
    assert cache.get(keys[0]) is not None  # used: now the most recent
    cache.put(keys[2], coarse)
    assert [cache.path(k).exists() for k in keys] == [True, False, True]


def test_a_cache_that_cannot_be_written_only_loses_the_entry(coarse, tmp_path):
    blocked = tmp_path / "file"
    blocked.write_text("a file where the cache folder would be")
    cache = LayoutCache(blocked / "layouts")
    mesh, _, hit = cache.get_or_make(cache.key("unwrap", "m"), lambda: (coarse, {}))
    assert mesh is coarse and not hit and cache.get(cache.key("unwrap", "m")) is None


def test_unwrap_through_the_cache_equals_unwrap_and_follows_its_options(coarse, tmp_path):
    cache = LayoutCache(tmp_path)
    first, hit1 = cache.unwrap(coarse, resolution=64)
    again, hit2 = cache.unwrap(coarse, resolution=64)
    other, hit3 = cache.unwrap(coarse, resolution=128)
    assert (hit1, hit2, hit3) == (False, True, False)
    assert_same_mesh(first, unwrap(coarse, resolution=64))
    assert_same_mesh(first, again)
    assert np.array_equal(again.source_vertex, first.source_vertex)
    assert len(list(tmp_path.glob("unwrap-*.npz"))) == 2
