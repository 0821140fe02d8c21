"""`neural-bake fit sequence FRAMES… --times … -o MODEL`: a space-time SDF through mesh frames (thin verb)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from .config_options import ConfigCommand
from .fit_morph import check_output, report_fit, spacetime_config, spacetime_options, spacetime_spec
from .options import verbosity_options

__all__ = ["command"]


@click.command(cls=ConfigCommand, config=spacetime_spec("fit_sequence", ("frames", "output")), epilog="""\b
Example:
  neural-bake samples -o samples/ --names twisting_torus
  neural-bake fit sequence samples/twisting_torus -o twist.sdf --minutes 3""")
@click.argument("frames", nargs=-1, type=click.Path())
@click.option("--times", default=None,
              help="Frame times: START:STOP:COUNT or a comma-separated list (default: the folder's frames.json, "
                   "else evenly spaced over [0, 1]).")
@click.option("-o", "--output", type=click.Path(dir_okay=False),
              help="Model file to write (safetensors + JSON metadata, kind 'spacetime_sdf').")
@spacetime_options
@verbosity_options
def command(frames, times, output, pool, metrics, config):
    """Fit a space-time SDF through the mesh FRAMES (files, or one folder with frames.json as `neural-bake
    samples` writes it).

    --method interpolate: between frames, the two neighbouring frames' distances interpolated; eikonal: the
    eikonal term alone."""
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
    fit = fit_sequence(meshes, ts, spacetime_config(config, pool))
    report_fit(fit, list(zip(ts, meshes)), metrics, output)
