"""Batch manifests: CSV, JSON, text and glob forms, and every manifest that is refused before any work."""

import json
import os

import pytest

from neural_bake.pipelines.manifest import ManifestError, read_manifest


@pytest.fixture
def meshes(tmp_path):
    d = tmp_path / "m"
    (d / "sub").mkdir(parents=True)
    for name in ("a.obj", "b.obj", "sub/c.ply"):
        (d / name).write_text("# not read by the manifest\n")
    return d


def test_csv_with_overrides_and_relative_paths(meshes):
    (meshes / "list.csv").write_text("mesh,name,texture,sdf.minutes,bake.size\n"
                                     "a.obj,hero,tex.png,0.5,\n"
                                     "\n"
                                     "sub/c.ply,,,,1024\n")
    assets = read_manifest(meshes / "list.csv")
    assert [a.name for a in assets] == ["hero", "c"]
    assert assets[0].mesh == str(meshes / "a.obj") and assets[0].texture == str(meshes / "tex.png")
    assert assets[0].options == {"sdf": {"minutes": "0.5"}}  # empty cells keep the batch's value
    assert assets[1].options == {"bake": {"size": "1024"}} and assets[1].texture is None
    assert assets[1].where.endswith("list.csv:4")


def test_json_forms(meshes):
    (meshes / "l.json").write_text(json.dumps({"assets": [
        "a.obj", {"mesh": "b.obj", "name": "x/b", "bake": {"size": 256}, "sdf.seed": 3}]}))
    assets = read_manifest(meshes / "l.json")
    assert [a.name for a in assets] == ["a", "x/b"]
    assert assets[1].options == {"bake": {"size": 256}, "sdf": {"seed": 3}}
    (meshes / "l2.json").write_text(json.dumps(["sub/c.ply"]))
    assert read_manifest(meshes / "l2.json")[0].mesh == str(meshes / "sub" / "c.ply")


def test_text_file_and_glob(meshes, monkeypatch):
    (meshes / "list.txt").write_text("# assets\n\na.obj\n  sub/c.ply  \n")
    assert [a.name for a in read_manifest(meshes / "list.txt")] == ["a", "c"]
    monkeypatch.chdir(meshes)
    assert [a.name for a in read_manifest("*.obj")] == ["a", "b"]
    assert [a.name for a in read_manifest("**/*.*")] == ["a", "b", "list", "c"]


@pytest.mark.parametrize("name,text,message", [
    ("e.txt", "# nothing\n\n", "lists no asset"),
    ("e.csv", "", "lists no asset"),
    ("h.csv", "mesh,name\n", "lists no asset"),
    ("e.json", "[]", "lists no asset"),
    ("bad.json", "{not json", "not valid JSON"),
    ("obj.json", '{"meshes": []}', "needs an 'assets' list"),
    ("num.json", "[3]", "an asset is a mesh path or an object"),
    ("col.csv", "path\nx.obj\n", "no 'mesh' column"),
    ("unk.csv", "mesh,size\na.obj,3\n", "column 'size': unknown"),
    ("stage.csv", "mesh,render.size\na.obj,3\n", "column 'render.size': unknown"),
    ("field.csv", "mesh,sdf.minuts\na.obj,3\n", r"field.csv:1: column 'sdf.minuts': unknown setting \(did you mean "
                                                 r"sdf.minutes\?\)$"),
    ("field.json", '[{"mesh": "a.obj", "bake": {"nosuch": 1}}]', r"field.json\[0\]: key 'bake.nosuch': unknown "
                                                                  r"setting$"),
    ("preset.csv", "mesh,coarse.preset\na.obj,quick\n", "column 'coarse.preset': the coarse stage has no presets"),
    ("nomesh.json", '[{"name": "x"}]', "no mesh path"),
    ("wide.csv", "mesh\na.obj,b.obj\n", "more cells than header columns"),
])
def test_refused_manifests(meshes, name, text, message):
    (meshes / name).write_text(text)
    with pytest.raises(ManifestError, match=message) as info:
        read_manifest(meshes / name)
    assert name in str(info.value)


def test_missing_manifest_folder_and_empty_glob(meshes):
    with pytest.raises(ManifestError, match="no such manifest file"):
        read_manifest(meshes / "nope.csv")
    with pytest.raises(ManifestError, match="is a folder"):
        read_manifest(meshes)
    with pytest.raises(ManifestError, match="matches no file"):
        read_manifest(str(meshes / "*.fbx"))


def test_duplicate_asset_and_same_output_name(meshes):
    (meshes / "dup.txt").write_text("a.obj\nb.obj\n./a.obj\n")
    with pytest.raises(ManifestError, match=r"dup.txt:3: duplicate asset: .*a.obj is already listed at .*dup.txt:1"):
        read_manifest(meshes / "dup.txt")
    # the same mesh with other options is two assets, but they need two names
    (meshes / "same.csv").write_text("mesh,bake.size\na.obj,512\na.obj,1024\n")
    with pytest.raises(ManifestError, match=r"same.csv:3: output name 'a' is also the name of .*same.csv:2"):
        read_manifest(meshes / "same.csv")
    (meshes / "named.csv").write_text("mesh,name,bake.size\na.obj,a512,512\na.obj,a1024,1024\n")
    assert [a.name for a in read_manifest(meshes / "named.csv")] == ["a512", "a1024"]
    # different meshes, one name (case differs only)
    (meshes / "case.csv").write_text("mesh,name\na.obj,Hero\nb.obj,hero\n")
    with pytest.raises(ManifestError, match="output name 'hero'"):
        read_manifest(meshes / "case.csv")
    (meshes / "nest.csv").write_text("mesh,name\na.obj,x\nb.obj,x/y\n")
    with pytest.raises(ManifestError, match="lies inside the folder of asset 'x'"):
        read_manifest(meshes / "nest.csv")


@pytest.mark.parametrize("name", ["../up", "a/../../b", "/etc/x", ".hidden", "a//b", "a\\b", "C:x", " "])
def test_names_that_would_leave_out_are_refused(meshes, name):
    (meshes / "n.json").write_text(json.dumps([{"mesh": "a.obj", "name": name}]))
    with pytest.raises(ManifestError, match="n.json\\[0\\]: name"):
        read_manifest(meshes / "n.json")


def test_missing_mesh_is_not_a_manifest_error(meshes):
    """A mesh that does not exist fails alone in the batch (tests/pipelines/test_batch.py), not here."""
    (meshes / "m.txt").write_text("a.obj\nmissing.obj\n")
    assets = read_manifest(meshes / "m.txt")
    assert not os.path.exists(assets[1].mesh)
