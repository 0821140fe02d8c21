"""The interactive glTF viewer of the reports: where the model-viewer script is, and how a report embeds it.

``@google/model-viewer`` (npm; the set-up fetches it into ``.cache/model-viewer`` of the checkout) renders
glTF with normal maps and tangents. A report copies its UMD build beside the HTML (a classic script, which
browsers run from ``file://``; ES modules they refuse there) and embeds the GLBs and the sun HDR as data URIs
in ``models.js``, because browsers refuse ``fetch`` of ``file://`` URLs: the report then works offline from a
double-click, with every file beside it.
"""

from __future__ import annotations

import base64
import json
import math
import os
from pathlib import Path

import numpy as np

from ..render.camera import Camera

__all__ = ["find_model_viewer", "model_viewer_attributes", "models_js", "MODEL_VIEWER_SCRIPT", "MODEL_VIEWER_ENV"]

#: File name of model-viewer's UMD build inside its npm package (``dist/``) and beside a report.
MODEL_VIEWER_SCRIPT = "model-viewer-umd.min.js"
#: Environment variable naming a model-viewer UMD script to use instead of the checkout's cache.
MODEL_VIEWER_ENV = "NEURAL_BAKE_MODEL_VIEWER"


def _cache_candidates() -> list[Path]:
    root = Path(__file__).resolve().parents[2]  # the checkout (editable install)
    return [root / ".cache" / "model-viewer" / "node_modules" / "@google" / "model-viewer" / "dist" / MODEL_VIEWER_SCRIPT]


def find_model_viewer() -> tuple[Path | None, str]:
    """(path of model-viewer's UMD script, "") or (None, the reason it is missing, one line)."""
    env = os.environ.get(MODEL_VIEWER_ENV)
    if env:
        p = Path(env)
        if p.is_file():
            return p, ""
        return None, f"{MODEL_VIEWER_ENV}={env}: no such file"
    for p in _cache_candidates():
        if p.is_file():
            return p, ""
    return None, ("model-viewer is not installed: run scripts/setup.sh where npm is present (it fetches "
                  "@google/model-viewer into .cache/model-viewer), or set " + MODEL_VIEWER_ENV)


def model_viewer_attributes(camera: Camera) -> dict[str, str]:
    """model-viewer attributes that show the view of ``camera`` (source frame = glTF metres, +Y up): the
    orbit (θ about +Y from +Z towards +X, φ down from +Y, radius), the target and the vertical field of
    view, with the orbit limits opened so model-viewer does not clamp them (the largest radius stays a few
    times the view's: model-viewer sets its far plane from it, and a huge one loses the depth range)."""
    eye, target = np.asarray(camera.position), np.asarray(camera.look_at)
    rel = eye - target
    r = float(np.linalg.norm(rel))
    theta = math.degrees(math.atan2(rel[0], rel[2]))
    phi = math.degrees(math.acos(max(-1.0, min(1.0, rel[1] / r))))
    return {
        "camera-orbit": f"{theta:.6f}deg {phi:.6f}deg {r:.6g}m",
        "camera-target": " ".join(f"{c:.6g}m" for c in target),
        "field-of-view": f"{camera.fov_deg:.6g}deg",
        "min-camera-orbit": "auto 0deg 0m",
        "max-camera-orbit": f"auto 180deg {4 * r:.6g}m",
        "min-field-of-view": "1deg",
        "max-field-of-view": "179deg",
    }


def _data_uri(path: Path, mime: str, suffix: str = "") -> str:
    return f"data:{mime};base64,{base64.b64encode(Path(path).read_bytes()).decode('ascii')}{suffix}"


def models_js(models: dict[str, Path], environment: Path | None) -> str:
    """The text of ``models.js``: ``window.NEURAL_BAKE_MODELS = {name: data URI of the GLB}`` and
    ``window.NEURAL_BAKE_ENV`` (the HDR as a data URI ending in ``#sun.hdr``, the extension model-viewer
    picks its HDR loader by; the fragment is not part of the data)."""
    uris = {k: _data_uri(p, "model/gltf-binary") for k, p in models.items()}
    env = _data_uri(environment, "application/octet-stream", "#sun.hdr") if environment is not None else None
    return (f"window.NEURAL_BAKE_MODELS = {json.dumps(uris)};\n"
            f"window.NEURAL_BAKE_ENV = {json.dumps(env)};\n")
