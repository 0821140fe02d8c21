"""Command-line options generated from a stage's config dataclass, for every verb in one place.

A verb made with ``@click.command(cls=ConfigCommand, config=ConfigSpec(...))`` gets one option per config
field (``--field-name``; ``--name/--no-name`` for a bool; ``none`` is a value where the field allows None), its
help the field's docstring line with the default the verb resolves to, plus ``--config FILE`` (a TOML file of
``field = value`` lines), ``--print-config`` (the resolved settings as such a file) and, when the stage has
presets, ``--preset``. Order: the preset (of the command line, else of the file), then the file's fields, then
the options given. The callback receives the resolved config as ``config`` instead of the field options.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import click

__all__ = ["ConfigSpec", "ConfigCommand", "flag_name"]


@dataclass(frozen=True)
class ConfigSpec:
    """How a verb's options come from its config class."""

    load: Callable[[], type]
    """The config dataclass (a function, so the library is imported only when the options are needed)."""
    resolve: Callable[[str | None, dict], object]
    """``(preset or None, {field: value})`` → the config object; raises NeuralBakeError for a bad value."""
    presets: tuple[str, ...] = ()
    """Preset names of ``--preset`` (none: no such option)."""
    described: tuple[str, ...] = ()
    """The presets the help describes (default: all; aliases left out)."""
    costs: dict[str, str] = field(default_factory=dict)
    """What a preset is and costs on a 2-core CPU, for the help (default: its network ``WxD`` and its time
    budget ``minutes``, from the resolved config)."""
    preset_help: str = "Settings preset"
    """First words of ``--preset``'s help."""
    default_preset: str | None = None
    """The preset used when none is given (for the help)."""
    required: tuple[str, ...] = ()
    """Parameters the verb needs unless ``--print-config`` is given (e.g. ``mesh``, ``output``)."""
    pass_preset: bool = False
    """Also pass the preset applied (or None) to the callback as ``preset`` (a fit whose time budget is
    accounted against its preset's)."""
    settings_file: bool = True
    """Add ``--config FILE`` and ``--print-config`` for a TOML file of the config's fields; False: the verb has
    its own (render's scene file) and receives them as its own parameters."""


def flag_name(name: str) -> str:
    """The option of config field ``name``: ``max_boxes`` → ``--max-boxes``."""
    return "--" + name.replace("_", "-")


_PREFIX = "config__"  # parameter names of the generated options (no clash with a verb's own)


class _FieldType(click.ParamType):
    """A config field's type: text converted by :func:`neural_bake.configs.convert` (one line on failure)."""

    def __init__(self, hint):
        from neural_bake.configs import type_name

        self.hint = hint
        self.name = type_name(hint)

    def get_metavar(self, param, ctx=None):
        return self.name.upper().replace(" OR ", "|")

    def convert(self, value, param, ctx):
        from neural_bake.configs import convert
        from neural_bake.errors import NeuralBakeError

        if not isinstance(value, str):
            return value
        try:
            return convert(value, self.hint, param.opts[-1] if param else "value", text=True)
        except NeuralBakeError as exc:
            self.fail(str(exc), param, ctx)


def _options_named(text: str, fields) -> str:
    """A field's help with its ``name`` references to other fields as their options (``--name``)."""
    import re

    return re.sub(r"``([^`]+)``", lambda m: flag_name(m[1]) if m[1] in fields else m[1], text)


def _cost(config) -> str:
    """``"WxD, M min"`` of a fit's config (the parts it has)."""
    parts = []
    if hasattr(config, "width") and hasattr(config, "depth"):
        w, d = config.width, config.depth
        if getattr(config, "construction", "plain") == "tiles":  # a coarse level and tiles fitted on it
            parts.append(f"{config.coarse_width}x{d} + {config.tile_width}x{config.tile_depth} tiles on a "
                         f"{config.tile_grid}³ grid")
        elif getattr(config, "construction", "plain") != "plain" and getattr(config, "coarse_width", 0):
            c = config.coarse_width  # a coarse level and a fine one fitted on it, saved as their sum
            parts.append(f"{c}x{d} + {w - c}x{d} as one {w}x{d}")
        else:
            parts.append(f"{w}x{d}")
    if getattr(config, "minutes", None):
        parts.append(f"{config.minutes:g} min")
    return ", ".join(parts) or "see BENCHMARKS.md"


def _show(value) -> str:
    if isinstance(value, tuple):
        return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    if value is None:
        return "none"
    return str(value).lower() if isinstance(value, bool) else str(value)


