"""Fit a mesh at fixed step counts (64x1: 150 steps, 256x3: 20; no polish, one micro-batch, float32 GEMMs, no
compile) and print the fits' figures and a digest of their weights, as JSON.

Run it with two checkouts on ``PYTHONPATH`` to show that a change leaves fitting bit for bit as it was:
``PYTHONPATH=OLD python scripts/fit_fingerprint.py samples/data/bumpy_sphere.obj``, then with NEW.
"""
import hashlib
import json
import sys

import torch

from neural_bake.fit.metrics import sdf_metrics
from neural_bake.fit.sdf import fit_sdf
from neural_bake.io.mesh_io import load_mesh


def main(path: str) -> dict:
    torch.set_num_threads(1)
    mesh = load_mesh(path)
    out = {}
    for preset, steps in (("64x1", 150), ("256x3", 20)):
        fit = fit_sdf(mesh, preset=preset, steps=steps, minutes=None, polish_evals=0, seed=0, progress=False,
                      micro_batches=1, compile="off", gemm_dtype="float32")
        w = torch.cat([p.detach().flatten() for p in fit.model.parameters()]).double().numpy()
        m = sdf_metrics(fit.model, mesh, n=20000, seed=0, resolution=64)
        out[preset] = {"steps": fit.steps, "weights_blake2b": hashlib.blake2b(w.tobytes(), digest_size=8).hexdigest(),
                       **{k: round(float(v), 6) for k, v in m.items() if isinstance(v, (int, float))}}
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1])))
