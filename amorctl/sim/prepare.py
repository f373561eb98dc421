"""Make a character's model file, as it comes, fit for amorctl: one place, applied before compiling.

A model from a robot package (MuJoCo Menagerie style) brings its own sensors, position actuators
with their own gains, joint armature and friction, and usually no floor. :func:`prepare_spec`
edits the parsed :class:`mujoco.MjSpec` so that what the :class:`~amorctl.core.specs.CharacterSpec`
states is what gets simulated:

- every actuated joint must exist and be driven by exactly one actuator (found by name, else by
  its joint transmission); a missing one is an error naming the file and the joints;
- ``kind="pd"``: each actuator must be a position actuator (``<position>``: fixed gain, affine
  bias); the spec's ``kp``, ``kd`` and ``torque_limit`` overwrite the file's gains and force range
  (the joint's own ``actuatorfrcrange`` is lifted so the spec's limit is the one that acts). Any
  other actuator type is refused with the mismatch named;
- ``kind="servo"``: amorctl computes the torque, so position actuators become motors (gain 1,
  no bias, no control or force limit); other types are refused;
- per-joint ``armature``, ``friction_coulomb`` (``frictionloss``) and ``friction_viscous``
  (``damping``) of :class:`~amorctl.core.specs.JointSpec` are written when stated;
- a floor plane (``amorctl_floor``) is added when the world has no plane or height field and the
  spec's ``add_floor`` is true;
- amorctl's own sensors are appended under names in the ``amorctl:`` namespace and located by
  name after compiling (:func:`sensor_addresses`), so sensors the file already has keep working and
  never shift amorctl's readings.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.specs import CharacterSpec

FLOOR_NAME = "amorctl_floor"
SENSOR_PREFIX = "amorctl:"
_EE_SENSORS = (
    ("pos", mujoco.mjtSensor.mjSENS_FRAMEPOS),
    ("quat", mujoco.mjtSensor.mjSENS_FRAMEQUAT),
    ("linvel", mujoco.mjtSensor.mjSENS_FRAMELINVEL),
)
_GROUND_TYPES = (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD)


def ee_sensor_name(index: int, body: str, quantity: str) -> str:
    """Name of amorctl's sensor of end effector ``index`` (``quantity``: pos | quat | linvel); the
    index keeps names unique when a body is listed twice."""
    return f"{SENSOR_PREFIX}ee{index}:{body}:{quantity}"


def torque_sensor_name(joint: str) -> str:
    """Name of amorctl's ``actuatorfrc`` sensor of one actuated joint (PD characters)."""
    return f"{SENSOR_PREFIX}{joint}:actuatorfrc"


def has_floor(spec: mujoco.MjSpec) -> bool:
    """Whether the world body holds a plane or height field (something to stand on)."""
    return any(g.type in _GROUND_TYPES for g in spec.worldbody.geoms)


def add_floor(spec: mujoco.MjSpec) -> None:
    """Add an infinite ground plane at z = 0 that collides with every default geom."""
    g = spec.worldbody.add_geom()
    g.name = FLOOR_NAME
    g.type = mujoco.mjtGeom.mjGEOM_PLANE
    g.size = [0.0, 0.0, 0.05]
    g.contype = 1
    g.conaffinity = 1
    g.rgba = [0.4, 0.5, 0.6, 1.0]


def is_position_actuator(act: mujoco.MjsActuator) -> bool:
    """A ``<position>`` actuator: force = kp (ctrl - q) - kv q̇, i.e. fixed gain and affine bias."""
    return (
        act.gaintype == mujoco.mjtGain.mjGAIN_FIXED
        and act.biastype == mujoco.mjtBias.mjBIAS_AFFINE
        and abs(act.biasprm[1] + act.gainprm[0]) <= 1e-9 * max(1.0, abs(act.gainprm[0]))
    )


def is_motor(act: mujoco.MjsActuator) -> bool:
    """A ``<motor>`` actuator: force = gain * ctrl."""
    return act.gaintype == mujoco.mjtGain.mjGAIN_FIXED and act.biastype == mujoco.mjtBias.mjBIAS_NONE