class ConfigCommand(click.Command):
    """A click command whose config options are generated from a :class:`ConfigSpec` on first use."""

    def __init__(self, *args, config: ConfigSpec, **kwargs):
        super().__init__(*args, **kwargs)
        self.spec = config
        self._fields: list[str] | None = None

    # -- options

    def config_fields(self) -> list[str]:
        """The config fields that have an option."""
        self._add_params()
        assert self._fields is not None
        return self._fields

    def _add_params(self) -> None:
        if self._fields is not None:
            return
        from neural_bake.configs import field_help, field_types

        spec = self.spec
        cls = spec.load()
        hints = field_types(cls)
        base = spec.resolve(spec.default_preset, {})
        by_preset = {p: spec.resolve(p, {}) for p in spec.presets}
        params: list[click.Parameter] = []
        if spec.presets:
            costs = []
            for p in spec.described or spec.presets:
                costs.append(f"{p} ({spec.costs.get(p) or _cost(by_preset[p])})")
            params.append(click.Option(["--preset", "preset"], type=click.Choice(spec.presets), default=None,
                                       help=f"{spec.preset_help}: {', '.join(costs)} on a 2-core CPU"
                                            + (f" [default: {spec.default_preset}]" if spec.default_preset else "")))
        if spec.settings_file:
            params.append(click.Option(["--config", "config_path"], type=click.Path(dir_okay=False), default=None,
                                       metavar="FILE", help="TOML settings file (field = value; --print-config "
                                                            "writes one); the options given override it."))
            params.append(click.Option(["--print-config"], is_flag=True,
                                       help="Print the resolved settings as a TOML settings file and exit."))
        self._fields = list(hints)
        own = {p.name for p in self.params}  # a field the verb spells itself (an older spelling) keeps it
        for name, hint in hints.items():
            if _PREFIX + name in own:
                continue
            default = getattr(base, name)
            varies = any(getattr(c, name) != default for c in by_preset.values())
            shown = f"[default: {_show(default)}" + (", or the preset's]" if varies else "]")
            help_text = f"{_options_named(field_help(cls, name), hints)} {shown}"
            flag = flag_name(name)
            if hint is bool:
                params.append(click.Option([f"{flag}/--no-{flag[2:]}", _PREFIX + name], default=None, help=help_text))
            else:
                params.append(click.Option([flag, _PREFIX + name], type=_FieldType(hint), default=None, help=help_text))
        self.params = [*self.params, *params]

    def get_params(self, ctx):
        self._add_params()
        return super().get_params(ctx)

    @staticmethod
    def given(ctx, name: str) -> bool:
        """Whether config field ``name``'s option was given on the command line (or by the environment)."""
        source = ctx.get_parameter_source(_PREFIX + name)
        return source in (click.core.ParameterSource.COMMANDLINE, click.core.ParameterSource.ENVIRONMENT)

    # -- running

    def resolve(self, ctx) -> tuple[object, str | None, dict]:
        """(config, preset applied, the verb's own params) from the parsed ``ctx.params``: the preset, the file,
        then the options given on the command line (an option left out keeps the file's or the preset's value)."""
        from neural_bake.configs import convert, field_types, read_config
        from neural_bake.io.tomlio import read_toml

        spec = self.spec
        params = dict(ctx.params)
        config_path = params.pop("config_path", None) if spec.settings_file else None
        if spec.settings_file:
            params.pop("print_config", None)
        preset = params.pop("preset", None)
        typed = (click.core.ParameterSource.COMMANDLINE, click.core.ParameterSource.ENVIRONMENT)
        given = {k[len(_PREFIX):]: params.pop(k) for k in list(params) if k.startswith(_PREFIX)
                 if ctx.get_parameter_source(k) in typed}
        for k in [k for k in params if k.startswith(_PREFIX)]:
            params.pop(k)
        values = {}
        if config_path:
            values = read_config(spec.load(), read_toml(config_path), where=config_path,
                                 extra=("preset",) if spec.presets else ())
            file_preset = values.pop("preset", None)
            if file_preset is not None and file_preset not in spec.presets:
                from neural_bake.errors import NeuralBakeError

                raise NeuralBakeError(f"{config_path}: preset={file_preset!r}: expected one of "
                                      f"{', '.join(spec.presets)}")
            preset = preset or file_preset
        hints = field_types(spec.load())  # a verb's own spelling of a field gives its text (e.g. on/off)
        values.update({k: convert(v, hints[k], flag_name(k), text=True) if isinstance(v, str) else v
                       for k, v in given.items()})
        preset = preset or spec.default_preset
        return spec.resolve(preset, values), preset, params

    def invoke(self, ctx):
        from neural_bake.configs import config_table
        from neural_bake.io.tomlio import toml_text

        print_config = self.spec.settings_file and ctx.params.get("print_config")
        config, preset, params = self.resolve(ctx)
        if print_config:
            click.echo(toml_text(*config_table(config)), nl=False)
            return None
        missing = [p for p in self.spec.required if params.get(p) is None]
        if missing:
            names = {p.name: (p.opts[-1] if isinstance(p, click.Option) else p.human_readable_name)
                     for p in self.get_params(ctx)}
            raise click.UsageError(f"missing {', '.join(names.get(m, m) for m in missing)} "
                                   f"(needed unless --print-config)", ctx)
        if self.callback is not None:
            if self.spec.pass_preset:
                params["preset"] = preset
            return ctx.invoke(self.callback, config=config, **params)
        return None

