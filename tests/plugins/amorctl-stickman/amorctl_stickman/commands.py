"""``amorctl stickman ...``: the commands this plugin adds, as a robot vendor adds its tools.

``calibrate`` stands in for a servo calibration: it reports the zero offset of every joint.
Under ``--json`` it prints the JSON alone on stdout, as amorctl's own commands do.
"""

from __future__ import annotations

import json
import math
from typing import Annotated

import typer

from amorctl_stickman import SPEC

app = typer.Typer(
    help="Stickman12 robot tools: servo calibration and joints.", no_args_is_help=True, add_completion=False
)


@app.command()
def calibrate(
    offset: Annotated[float, typer.Option("--offset", help="Zero offset of every servo, degrees.")] = 0.0,
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Calibrate the 12 servos: the zero offset of each joint, radians."""
    offsets = {joint.name: math.radians(offset) for joint in SPEC.joints}
    if json_out:
        print(json.dumps({"character": SPEC.name, "offsets": offsets}))
    else:
        print(f"{SPEC.name}: {len(offsets)} servos calibrated, zero offset {offset:g} deg")


@app.command()
def joints() -> None:
    """List the joints, one per line, with their group."""
    for joint in SPEC.joints:
        print(f"{joint.name} {joint.group}")
