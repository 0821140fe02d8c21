"""`neural-bake import WEIGHTS -o MODEL --omega0 W`: SIREN weights from the reference code as a model file (thin verb)."""

from __future__ import annotations

import math

import click

from .options import lock_outputs, output_option, refuse_nonpositive, say, verbosity_options

__all__ = ["command"]


@click.command(epilog="""\b
Examples:
  neural-bake import sdf_final.pth -o bunny.sdf --omega0 30
  neural-bake import model.pth -o bunny.sdf --omega0 30 --frame-from bunny.obj
  neural-bake import weights.bin -o shape.sdf --raw --width 64 --depth 1 --omega0 30 --frame-scale 0.5

\b
State dicts: SingleBVPNet (net.net.<i>.0.*), FCBlock or i3d SIREN (net.<i>.0.*),
the notebooks' Siren (net.<i>.linear.*, last net.<N>.*); a leading module. is stripped.
Raw files: little-endian float32, layer by layer from the input: weight (out, in) row-major, then bias.""")
@click.argument("weights", metavar="WEIGHTS", type=click.Path(dir_okay=False))
@output_option("Model file to write (an SDF: safetensors with JSON metadata, ω and frame included).")
@click.option("--omega0", type=float, required=True,
              help="ω0 of the first layer as trained (the reference code's first_omega_0, 30 by default there).")
@click.option("--hidden-omega0", type=float, default=None,
              help="ω of the hidden layers as trained (hidden_omega_0; i3d's ww) [default: --omega0].")
@click.option("--kind", type=click.Choice(["sdf"]), default="sdf", show_default=True,
              help="What the network is: a signed distance of (x, y, z).")
@click.option("--frame-center", metavar="X,Y,Z", default=None,
              help="Source-frame point at the origin of the network's input space [default 0,0,0].")
@click.option("--frame-scale", type=float, default=None,
              help="Input-space length of one source unit: input = (source - centre) · scale [default 1].")
@click.option("--frame-from", metavar="MESH", type=click.Path(dir_okay=False), default=None,
              help="Take the frame from a mesh, normalised as `fit sdf` does (centred, longest side 1.8).")
@click.option("--raw", is_flag=True, help="WEIGHTS is a headerless float32 file of the --width/--depth SIREN.")
@click.option("--width", type=int, default=None, help="W of a --raw file's (W, D) SIREN.")
@click.option("--depth", type=int, default=None, help="D of a --raw file's (W, D) SIREN (D hidden W×W matrices).")
@verbosity_options
def command(weights, output, omega0, hidden_omega0, kind, frame_center, frame_scale, frame_from, raw, width,
            depth):
    """Convert the SIREN weights WEIGHTS (a PyTorch state dict, or a raw float32 file) into a model file."""
    from neural_bake.fields.imported import import_siren

    refuse_nonpositive(omega0=omega0, hidden_omega0=hidden_omega0, frame_scale=frame_scale)
    if raw and (width is None or depth is None):
        raise click.UsageError("--raw needs --width and --depth (the file's (W, D) SIREN)")
    if not raw and (width is not None or depth is not None):
        raise click.UsageError("--width and --depth describe a --raw file; give --raw too")
    frame = _frame(frame_center, frame_scale, frame_from)
    lock_outputs(output)  # checks its folder; one writer per file
    field = import_siren(weights, output, omega_0=omega0, hidden_omega=hidden_omega0, frame=frame, kind=kind,
                         raw=(width, depth) if raw else None)
    m, src = field.model, field.metadata["imported_from"]
    say(f"{src['file']}: {src['format']} ({src['layout']}), SIREN {m.width}x{m.depth} of (x, y, z) -> f, "
        f"ω0 {m.omega_0:g}, hidden ω {m.hidden_omega:g}, {str(next(m.parameters()).dtype).split('.')[-1]}")
    say(f"frame: centre {', '.join(f'{c:g}' for c in field.frame.center)}, scale {field.frame.scale:g}")
    say(f"wrote {output}")


def _frame(center: str | None, scale: float | None, mesh: str | None):
    from neural_bake.errors import NeuralBakeError
    from neural_bake.types import Frame

    if mesh is not None:
        if center is not None or scale is not None:
            raise click.UsageError("give --frame-from or --frame-center/--frame-scale, not both")
        from neural_bake.io.mesh_io import load_mesh

        return load_mesh(mesh).frame
    if center is None and scale is None:
        return None
    xyz = (0.0, 0.0, 0.0)
    if center is not None:
        try:
            xyz = tuple(float(c) for c in center.split(","))
        except ValueError:
            xyz = ()
        if len(xyz) != 3 or not all(math.isfinite(c) for c in xyz):
            raise NeuralBakeError(f"--frame-center {center!r}: must be X,Y,Z, three finite numbers")
    return Frame(xyz, 1.0 if scale is None else float(scale))  # type: ignore[arg-type]
