"""`bench view` in a shrunken run: rows, figures in range, the maps' gain over the bare coarse mesh."""

from neural_bake.bench.view import COLUMNS, run


def test_bench_view_smallest_run():
    res = run(quick=True, views=1, size=64)
    rows = {r["method"]: r for r in res["rows"]}
    baked, bare = rows["ours: coarse mesh + baked maps"], rows["coarse mesh without maps"]
    assert set(COLUMNS) <= set(baked)
    assert baked["interior_psnr_db"] > bare["interior_psnr_db"] + 15
    assert baked["detail_corr"] > bare["detail_corr"] and baked["silhouette_iou"] > 0.95
    assert all(r["seconds_per_view"] > 0 for r in res["rows"])
    browser = [r for r in res["rows"] if r["method"].startswith("model-viewer")]
    assert browser or any("model-viewer row skipped" in n for n in res["notes"])
