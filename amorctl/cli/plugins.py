"""``amorctl plugins``: what is installed, by name, kind, package and version (commands that
plugins add too), and every plugin that is blocked, broken or uses a deprecated import path;
``plugins new`` writes a ready plugin package."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, print_json
from amorctl.registry import get_registry

app = typer.Typer(
    help="List installed plugins (characters, objective sets, backends, motion formats, commands); "
    "`new` writes one.",
    invoke_without_command=True,
)


@app.callback()
def plugins(ctx: typer.Context, json_out: JsonFlag = False) -> None:
    """List installed plugins (characters, objective sets, backends, motion formats, commands) and
    any that failed or use a deprecated import path."""
    if ctx.invoked_subcommand is not None:
        return
    from amorctl.cli.main import plugin_commands

    registry = get_registry()
    rows = sorted(registry.provided, key=lambda p: (p.kind, p.name))
    problems = [*registry.problems, *plugin_commands().problems, *registry.deprecated]
    levers = {p.name: sorted(registry.backend(p.name).levers) for p in rows if p.kind == "backend"}
    if json_out:
        print_json(
            {
                "plugins": [asdict(p) for p in rows],
                "backend_levers": levers,
                "problems": [asdict(p) for p in problems],
            }
        )
        return
    table = Table(title="amorctl plugins")
    for col in ("name", "kind", "package", "version"):
        table.add_column(col)
    for p in rows:
        table.add_row(p.name, p.kind, p.package, p.version)
    console.print(table)
    for name, names in levers.items():
        listed = ", ".join(names) or "none (the paper's MOPPO only)"
        console.print(f"backend {name!r} levers: {listed}", highlight=False)
    for prob in problems:
        detail = f": {prob.error}" if prob.error else ""
        console.print(
            f"[yellow]{prob.status}[/yellow] plugin {prob.plugin!r} from package "
            f"{prob.package!r} {prob.version}{detail}",
            highlight=False,
        )


@app.command("new")
def new(
    name: Annotated[str, typer.Argument(help="Plugin name: the entry point and the thing it registers.")],
    kind: Annotated[str, typer.Option("--kind", help="character | objectives | backend")] = "character",
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Directory to create (default: ./amorctl-NAME).")
    ] = None,
    json_out: JsonFlag = False,
) -> None:
    """Write a ready plugin package: pyproject with the entry point, the hook, a test using the kit."""
    from amorctl.testing.scaffold import new_plugin, package_names

    target = out or Path(package_names(name)[0])
    paths = new_plugin(name, kind, target)
    if json_out:
        print_json({"name": name, "kind": kind, "out": str(target), "files": [str(p) for p in paths]})
        return
    for p in paths:
        console.print(f"wrote {p}", highlight=False)
    console.print(
        f"next: pip install -e {target} && amorctl plugins && python -m pytest {target / 'tests'}",
        highlight=False,
    )
