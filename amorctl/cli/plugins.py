"""``amorctl plugins``: what is installed, by name, kind, package and version."""

from __future__ import annotations

from dataclasses import asdict

from rich.table import Table

from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, print_json
from amorctl.registry import get_registry


def plugins(json_out: JsonFlag = False) -> None:
    """List installed plugins (characters, objective sets, backends, motion formats) and any that failed."""
    registry = get_registry()
    rows = sorted(registry.provided, key=lambda p: (p.kind, p.name))
    if json_out:
        print_json({"plugins": [asdict(p) for p in rows], "problems": [asdict(p) for p in registry.problems]})
        return
    table = Table(title="amorctl plugins")
    for col in ("name", "kind", "package", "version"):
        table.add_column(col)
    for p in rows:
        table.add_row(p.name, p.kind, p.package, p.version)
    console.print(table)
    for prob in registry.problems:
        detail = f": {prob.error}" if prob.error else ""
        console.print(
            f"[yellow]{prob.status}[/yellow] plugin {prob.plugin!r} from package "
            f"{prob.package!r} {prob.version}{detail}",
            highlight=False,
        )
