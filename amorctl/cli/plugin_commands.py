"""Commands that plugins add (hook ``amorctl_register_commands``), built for the root group.

A plugin registers a :class:`~amorctl.core.specs.CommandSpec` holding a ``typer.Typer`` app or a
click command or group; here each becomes a command of ``amorctl``, listed in ``amorctl --help``
under "Plugin commands". A command that cannot be built (a name a built-in command has, an
object of another type, an app typer refuses) is left out and reported by ``amorctl plugins``,
as a broken hook is: the rest of the command line works.
"""

from __future__ import annotations

import sys
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any

import typer
import typer.main

from amorctl.cli.output import plugin_stdout
from amorctl.core.specs import CommandSpec
from amorctl.registry import PluginProblem, Provided, Registry

PANEL = "Plugin commands"


@dataclass
class PluginCommands:
    """The commands plugins add, by name, and those that could not be built."""

    commands: dict[str, Any] = field(default_factory=dict)  # name -> command of the root group
    targets: dict[str, Any] = field(default_factory=dict)  # name -> the plugin's own (click) command
    problems: list[PluginProblem] = field(default_factory=list)


def build_plugin_commands(registry: Registry, reserved: Collection[str]) -> PluginCommands:
    """Build every command the registry's plugins registered; ``reserved``: built-in names."""
    built = PluginCommands()
    for row in registry.provided:
        if row.kind != "command":
            continue
        try:
            if row.name in reserved:
                raise ValueError("a built-in amorctl command has this name")
            target = _target(registry.command(row.name).command)
            built.commands[row.name] = _build(registry.command(row.name), target, row)
            built.targets[row.name] = target
        except Exception as exc:  # the plugin's object: report it, keep the others
            error = f"command {row.name!r}: {type(exc).__name__}: {exc}"
            built.problems.append(PluginProblem(row.plugin, row.package, row.version, "broken", error))
    return built


def _build(spec: CommandSpec, target: Any, row: Provided) -> Any:
    """The root group's command for ``spec``: it hands all its arguments (``--help`` too) to the
    plugin's command, which prints on the real stdout (under ``--json`` too: a plugin's command
    owns its output). Typer carries its own copy of click, so a click command runs the same way."""
    help_text = (spec.help or target.help or "").strip()
    first_line = help_text.splitlines()[0] if help_text else ""
    app = typer.Typer(add_completion=False)

    @app.command(
        spec.name,
        help=help_text,
        short_help=f"{first_line} (from {row.package})".lstrip(),
        rich_help_panel=PANEL,
        add_help_option=False,
        context_settings={"ignore_unknown_options": True, "allow_extra_args": True},
    )
    def forward(ctx: typer.Context) -> None:
        with plugin_stdout():
            target.main(args=list(ctx.args), prog_name=f"amorctl {spec.name}")  # exits with its status

    return typer.main.get_command(app)


def _target(command: Any) -> Any:
    """The runnable form (``.main(args, prog_name)``) of a ``typer.Typer`` app or click command."""
    if isinstance(command, typer.Typer):
        return typer.main.get_command(command)  # one command, or a group
    click = sys.modules.get("click")  # a click command exists only if its author imported click
    if click is None or not isinstance(command, click.Command):
        raise TypeError(f"expected a typer.Typer app or a click command, got {type(command).__name__}")
    return command
