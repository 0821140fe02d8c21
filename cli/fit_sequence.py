"""`neural-bake fit sequence FRAMES… --times … -o MODEL`: a space-time SDF through mesh frames (thin verb)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from .fit_morph import check_output, network_options, pools, report_fit
from .options import verbosity, verbosity_options

__all__ = ["command"]


@click.command(epilog="""\b
Example:
  neural-bake samples -o samples/ --names twisting_torus
  neural-bake fit sequence samples/twisting_torus -o twist.sdf --minutes 3""")
@click.argument("frames", nargs=-1, required=True, type=click.Path())
@click.option("--times", default=None,
              help="Frame times: START:STOP:COUNT or a comma-separated list (default: the folder's frames.json, "
                   "else evenly spaced over [0, 1]).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Model file to write (safetensors + JSON metadata, kind 'spacetime_sdf').")
@click.option("--method", type=click.Choice(["interpolate", "eikonal"]), default="interpolate", show_default=True,
              help="Between frames: interpolate the two neighbouring frames' distances, or the eikonal term alone.")
@network_options
@verbosity_options
def command(frames, times, output, method, width, depth, steps, minutes, seed, lr, time_extent, pool, metrics,
            progress):
    """Fit a space-time SDF through the mesh FRAMES (files, or one folder with frames.json as `neural-bake
    samples` writes it)."""
    from neural_bake.errors import NeuralBakeError
    from neural_bake.fit.spacetime import fit_sequence, parse_times
    from neural_bake.io.mesh_io import load_mesh
    from neural_bake.samples.generate import FRAMES_FILE

    check_output(output)
    files, listed = [Path(f) for f in frames], None
    if len(files) == 1 and files[0].is_dir():
        index = files[0] / FRAMES_FILE
        if not index.is_file():
            raise NeuralBakeError(f"{files[0]}: a folder without {FRAMES_FILE}; give the frame files instead")
        try:
            data = json.loads(index.read_text())
            files, listed = [files[0] / f for f in data["frames"]], [float(t) for t in data["times"]]
        except (ValueError, KeyError, TypeError):
            raise NeuralBakeError(f"{index}: not a frames index (needs 'frames' and 'times' lists)") from None
    ts = parse_times(times, name="--times") if times else listed
    if ts is None:
        ts = [0.0] if len(files) == 1 else [k / (len(files) - 1) for k in range(len(files))]
    if len(ts) != len(files):
        raise NeuralBakeError(f"--times: {len(ts)} times for {len(files)} frames")
    meshes = [load_mesh(f) for f in files]
    fit = fit_sequence(meshes, ts, method=method, width=width, depth=depth, steps=steps, minutes=minutes, seed=seed, lr=lr,
                       time_extent=time_extent, progress=progress and verbosity() >= 0, **pools(pool))
    report_fit(fit, list(zip(ts, meshes)), metrics, output)
