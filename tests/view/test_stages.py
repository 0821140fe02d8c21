"""The time-by-stage tree of a bake report: nested stages inside their parent, the top row summing to the run."""

import re

import pytest

from neural_bake.view.stages import OTHER, stage_bar_svg, stage_tree

#: A cached bake's stage times as bake_asset records them (the Baker's set-up and bake, then the pipeline's).
CACHED = {"unwrap": 0.4, "tangents": 0.1, "rasterize": 5.0, "sdf": 30.0, "texture": 2.0, "maps": 20.0,
          "hybrid": 15.0, "adaptive": 6.0, "check": 0.5, "padding": 0.5, "bake": 60.0, "load": 0.5,
          "coarse": 0.2, "prepare": 6.0, "write": 1.0}


def _names(node):
    return [c.name for c in node.children]


def test_nested_stages_sit_in_their_parent_and_the_run_sums_to_its_wall_time():
    tree = stage_tree(CACHED, 75.0)
    assert _names(tree) == ["load", "coarse", "prepare", "bake", "write", OTHER]
    assert sum(c.seconds for c in tree.children) == pytest.approx(75.0)
    assert tree.children[-1].seconds == pytest.approx(75.0 - 0.5 - 0.2 - 6.0 - 60.0 - 1.0)
    prepare, bake = tree.find("prepare"), tree.find("bake")
    assert _names(prepare) == ["unwrap", "tangents", "rasterize", OTHER]  # cached texels: rasterised in set-up
    assert _names(bake) == ["sdf", "texture", "maps", "adaptive", "check", "padding", OTHER]
    assert _names(tree.find("maps")) == ["hybrid", OTHER]
    for parent in (prepare, bake, tree.find("maps")):  # every parent is split exactly
        assert sum(c.seconds for c in parent.children) == pytest.approx(parent.seconds)
    # no stage is counted twice: the leaves add up to the wall time too
    leaves = []

    def walk(n):
        if not n.children:
            leaves.append(n.seconds)
        for c in n.children:
            walk(c)

    walk(tree)
    assert sum(leaves) == pytest.approx(75.0)


def test_a_streamed_bake_rasterises_inside_the_bake():
    seconds = {**CACHED, "prepare": 0.6, "rasterize": 5.0, "bake": 65.0}
    tree = stage_tree(seconds, 80.0)
    assert "rasterize" in _names(tree.find("bake")) and "rasterize" not in _names(tree.find("prepare"))
    assert sum(c.seconds for c in tree.children) == pytest.approx(80.0)


def test_total_from_the_seconds_and_bad_entries_skipped():
    tree = stage_tree({"load": 1.0, "bake": 2.0, "sdf": 1.5, "total": 4.0, "note": "x", "neg": -1.0})
    assert tree.seconds == 4.0 and _names(tree) == ["load", "bake", OTHER]
    assert _names(tree.find("bake")) == ["sdf", OTHER]
    # stages adding up to more than the run's total widen the run rather than overflowing it
    over = stage_tree({"load": 3.0, "write": 3.0}, 5.0)
    assert over.seconds == 6.0 and _names(over) == ["load", "write"]


def test_the_bar_draws_each_stage_inside_its_parent_on_the_wall_time_scale():
    tree = stage_tree(CACHED, 75.0)
    svg = stage_bar_svg(tree, width=752)  # 750 px for 75 s: 10 px a second
    rects = re.findall(r"<title>([^<]+): ([\d.]+) s</title><rect x='([\d.]+)' y='(\d+)' width='([\d.]+)'", svg)
    rows: dict[int, list] = {}
    for name, secs, x, y, w in rects:
        rows.setdefault(int(y), []).append((name, float(secs), float(x), float(w)))
    top = rows[min(rows)]
    assert sum(w for *_, w in top) == pytest.approx(750.0, abs=0.1)
    spans = {name: (x, x + w) for name, _, x, w in top}
    bake_lo, bake_hi = spans["bake"]
    second = rows[sorted(rows)[1]]
    sdf = next(r for r in second if r[0] == "sdf")
    assert bake_lo - 0.01 <= sdf[2] and sdf[2] + sdf[3] <= bake_hi + 0.01 and sdf[3] == pytest.approx(300.0, abs=0.1)
