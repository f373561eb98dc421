"""Options shared by several subcommands, as ``Annotated`` aliases."""

from __future__ import annotations

from typing import Annotated

import typer

JsonFlag = Annotated[bool, typer.Option("--json", help="Print machine-readable JSON instead of a table.")]
CharacterOpt = Annotated[str, typer.Option("--character", "-c", help="Character plugin name.")]
