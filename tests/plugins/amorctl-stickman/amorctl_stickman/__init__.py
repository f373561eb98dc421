"""A third-party amorctl plugin: the 12-hinge 'stickman12' character and its ``amorctl stickman``
commands.

It lives in amorctl's test tree to prove that a separately installed package can add a character
and commands through the ``amorctl`` entry-point group, with no change to amorctl itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

from amorctl.api import ActuatorModel, CharacterSpec, CommandSpec, JointSpec, hookimpl

_HERE = Path(__file__).parent
_D = math.radians


def _joint(name: str, group: str, lo: float, hi: float, kp: float, limit: float) -> JointSpec:
    return JointSpec(name=name, group=group, range=(_D(lo), _D(hi)), kp=kp, kd=kp / 10, torque_limit=limit)


SPEC = CharacterSpec(
    name="stickman12",
    description="Small 12-hinge stick figure (third-party test plugin)",
    mjcf_path=_HERE / "stickman12.xml",
    root_body="root",
    joints=(
        _joint("left_shoulder", "upper", -180, 180, 40, 20),
        _joint("left_elbow", "upper", 0, 150, 20, 10),
        _joint("right_shoulder", "upper", -180, 180, 40, 20),
        _joint("right_elbow", "upper", 0, 150, 20, 10),
        _joint("left_hip_x", "lower", -45, 45, 80, 40),
        _joint("left_hip_y", "lower", -120, 45, 80, 40),
        _joint("left_knee", "lower", 0, 150, 60, 30),
        _joint("left_ankle", "feet", -45, 45, 40, 20),
        _joint("right_hip_x", "lower", -45, 45, 80, 40),
        _joint("right_hip_y", "lower", -120, 45, 80, 40),
        _joint("right_knee", "lower", 0, 150, 60, 30),
        _joint("right_ankle", "feet", -45, 45, 40, 20),
    ),
    end_effectors=("left_hand", "right_hand", "left_foot", "right_foot"),
    actuator=ActuatorModel(kind="pd"),
    standing_height=0.865,
    min_standing_height=0.3,  # a test fixture: it is not tuned to balance unaided
    keypoints={
        "root": "root",
        "head": "torso",
        "left_hand": "left_hand",
        "right_hand": "right_hand",
        "left_foot": "left_foot",
        "right_foot": "right_foot",
    },
    scale_profile="humanoid",
    objective_scales={"tracking7": {"up": 2.0, "lo": 2.0, "feet": 2.0}},
    licence="MIT",
)


@hookimpl
def amorctl_register_characters(register: Callable[[CharacterSpec], None]) -> None:
    """Provide stickman12."""
    register(SPEC)


@hookimpl
def amorctl_register_commands(register: Callable[[CommandSpec], None]) -> None:
    """Provide ``amorctl stickman calibrate|joints``."""
    from amorctl_stickman.commands import app

    register(CommandSpec("stickman", app))
