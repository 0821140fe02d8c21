"""Make the README's picture from a demo output folder: the source mesh, the baked asset, the bare coarse
mesh (same camera and lights), then the normal and albedo maps, side by side in one PNG.

    .venv/bin/python scripts/readme_picture.py demo-out docs/demo.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def _fit(img: np.ndarray, size: int) -> np.ndarray:
    """Nearest-neighbour resize of a uint8 (H, W, 3) image to height ``size`` (aspect kept)."""
    h, w = img.shape[:2]
    rows = (np.arange(size) * h // size).clip(0, h - 1)
    cols = (np.arange(round(w * size / h)) * w // round(w * size / h)).clip(0, w - 1)
    return img[rows][:, cols]


def main(demo_dir: str, out_png: str, size: int = 320) -> None:
    from neural_bake.io.images import read_image, write_image
    from neural_bake.samples.generate import sample_path
    from neural_bake.view import load_view_mesh, render_mesh, to_srgb8, view_camera

    demo = Path(demo_dir)
    source = load_view_mesh(sample_path("bumpy_sphere"))
    asset = load_view_mesh(demo / "asset.glb")
    camera = view_camera(source, width=size, height=size)
    panels = [
        to_srgb8(render_mesh(source, camera).rgb),
        to_srgb8(render_mesh(asset, camera).rgb),
        to_srgb8(render_mesh(asset, camera, use_normal_map=False).rgb),
    ]
    for name in ("normal.png", "albedo.png"):
        img = read_image(demo / name, colour="data")  # the file's values / 255, as stored
        panels.append(_fit(np.round(np.clip(img[..., :3], 0, 1) * 255).astype(np.uint8), size))
    gap = np.full((size, 8, 3), 255, np.uint8)
    row = np.concatenate([p for panel in panels for p in (panel, gap)][:-1], axis=1)
    write_image(out_png, row / 255.0, colour="data")  # already sRGB-encoded 8-bit values


if __name__ == "__main__":
    main(*sys.argv[1:3])
