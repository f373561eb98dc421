"""``biped20``: a 20-servo biped on the Robotis OP3's kinematics, masses and servo parameters.

The MJCF (primitive geoms, no meshes) keeps MuJoCo Menagerie ``op3.xml``'s joint names, axes,
link masses and inertias. Actuation is a servo model beyond ideal PD (``ActuatorModel(kind="servo")``):
PD on a command delayed by ``latency_steps`` physics steps, clipped by a linear torque–speed curve
(:mod:`amorctl.sim.actuators`), plus native armature and Coulomb/viscous friction.
See ``docs/characters.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

from amorctl.api import ActuatorModel, CharacterSpec, JointGroup, JointSpec, hookimpl

#: op3.xml servo parameters (XM430-W350 servos): position-actuator kp, forcerange, joint defaults.
KP = 21.1  # N·m/rad
KD = 0.0  # the servo's derivative gain; op3.xml models the velocity term as joint damping instead
TORQUE_LIMIT = 5.0  # N·m
ARMATURE = 0.045  # kg·m²
FRICTION_COULOMB = 0.03  # N·m (frictionloss)
FRICTION_VISCOUS = 1.084  # N·m·s/rad (damping)
#: XM430-W350 no-load speed, 46 rpm at 12 V (ROBOTIS e-Manual), in rad/s.
NO_LOAD_SPEED = 46.0 * 2.0 * math.pi / 60.0
#: 2 physics steps at 250 Hz = 8 ms: about one cycle of the ROBOTIS framework's 8 ms control loop (estimate).
LATENCY_STEPS = 2
#: op3.xml has no joint limits; its position actuators' ctrlrange is ±π.
_RANGE = (-3.141592, 3.141592)

#: joint -> group, in MJCF qpos order (op3.xml's order).
_JOINTS: tuple[tuple[str, JointGroup], ...] = (
    ("head_pan", "upper"),
    ("head_tilt", "upper"),
    ("l_sho_pitch", "upper"),
    ("l_sho_roll", "upper"),
    ("l_el", "upper"),
    ("r_sho_pitch", "upper"),
    ("r_sho_roll", "upper"),
    ("r_el", "upper"),
    ("l_hip_yaw", "lower"),
    ("l_hip_roll", "lower"),
    ("l_hip_pitch", "lower"),
    ("l_knee", "lower"),
    ("l_ank_pitch", "feet"),
    ("l_ank_roll", "feet"),
    ("r_hip_yaw", "lower"),
    ("r_hip_roll", "lower"),
    ("r_hip_pitch", "lower"),
    ("r_knee", "lower"),
    ("r_ank_pitch", "feet"),
    ("r_ank_roll", "feet"),
)

#: MuJoCo Playground's OP3 ``stand_bent_knees`` keyframe: knees bent, arms down, feet flat.
STANDING_POSE: dict[str, float] = {
    "l_sho_pitch": -0.534072,
    "l_sho_roll": 0.879648,
    "l_el": -0.62832,
    "r_sho_pitch": 0.534072,
    "r_sho_roll": -0.879648,
    "r_el": 0.62832,
    "l_hip_pitch": -0.596904,
    "l_knee": 1.13098,
    "l_ank_pitch": 0.534072,
    "r_hip_pitch": 0.596904,
    "r_knee": -1.13098,
    "r_ank_pitch": -0.534072,
}

#: Root (torso frame) height with STANDING_POSE and both soles flat on the floor, m.
STANDING_HEIGHT = 0.244784

SPEC = CharacterSpec(
    name="biped20",
    description="Robotis OP3-based biped (3.1 kg, 0.5 m): free root + 20 servos, latency, torque-speed curve",
    mjcf_path=Path(__file__).with_name("biped20.xml"),
    root_body="torso",
    joints=tuple(JointSpec(n, g, _RANGE, KP, KD, TORQUE_LIMIT) for n, g in _JOINTS),
    end_effectors=("left_hand", "right_hand", "left_foot", "right_foot"),
    actuator=ActuatorModel(
        kind="servo",
        armature=ARMATURE,
        friction_coulomb=FRICTION_COULOMB,
        friction_viscous=FRICTION_VISCOUS,
        no_load_speed=NO_LOAD_SPEED,
        latency_steps=LATENCY_STEPS,
    ),
    standing_height=STANDING_HEIGHT,
    min_standing_height=round(0.9 * STANDING_HEIGHT, 4),
    keypoints={
        "root": "torso",
        "head": "head_tilt_link",
        "left_hand": "left_hand",
        "right_hand": "right_hand",
        "left_foot": "left_foot",
        "right_foot": "right_foot",
    },
    scale_profile="robot",
    standing_pose=STANDING_POSE,
    physics_hz=250,
    control_hz=50,
    licence="Apache-2.0 (Robotis OP3 parameters via MuJoCo Menagerie)",
)


@hookimpl
def amorctl_register_characters(register: Callable[[CharacterSpec], None]) -> None:
    """Register :data:`SPEC`."""
    register(SPEC)
