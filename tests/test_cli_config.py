"""Options generated from the config dataclasses: every field has an option with one help line, a TOML file
applies first and options override it, --print-config writes a file that loads back to the same settings, bad
files fail in one line naming the file and the key (exit 2); every verb's help shows an example."""

import dataclasses

import click
import pytest
import torch

from neural_bake.cli.config_options import ConfigCommand
from neural_bake.cli.main import cli, main
from neural_bake.configs import field_types

CONFIG_VERBS = [("fit", "sdf"), ("fit", "nested"), ("fit", "texture"), ("fit", "morph"), ("fit", "sequence"), ("bake",),
                ("demo",)]


def command_of(path):
    ctx = click.Context(cli)
    cmd = cli
    for name in path:
        cmd = cmd.get_command(ctx, name)
    return cmd


def all_verbs():
    """(path, command) of every registered verb, groups walked."""
    out = []

    def walk(group, path):
        ctx = click.Context(group)
        for name in group.list_commands(ctx):
            cmd = group.get_command(ctx, name)
            if isinstance(cmd, click.Group):
                walk(cmd, (*path, name))
            else:
                out.append(((*path, name), cmd))

    walk(cli, ())
    return out


@pytest.mark.parametrize("path", [*CONFIG_VERBS, ("render",)], ids=" ".join)
def test_every_config_field_has_an_option_with_one_help_line(path):
    cmd = command_of(path)
    assert isinstance(cmd, ConfigCommand)
    ctx = click.Context(cmd)
    params = cmd.get_params(ctx)
    options = {o: p for p in params for o in p.opts}
    by_name = {p.name: p for p in params}
    cls = cmd.spec.load()
    names = [f.name for f in dataclasses.fields(cls)]
    assert names == cmd.config_fields() and len(names) >= 6
    for name in names:
        param = by_name["config__" + name]  # --field-name, or the verb's older spelling of it (bake --tolerance)
        assert param.help and "\n" not in param.help and "[default: " in param.help, name
        assert param.help.split(" [default: ")[0].strip(), name  # the field's own line, not only the default
    for opt in ("--config", "--print-config", "-q", "--quiet", "-v", "--verbose"):
        assert opt in options


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("path", CONFIG_VERBS, ids=" ".join)
def test_print_config_round_trips_through_a_config_file(path, tmp_path, capsys):
    code, text, err = run(capsys, *path, "--print-config")
    assert code == 0, err
    f = tmp_path / "c.toml"
    f.write_text(text)
    code, again, err = run(capsys, *path, "--config", str(f), "--print-config")
    assert code == 0, err
    assert again == text
    cmd = command_of(path)
    import tomllib

    from neural_bake.configs import read_config

    loaded = read_config(cmd.spec.load(), tomllib.loads(text), where=str(f))
    assert cmd.spec.resolve(None, loaded) == cmd.spec.resolve(cmd.spec.default_preset, {})
    assert set(loaded) == set(cmd.config_fields())


def test_fit_sdf_defaults_to_the_default_preset(capsys):
    import tomllib

    code, text, err = run(capsys, "fit", "sdf", "--print-config")
    got = tomllib.loads(text)
    assert code == 0 and (got["width"], got["depth"], got["minutes"]) == (192, 3, 5.0), err
    assert got["surface_normals"] == "vertex"


def test_a_config_file_applies_first_and_options_override_it(tmp_path, capsys):
    import tomllib

    f = tmp_path / "nested.toml"
    f.write_text('preset = "quick"\nsteps = 5\nseed = 3\nminutes = "none"\ncertify = true\n')
    code, text, err = run(capsys, "fit", "nested", "--config", str(f), "--steps", "7", "--print-config")
    assert code == 0, err
    got = tomllib.loads(text)
    # the file's preset (quick: 32x1), then the file's fields, then the option given
    assert (got["levels"], got["steps"], got["seed"], got["certify"], got["minutes"]) == ("32x1", 7, 3, True, "none")
    code, text, err = run(capsys, "fit", "nested", "--config", str(f), "--preset", "high", "--no-certify",
                          "--print-config")
    got = tomllib.loads(text)
    assert (got["levels"], got["steps"], got["certify"]) == ("64x1,256x1", 5, False)  # --preset beats the file's


def _tiny_fit_inputs(tmp_path, *, steps: int, subdivisions: int):
    """An icosphere mesh file and a config file of a 16x1 fit of ``steps`` steps on small pools."""
    import trimesh

    src = tmp_path / "ball.obj"
    trimesh.creation.icosphere(subdivisions=subdivisions).export(src)
    f = tmp_path / "sdf.toml"
    f.write_text(f"width = 16\ndepth = 1\nsteps = {steps}\nminutes = \"none\"\nseed = 5\npool_surface = 2000\n"
                 "pool_near = 2000\npool_uniform = 500\nbatch = 256\nbatch_near = 256\nbatch_uniform = 64\n"
                 "polish_evals = 0\ncompile = \"off\"\n")
    return src, f


