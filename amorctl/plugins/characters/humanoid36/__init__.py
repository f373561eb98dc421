"""``humanoid36``: the DeepMimic humanoid with 36 velocity DoF and PD "virtual actuators".

Proportions, masses and joint layout follow ``pybullet_data/humanoid/humanoid.urdf`` at pybullet's
global scale 0.25 (45 kg). Each DeepMimic ball joint ``J`` is three hinges ``J_x, J_y, J_z``
(R = Rx Ry Rz, intrinsic XYZ, axes in the body frame); the two extra DoF are the toes. Body frames
are the DeepMimic link frames rotated +90° about x (Y-up → Z-up): a DeepMimic vector (x, y, z) is
(x, -z, y) here. See ``docs/characters.md``.

PD gains and torque limits are DeepMimic's (``pybullet_envs/deep_mimic``: ``kpOrg``, ``kdOrg``,
``maxForces``); MuJoCo position actuators apply them natively.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from amorctl.api import ActuatorModel, CharacterSpec, JointGroup, JointSpec, hookimpl

_PI = 3.14159  # the MJCF writes ranges with these literals
_HALF_PI = 1.5708
_BALL_RANGES = {"x": (-_PI, _PI), "y": (-_HALF_PI, _HALF_PI), "z": (-_PI, _PI)}

#: DeepMimic joint -> (group, kp, kd, torque limit). Toes: our own choice, scaled from the ankle.
_GAINS: dict[str, tuple[JointGroup, float, float, float]] = {
    "chest": ("upper", 1000.0, 100.0, 200.0),
    "neck": ("upper", 100.0, 10.0, 50.0),
    "shoulder": ("upper", 400.0, 40.0, 100.0),
    "elbow": ("upper", 300.0, 30.0, 60.0),
    "hip": ("lower", 500.0, 50.0, 200.0),
    "knee": ("lower", 500.0, 50.0, 150.0),
    "ankle": ("feet", 400.0, 40.0, 90.0),
    "toe": ("feet", 100.0, 10.0, 30.0),
}

_HINGE_RANGES = {
    "elbow": (0.0, _PI),  # DeepMimic URDF: [0, 3.14]
    "knee": (-_PI, 0.3),  # URDF: [-3.14, 0]; the clips hyperextend to +0.22
    "toe": (-_HALF_PI, 0.7854),  # toes up (negative) to 90°, down to 45°
}


def _ball(name: str, kind: str) -> tuple[JointSpec, ...]:
    group, kp, kd, limit = _GAINS[kind]
    return tuple(JointSpec(f"{name}_{a}", group, _BALL_RANGES[a], kp, kd, limit) for a in "xyz")


def _hinge(name: str, kind: str) -> JointSpec:
    group, kp, kd, limit = _GAINS[kind]
    return JointSpec(name, group, _HINGE_RANGES[kind], kp, kd, limit)


def _joints() -> tuple[JointSpec, ...]:
    """The 30 hinges in MJCF qpos order (depth-first: chest, neck, arms, then legs)."""
    joints: list[JointSpec] = [*_ball("chest", "chest"), *_ball("neck", "neck")]
    for side in ("right", "left"):
        joints += [*_ball(f"{side}_shoulder", "shoulder"), _hinge(f"{side}_elbow", "elbow")]
    for side in ("right", "left"):
        joints += [*_ball(f"{side}_hip", "hip"), _hinge(f"{side}_knee", "knee")]
        joints += [*_ball(f"{side}_ankle", "ankle"), _hinge(f"{side}_toe", "toe")]
    return tuple(joints)


#: Root height of the zero pose with the soles on the floor: hip→knee 0.421546 + knee→ankle 0.40987
#: + ankle→sole 0.05 (URDF lengths × 0.25).
STANDING_HEIGHT = 0.881416

SPEC = CharacterSpec(
    name="humanoid36",
    description="DeepMimic humanoid (45 kg, 1.6 m): free root + 30 PD hinges, toes added",
    mjcf_path=Path(__file__).with_name("humanoid36.xml"),
    root_body="root",
    joints=_joints(),
    end_effectors=("left_hand", "right_hand", "left_foot", "right_foot"),
    # Armature: reflected inertia of the virtual actuators, 0.01 kg·m² per hinge. DeepMimic's stable
    # (implicit) PD needs none; MuJoCo's explicit PD stiffness at 250 Hz is unstable without it on
    # the light foot and toe links.
    actuator=ActuatorModel(kind="pd", armature=0.01),
    standing_height=STANDING_HEIGHT,
    min_standing_height=round(0.9 * STANDING_HEIGHT, 4),
    keypoints={
        "root": "root",
        "head": "neck",
        "left_hand": "left_hand",
        "right_hand": "right_hand",
        "left_foot": "left_foot",
        "right_foot": "right_foot",
    },
    scale_profile="humanoid",
    standing_pose={},
    physics_hz=250,
    control_hz=50,
    licence="MIT (DeepMimic humanoid proportions)",
    retarget="direct",  # built on the DeepMimic skeleton: joint rotations map onto hinge triplets
)


@hookimpl
def amorctl_register_characters(register: Callable[[CharacterSpec], None]) -> None:
    """Register :data:`SPEC`."""
    register(SPEC)
