"""``amorctl characters``: list the installed characters, show one in full."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, print_json
from amorctl.core.errors import AmorError
from amorctl.registry import get_registry
from amorctl.sim.character_info import describe_character

app = typer.Typer(help="Inspect the installed characters.", no_args_is_help=True)


@app.command("list")
def list_characters(json_out: JsonFlag = False) -> None:
    """List installed characters with their DoF counts and rates."""
    registry = get_registry()
    specs, unavailable = [], {}
    for n in registry.names("character"):
        try:  # a lazily built character whose model is missing is listed, not fatal
            specs.append(registry.character(n))
        except AmorError as exc:
            unavailable[n] = str(exc)
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
                ],
                "unavailable": unavailable,
            }
        )
        return
    table = Table(title="characters")
    for col in ("name", "joints", "physics Hz", "control Hz", "description"):
        table.add_column(col)
    for s in specs:
        table.add_row(s.name, str(s.num_joints), str(s.physics_hz), str(s.control_hz), s.description)
    for n, problem in unavailable.items():
        table.add_row(n, "-", "-", "-", f"unavailable: {problem}")
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
    console.print(
        "actuator model (as simulated: joint properties from the compiled model): "
        + ", ".join(f"{k}={_range_text(v)}" for k, v in act.items()),
        highlight=False,
    )
    table = Table(title=f"{info['name']} joints")
    for col in (
        "joint",
        "group",
        "range (deg)",
        "kp",
        "kd",
        "torque limit",
        "armature",
        "friction",
        "damping",
    ):
        table.add_column(col)
    for j in info["joints"]:
        lo, hi = j["range_deg"]
        table.add_row(
            j["name"],
            j["group"],
            f"{lo:.0f} … {hi:.0f}",
            *(
                f"{j[k]:g}"
                for k in ("kp", "kd", "torque_limit", "armature", "friction_coulomb", "friction_viscous")
            ),
        )
    console.print(table)


def _range_text(value: object) -> str:
    """``0.01`` or ``0.005…0.02`` (a [min, max] of per-joint values)."""
    return (
        f"{value[0]:g}…{value[1]:g}"
        if isinstance(value, list)
        else f"{value:g}"
        if isinstance(value, float)
        else str(value)
    )


#: scale profile -> the built-in character whose ``smooth`` scales the profile was tuned on.
REFERENCE_CHARACTERS = {"robot": "biped20", "humanoid": "humanoid36"}
_STYLE = {"pass": "green", "warn": "yellow", "fail": "red"}


@app.command("check")
def check_character_cmd(
    name: Annotated[str, typer.Argument(help="Character name (see `amorctl characters list`).")],
    hold: Annotated[bool, typer.Option("--hold/--no-hold", help="Run the 5 s PD hold test.")] = True,
    cost: Annotated[
        bool,
        typer.Option("--cost/--no-cost", help="Time the simulation (about a second) and report its cost."),
    ] = True,
    objective_set: Annotated[
        str, typer.Option("--objectives", help="Objective set whose smooth scales to suggest for.")
    ] = "tracking7",
    json_out: JsonFlag = False,
) -> None:
    """Check a character's spec against its model: one pass/warn/fail line per check; exit 1 on a fail."""
    from amorctl.sim.check import check_character, checks_json, worst

    registry = get_registry()
    spec = registry.character(name)
    ref_name = REFERENCE_CHARACTERS.get(spec.scale_profile)
    reference = registry.character(ref_name) if ref_name in registry.names("character") else None
    scale = None
    if reference is not None and objective_set in registry.names("objective-set"):
        try:
            scales = getattr(registry.objective_set(objective_set).make(spec), "scales", {})
        except AmorError:
            scales = {}
        scale = scales.get("smooth_torque")
    checks = check_character(spec, hold=hold, reference=reference, smooth_torque_scale=scale, cost=cost)
    result = worst(checks)
    if json_out:
        print_json({"character": name, "result": result, "checks": checks_json(checks)})
    else:
        for c in checks:
            console.print(
                f"[{_STYLE[c.status]}]{c.status:<4}[/{_STYLE[c.status]}] {c.name}: {escape(c.detail)}",
                highlight=False,
                soft_wrap=True,  # one line per check, also when piped (grep, CI logs)
            )
        console.print(f"{name}: {result}", highlight=False, soft_wrap=True)
    if result == "fail":
        raise typer.Exit(1)