def test_a_config_file_drives_a_real_fit(tmp_path, capsys):
    from neural_bake.fit.sdf import load_sdf

    src, f = _tiny_fit_inputs(tmp_path, steps=4, subdivisions=1)
    out = tmp_path / "ball.sdf"
    code, printed, err = run(capsys, "fit", "sdf", str(src), "-o", str(out), "--config", str(f), "--seed", "6",
                             "--no-metrics", "--quiet")
    assert code == 0, err
    assert printed == ""  # --quiet: no lines, no progress bar
    fit = load_sdf(out)
    assert (fit.config.width, fit.config.depth, fit.steps, fit.config.seed, fit.config.pool_surface) == (16, 1, 4, 6, 2000)


def test_fit_sdf_says_when_faces_lie_inside_another_shell(tmp_path, capsys):
    import trimesh

    src, f = _tiny_fit_inputs(tmp_path, steps=2, subdivisions=1)
    a = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    b = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    b.apply_translation((0.5, 0.1, 0.05))  # half inside a
    both = tmp_path / "boxes.obj"
    trimesh.util.concatenate([a, b]).export(both)
    for mesh, says in ((src, False), (both, True)):
        code, printed, err = run(capsys, "fit", "sdf", str(mesh), "-o", str(tmp_path / f"{mesh.stem}.sdf"),
                                 "--config", str(f), "--no-metrics")
        assert code == 0, err
        assert ("faces lie inside another of its shells" in printed) is says, printed


def test_fit_sdf_tiles_construction_writes_a_tiled_sdf(tmp_path, capsys):
    """`fit sdf --construction tiles`: the coarse level and its tiles in one file that loads as a field."""
    from neural_bake.fields import load_field
    from neural_bake.nets.tiles import TiledSdf

    src, f = _tiny_fit_inputs(tmp_path, steps=8, subdivisions=2)
    out = tmp_path / "ball.sdf"
    code, printed, err = run(capsys, "fit", "sdf", str(src), "-o", str(out), "--config", str(f),
                             "--construction", "tiles", "--coarse-width", "6", "--tile-grid", "3", "--tile-width",
                             "8", "--tile-depth", "1", "--no-metrics")
    assert code == 0, err
    field = load_field(out)
    assert isinstance(field.model, TiledSdf) and f"fit sdf 6x1+{field.model.tiles.tiles}x(8x1):" in printed
    values, normals, valid = field.value_and_normal(torch.rand(64, 3) * 2 - 1)
    assert valid.all() and torch.isfinite(values).all()
    code, _, err = run(capsys, "fit", "sdf", str(src), "-o", str(out), "--config", str(f), "--construction", "tiles",
                       "--coarse-width", "6", "--tile-margin", "0.5")
    assert code == 2 and "tile_margin must be in (0, 0.25] cells" in err and err.count("\n") == 1


def test_fit_sdf_residual_construction_writes_one_sdf_of_both_levels(tmp_path, capsys):
    """`fit sdf --construction residual`: a coarse level, then a fine one of the rest of the width on top of it,
    written as one SIREN of the config's width that loads as a field; an unknown construction is refused in
    one line."""
    from neural_bake.fields import load_field
    from neural_bake.fit.sdf import load_sdf

    src, f = _tiny_fit_inputs(tmp_path, steps=8, subdivisions=2)
    out = tmp_path / "ball.sdf"
    code, printed, err = run(capsys, "fit", "sdf", str(src), "-o", str(out), "--config", str(f),
                             "--construction", "residual", "--coarse-width", "6", "--audit-candidates", "3000",
                             "--no-metrics")
    assert code == 0, err
    assert "fit sdf 6x1+10x1:" in printed and "whose band is |h| <" in printed and "coarse level made 2" in printed
    assert "its band audit kept " in printed and " of 3000 candidates in " in printed
    field = load_field(out)
    assert field.model.layers[0].weight.shape[0] == 16
    assert (load_sdf(out).config.construction, load_sdf(out).config.coarse_width) == ("residual", 6)
    x = torch.rand(64, 3, dtype=torch.float32) * 2 - 1
    values, normals, valid = field.value_and_normal(x)
    assert valid.all() and torch.isfinite(values).all()
    assert torch.allclose(normals.norm(dim=1), torch.ones(64), atol=1e-4)
    code, _, err = run(capsys, "fit", "sdf", str(src), "-o", str(out), "--config", str(f), "--construction", "octree")
    assert code == 2 and "construction must be one of plain, residual, residual-warm, tiles, got 'octree'" in err
    assert err.count("\n") == 1
    code, _, err = run(capsys, "fit", "sdf", str(src), "-o", str(out), "--config", str(f), "--construction",
                       "residual", "--coarse-width", "16")
    assert code == 2 and "coarse_width must be an integer in (0, width 16)" in err
    # a construction is checkpointed level by level (the coarse level beside the file) and resumed
    code, _, err = run(capsys, "fit", "sdf", str(src), "-o", str(out), "--config", str(f), "--construction",
                       "residual", "--coarse-width", "6", "--resume", "--no-metrics")
    assert code == 0, err
    assert (tmp_path / "ball.sdf.ckpt").is_file() and (tmp_path / "ball.sdf.coarse.ckpt").is_file()
    code, printed, err = run(capsys, "fit", "sdf", str(src), "-o", str(out), "--config", str(f), "--construction",
                             "residual", "--coarse-width", "6", "--resume", "--no-metrics")
    assert code == 0 and "resumed finished run" in printed + err


