"""`neural-bake bench …`: one sub-verb per capability; each takes --quick and --json PATH."""

from __future__ import annotations

import click

from .main import LazyGroup

BENCHES = {
    "sampling": ("neural_bake.cli.bench_sampling", "command"),
    "normals": ("neural_bake.cli.bench_normals", "command"),
    "range": ("neural_bake.cli.bench_range", "command"),
    "fit": ("neural_bake.cli.bench_fit", "command"),
    "nested": ("neural_bake.cli.bench_nested", "command"),
    "texture": ("neural_bake.cli.bench_texture", "command"),
    "bake": ("neural_bake.cli.bench_bake", "command"),
    "coarse": ("neural_bake.cli.bench_coarse", "command"),
    "render": ("neural_bake.cli.bench_render", "command"),
    "dynamic": ("neural_bake.cli.bench_dynamic", "command"),
    "fidelity": ("neural_bake.cli.bench_fidelity", "command"),
    "view": ("neural_bake.cli.bench_view", "command"),
    "batch": ("neural_bake.cli.bench_batch", "command"),
    "budget": ("neural_bake.cli.bench_budget", "command"),
    "contention": ("neural_bake.cli.bench_contention", "command"),
}


class BenchGroup(LazyGroup):
    """The bench verbs: one without an example of its own shows the one every bench verb takes."""

    def get_command(self, ctx, name):
        cmd = super().get_command(ctx, name)
        if cmd is not None and not cmd.epilog:
            cmd.epilog = f"\b\nExample:\n  neural-bake bench {name} --quick --json {name}.json"
        return cmd


@click.group(cls=BenchGroup, lazy=BENCHES)
def group():
    """Benchmarks: accuracy against time, beside the baseline a user would otherwise pick."""


def bench_options(fn):
    """The options every bench verb takes: --quick and --json PATH (checked and locked before the run)."""
    import functools

    inner = fn

    @functools.wraps(inner)
    def fn(*args, **kwargs):
        from .options import lock_outputs

        lock_outputs(kwargs.get("json_path"))
        return inner(*args, **kwargs)

    fn = click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
                      help="Also write the figures as JSON to this file.")(fn)
    fn = click.option("--quick", is_flag=True, help="A shrunken run (under two minutes) for smoke checks.")(fn)
    return fn


def report(result: dict, json_path: str | None, columns=None) -> None:
    """Print a benchmark result's table (and notes) and write its JSON when asked."""
    from neural_bake.bench.common import format_table, write_json

    title = result.get("title", result.get("name", "benchmark"))
    click.echo(f"== {title} ==")
    for table_name, rows in result.get("tables", {"": result.get("rows", [])}).items():
        if table_name:
            click.echo(f"-- {table_name}")
        click.echo(format_table(rows, columns))
    for note in result.get("notes", []):
        click.echo(f"note: {note}")
    if json_path:
        write_json(json_path, result)
        click.echo(f"wrote {json_path}")


@group.command("all")
@bench_options
def run_all(quick: bool, json_path: str | None):
    """Run every benchmark in turn (use --quick for a smoke check of all of them)."""
    import importlib

    results = {}
    for name in BENCHES:
        bench_module = importlib.import_module(f"neural_bake.bench.{name}")
        result = bench_module.run(quick=quick)
        report(result, None)
        results[name] = result
    if json_path:
        from neural_bake.bench.common import write_json

        write_json(json_path, results)
        click.echo(f"wrote {json_path}")