def actuator_kind(act: mujoco.MjsActuator) -> str:
    """``position``, ``motor`` or a description of anything else (for messages)."""
    if is_position_actuator(act):
        return "position"
    if is_motor(act):
        return "motor"
    return f"gain {act.gaintype.name}, bias {act.biastype.name}"


def joint_actuators(
    spec: mujoco.MjSpec, character: CharacterSpec, path: Path
) -> dict[str, mujoco.MjsActuator]:
    """The actuator of every actuated joint: the one named like the joint, else the one whose
    joint transmission targets it.

    Raises:
        AmorError: a joint is missing from the file, or has no actuator (both listed by name).
    """
    joints = {j.name for j in spec.joints}
    missing = [n for n in character.joint_names() if n not in joints]
    if missing:
        raise AmorError(
            f"{path}: character {character.name!r} names joint(s) the model lacks: {', '.join(missing)}"
        )
    by_name = {a.name: a for a in spec.actuators if a.name}
    by_target: dict[str, mujoco.MjsActuator] = {}
    for a in spec.actuators:
        if a.trntype == mujoco.mjtTrn.mjTRN_JOINT:
            by_target.setdefault(a.target, a)
    found: dict[str, mujoco.MjsActuator] = {}
    for name in character.joint_names():
        act = by_name.get(name)
        if act is None or act.trntype != mujoco.mjtTrn.mjTRN_JOINT or act.target != name:
            act = by_target.get(name)
        if act is not None:
            found[name] = act
    absent = [n for n in character.joint_names() if n not in found]
    if absent:
        raise AmorError(
            f"{path}: no actuator drives joint(s) {', '.join(absent)} (character {character.name!r})"
        )
    for name, act in found.items():
        if not act.name:  # sensors and lookups need a name
            act.name = f"{SENSOR_PREFIX}{name}"
    return found


def _apply_pd(act: mujoco.MjsActuator, joint: mujoco.MjsJoint, kp: float, kd: float, limit: float) -> None:
    gear = abs(float(act.gear[0])) or 1.0
    act.gainprm[0] = kp
    act.biasprm[1] = -kp
    act.biasprm[2] = -kd
    act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    act.forcerange = [-limit / gear, limit / gear]
    joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE


def _make_motor(act: mujoco.MjsActuator, joint: mujoco.MjsJoint) -> None:
    act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
    act.gainprm[0] = 1.0
    act.biastype = mujoco.mjtBias.mjBIAS_NONE
    act.biasprm[:3] = [0.0, 0.0, 0.0]
    act.dyntype = mujoco.mjtDyn.mjDYN_NONE
    act.inheritrange = 0.0
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    act.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE
    joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE


def apply_actuation(
    spec: mujoco.MjSpec, character: CharacterSpec, path: Path, acts: dict[str, mujoco.MjsActuator]
) -> None:
    """Apply the spec's PD gains and torque limits (``pd``) or turn actuators into motors (``servo``);
    ``acts`` is :func:`joint_actuators`' answer.

    Raises:
        AmorError: an actuator's type does not fit the character's actuator kind.
    """
    joints = {j.name: j for j in spec.joints}
    kind = character.actuator.kind
    for js in character.joints:
        act, joint = acts[js.name], joints[js.name]
        if kind == "pd":
            if not is_position_actuator(act):
                raise AmorError(
                    f"{path}: actuator {act.name!r} of joint {js.name!r} is a {actuator_kind(act)} actuator; "
                    f"character {character.name!r} has kind='pd', which needs <position> actuators "
                    f"(use kind='servo' for motors)"
                )
            _apply_pd(act, joint, js.kp, js.kd, js.torque_limit)
        else:
            if not (is_position_actuator(act) or is_motor(act)):
                raise AmorError(
                    f"{path}: actuator {act.name!r} of joint {js.name!r} is a {actuator_kind(act)} actuator; "
                    f"kind='servo' needs <motor> or <position> actuators"
                )
            if is_position_actuator(act):
                _make_motor(act, joint)


