"""``amorctl characters``: list the installed characters, show one in full."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.table import Table

from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, print_json
from amorctl.registry import get_registry
from amorctl.sim.character_info import describe_character

app = typer.Typer(help="Inspect the installed characters.", no_args_is_help=True)


@app.command("list")
def list_characters(json_out: JsonFlag = False) -> None:
    """List installed characters with their DoF counts and rates."""
    registry = get_registry()
    specs = [registry.character(n) for n in registry.names("character")]
    if json_out:
        print_json(
            {
                "characters": [
                    {
                        "name": s.name,
                        "description": s.description,
                        "num_joints": s.num_joints,
                        "physics_hz": s.physics_hz,
                        "control_hz": s.control_hz,
                    }
                    for s in specs
                ]
            }
        )
        return
    table = Table(title="characters")
    for col in ("name", "joints", "physics Hz", "control Hz", "description"):
        table.add_column(col)
    for s in specs:
        table.add_row(s.name, str(s.num_joints), str(s.physics_hz), str(s.control_hz), s.description)
    console.print(table)


@app.command("show")
def show_character(
    name: Annotated[str, typer.Argument(help="Character name (see `amorctl characters list`).")],
    json_out: JsonFlag = False,
) -> None:
    """Show every joint (group, range, PD gains, actuator), end effectors, root, rates, DoF counts."""
    info = describe_character(get_registry().character(name))
    if json_out:
        print_json(info)
        return
    console.print(f"[bold]{info['name']}[/bold]: {info['description']}", highlight=False)
    console.print(
        f"root body: {info['root_body']}   nq={info['nq']} nv={info['nv']} nu={info['nu']}   "
        f"physics {info['physics_hz']} Hz, control {info['control_hz']} Hz ({info['substeps']} substeps)   "
        f"mass {info['total_mass']:.2f} kg",
        highlight=False,
    )
    console.print(f"end effectors: {', '.join(info['end_effectors'])}", highlight=False)
    act = info["actuator_model"]
    console.print("actuator model: " + ", ".join(f"{k}={v}" for k, v in act.items()), highlight=False)
    table = Table(title=f"{info['name']} joints")
    for col in ("joint", "group", "range (deg)", "kp", "kd", "torque limit"):
        table.add_column(col)
    for j in info["joints"]:
        lo, hi = j["range_deg"]
        table.add_row(
            j["name"],
            j["group"],
            f"{lo:.0f} … {hi:.0f}",
            f"{j['kp']:g}",
            f"{j['kd']:g}",
            f"{j['torque_limit']:g}",
        )
    console.print(table)