@pytest.mark.parametrize("path", CONFIG_VERBS, ids=" ".join)
def test_a_bad_config_file_is_one_line_naming_the_file_and_the_key(path, tmp_path, capsys):
    f = tmp_path / "bad.toml"
    f.write_text("stepz = 3\n")
    code, _, err = run(capsys, *path, "--config", str(f), "--print-config")
    assert code == 2
    assert err.startswith(f"neural-bake: error: {f}: unknown key 'stepz'") and err.count("\n") == 1
    cls = command_of(path).spec.load()
    hints = field_types(cls)
    name = next(n for n, h in hints.items() if h is int)
    f.write_text(f'{name} = "many"\n')
    code, _, err = run(capsys, *path, "--config", str(f), "--print-config")
    assert code == 2
    assert err == f"neural-bake: error: {f}: {name}='many': expected int\n"
    f.write_text("[oops\n")
    code, _, err = run(capsys, *path, "--config", str(f), "--print-config")
    assert code == 2 and err.startswith(f"neural-bake: error: {f}: not valid TOML") and err.count("\n") == 1
    code, _, err = run(capsys, *path, "--config", str(tmp_path / "none.toml"), "--print-config")
    assert code == 2 and "none.toml: no such config file" in err


def test_a_bad_option_value_is_a_usage_error(capsys):
    code, _, err = run(capsys, "fit", "nested", "--steps", "lots", "--print-config")
    assert code == 2 and "--steps='lots': expected int" in err
    code, _, err = run(capsys, "bake", "--normal-space", "sideways", "--print-config")
    assert code == 2 and "--normal-space 'sideways': must be one of tangent, object" in err
    code, _, err = run(capsys, "fit", "sdf", "--print-config", "--preset", "huge")
    assert code == 2 and "huge" in err


def test_a_config_verb_without_its_arguments_says_which_are_missing(capsys):
    code, _, err = run(capsys, "fit", "texture", "--preset", "quick")
    assert code == 2 and "missing MESH, --sdf, --output" in err


def test_every_verb_shows_an_example_and_the_common_flags(capsys):
    verbs = all_verbs()
    assert len(verbs) > 25
    for path, cmd in verbs:
        code, text, err = run(capsys, *path, "--help")
        assert code == 0, (path, err)
        assert "Example" in text and f"neural-bake {' '.join(path)}" in text.split("Example", 1)[1], path
    for path in [("fit", "sdf"), ("fit", "nested"), ("fit", "texture"), ("bake",), ("demo",), ("render",),
                 ("batch",), ("samples",), ("view",)]:
        text = run(capsys, *path, "--help")[1]
        for flag in ("-o, --output", "--quiet", "--verbose"):
            assert flag in text, (path, flag)
    for path in [("fit", "sdf"), ("fit", "nested"), ("fit", "texture"), ("demo",), ("batch",), ("render",)]:
        text = run(capsys, *path, "--help")[1]
        assert "--device" in text, path
    for path in [("fit", "sdf"), ("fit", "nested"), ("fit", "texture"), ("demo",), ("batch",)]:
        assert "--seed" in run(capsys, *path, "--help")[1], path
    for path in [("fit", "sdf"), ("fit", "nested"), ("fit", "texture"), ("bake",), ("batch",)]:
        text = " ".join(run(capsys, *path, "--help")[1].split())
        for preset in ("quick (", "default (", "high ("):
            assert preset in text, (path, preset)  # each preset with its cost
    # a construction preset names its two levels and the one network they are saved as; a plain one its own
    text = " ".join(run(capsys, "fit", "sdf", "--help")[1].split())
    assert "high (64x4 + 192x4 as one 256x4, 10 min)" in text and "256x3 (256x3, 10 min)" in text