def apply_joint_properties(spec: mujoco.MjSpec, character: CharacterSpec) -> None:
    """Write the per-joint armature and friction that the JointSpecs state (None keeps the file's)."""
    joints = {j.name: j for j in spec.joints}
    for js in character.joints:
        joint = joints[js.name]
        if js.armature is not None:
            joint.armature = js.armature
        if js.friction_coulomb is not None:
            joint.frictionloss = js.friction_coulomb
        if js.friction_viscous is not None:
            damping = np.array(joint.damping, dtype=np.float64).reshape(-1)
            damping[0] = js.friction_viscous
            joint.damping = damping if damping.size > 1 else float(damping[0])


def add_tracking_sensors(
    spec: mujoco.MjSpec, character: CharacterSpec, acts: dict[str, mujoco.MjsActuator]
) -> None:
    """Append amorctl's named sensors: per end effector ``framepos``, ``framequat``, ``framelinvel``
    (world frame, body frame origin), and for PD characters one ``actuatorfrc`` per actuated joint."""
    for i, body in enumerate(character.end_effectors):
        for quantity, kind in _EE_SENSORS:
            s = spec.add_sensor()
            s.name = ee_sensor_name(i, body, quantity)
            s.type = kind
            s.objtype = mujoco.mjtObj.mjOBJ_XBODY
            s.objname = body
    if character.actuator.kind == "pd":
        for joint in character.joint_names():
            s = spec.add_sensor()
            s.name = torque_sensor_name(joint)
            s.type = mujoco.mjtSensor.mjSENS_ACTUATORFRC
            s.objtype = mujoco.mjtObj.mjOBJ_ACTUATOR
            s.objname = acts[joint].name


def prepare_spec(spec: mujoco.MjSpec, character: CharacterSpec, path: Path, sensors: bool = True) -> None:
    """All of the edits above, in place, in the order they must happen (see the module docstring)."""
    acts = joint_actuators(spec, character, path)
    apply_actuation(spec, character, path, acts)
    apply_joint_properties(spec, character)
    if character.add_floor and not has_floor(spec):
        add_floor(spec)
    if sensors:
        add_tracking_sensors(spec, character, acts)


@dataclass(frozen=True)
class SensorAddresses:
    """Where amorctl's sensors sit in ``sensordata``.

    ee [E, 10]: per end effector the addresses of pos (3), quat (4), linvel (3);
    torque [J]: the ``actuatorfrc`` address of each actuated joint (empty for servo characters).
    """

    ee: np.ndarray
    torque: np.ndarray


def sensor_addresses(model: mujoco.MjModel, character: CharacterSpec) -> SensorAddresses:
    """Look amorctl's sensors up by name in a compiled model.

    Raises:
        AmorError: a sensor is missing (the model was not compiled through :func:`prepare_spec`).
    """

    def adr(name: str, width: int) -> np.ndarray:
        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
        if sid < 0:
            raise AmorError(f"character {character.name!r}: compiled model lacks amorctl sensor {name!r}")
        if int(model.sensor_dim[sid]) != width:
            raise AmorError(f"character {character.name!r}: sensor {name!r} has dim {model.sensor_dim[sid]}")
        start = int(model.sensor_adr[sid])
        return np.arange(start, start + width)

    widths = {"pos": 3, "quat": 4, "linvel": 3}
    rows = [
        np.concatenate([adr(ee_sensor_name(i, body, q), w) for q, w in widths.items()])
        for i, body in enumerate(character.end_effectors)
    ]
    ee = np.array(rows, dtype=np.int64).reshape(len(character.end_effectors), 10)
    torque = (
        np.array([adr(torque_sensor_name(j), 1)[0] for j in character.joint_names()], dtype=np.int64)
        if character.actuator.kind == "pd"
        else np.zeros(0, dtype=np.int64)
    )
    return SensorAddresses(ee=ee, torque=torque)
