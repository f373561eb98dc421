"""Key-point inverse kinematics retargeting (any humanoid source -> e.g. ``biped20``), with ``mink``.

Method, per clip (all at the control rate):

1. Scale: s = target leg length / source leg length, each the vertical distance from the root key
   point to the mean foot key point in the zero pose. Every source key point is scaled about the
   world origin (so strides scale too), then shifted vertically so that the source's feet at their
   contact height land at the target's foot-origin height above its soles.
2. Contacts: a foot is in contact while its source key point is within ``CONTACT_HEIGHT`` of the
   clip's contact level and moves slower than ``CONTACT_SPEED`` horizontally (source units). Over
   each contact run the foot target is pinned to the run's mean position on the floor level, which
   removes foot sliding from the targets.
3. IK: differential IK with ``mink`` (QP solver daqp) per frame, warm-started from the previous
   frame: root position and orientation, feet position and orientation (kept flat on the ground
   plane, turned to the source foot's heading: a robot's feet are long relative to its legs, and
   a pitched foot would go through the floor), hands and head position,
   a weak posture task towards the character's standing pose, the joint limits, and a joint-speed
   bound (``MAX_JOINT_SPEED`` by default, a solver bound that keeps the solver from flipping a
   joint through its range between two frames when a target is out of reach; ``max_joint_speed``
   lowers it, e.g. to a servo's no-load speed so the reference stays within what the motors can
   follow).
4. Floor: the root is lifted wherever collision geometry dips below z = 0
   (:func:`amorctl.motion.retarget.common.lift_to_floor`).

The reported retargeting error is the mean distance between the character's key-point bodies and
the scaled (unpinned) source key points; the foot sliding before and after is recorded as well.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import mink
import mujoco
import numpy as np

from amorctl.core.geometry import heading_angle, quat_mul, yaw_quat
from amorctl.motion.kinematics import CharacterKinematics
from amorctl.motion.retarget.common import finish
from amorctl.motion.source import CharacterMotion, SourceMotion, forward_kinematics, keypoint_positions

CONTACT_HEIGHT = 0.03  # m above the clip's contact level (source units)
CONTACT_SPEED = 0.4  # m/s horizontal (source units)
COSTS = {  # key point -> (position cost, orientation cost)
    "root": (5.0, 2.0),
    "left_foot": (20.0, 2.0),
    "right_foot": (20.0, 2.0),
    "left_hand": (1.0, 0.0),
    "right_hand": (1.0, 0.0),
    "head": (0.5, 0.0),
}
POSTURE_COST = 0.05
DAMPING = 1e-3
MAX_JOINT_SPEED = 30.0  # rad/s bound on every actuated joint between frames (0 = unbounded)
ITERATIONS_FIRST = 50
ITERATIONS = 10
FEET = ("left_foot", "right_foot")


def source_leg_length(motion: SourceMotion) -> float:
    """Vertical root-to-feet distance of the source skeleton in its zero pose (m)."""
    skel = motion.skeleton
    zero = np.zeros((1, len(skel.names), 4))
    zero[..., 0] = 1.0
    rest = replace(motion, root_pos=np.zeros((1, 3)), local_quat=zero)
    kp = keypoint_positions(rest)
    return float(kp["root"][0, 2] - 0.5 * (kp["left_foot"][0, 2] + kp["right_foot"][0, 2]))


def target_geometry(kin: CharacterKinematics) -> tuple[float, float, dict[str, np.ndarray]]:
    """(leg length, foot-origin height above the sole, zero-pose key-point orientations relative
    to the root) of the character."""
    m, d = kin.model, kin.data
    d.qpos[:] = m.qpos0
    mujoco.mj_kinematics(m, d)
    kp = kin.spec.keypoints
    root = d.xpos[kin.body_id(kp["root"])]
    feet = [d.xpos[kin.body_id(kp[f])] for f in FEET]
    leg = float(root[2] - 0.5 * (feet[0][2] + feet[1][2]))
    foot_bodies = {kin.body_id(kp[f]) for f in FEET}
    sole = []
    for g in range(m.ngeom):
        if m.geom_bodyid[g] in foot_bodies or m.body_parentid[m.geom_bodyid[g]] in foot_bodies:
            sole.append(kin.geom_bottom(g))
    foot_height = float(feet[0][2] - min(sole)) if sole else 0.0
    rest = {k: d.xquat[kin.body_id(b)].copy() for k, b in kp.items()}
    return leg, foot_height, rest


def contact_mask(pos: np.ndarray, fps: float) -> np.ndarray:
    """[T] bool: the foot key point [T, 3] is low and slow (source units)."""
    level = np.percentile(pos[:, 2], 5)
    speed = np.zeros(pos.shape[0])
    if pos.shape[0] > 1:
        v = np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=-1) * fps
        speed = np.concatenate([v[:1], np.minimum(v[1:], v[:-1]), v[-1:]]) if v.size > 1 else np.repeat(v, 2)
    return (pos[:, 2] - level < CONTACT_HEIGHT) & (speed < CONTACT_SPEED)


def pin_contacts(target: np.ndarray, contact: np.ndarray, floor_z: float) -> np.ndarray:
    """Foot targets [T, 3] with every contact run held at its mean xy and at ``floor_z``."""
    out = target.copy()
    t = 0
    while t < len(contact):
        if not contact[t]:
            t += 1
            continue
        end = t
        while end < len(contact) and contact[end]:
            end += 1
        out[t:end, :2] = target[t:end, :2].mean(axis=0)
        out[t:end, 2] = floor_z
        t = end
    return out


def sliding(pos: np.ndarray, contact: np.ndarray, fps: float) -> float:
    """Mean horizontal speed (m/s) of a foot [T, 3] over consecutive contact frames."""
    both = contact[1:] & contact[:-1]
    if not both.any():
        return 0.0
    v = np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=-1) * fps
    return float(v[both].mean())


@dataclass(frozen=True)
class IkTargets:
    """What IK tracks, per key point (source skeleton scaled onto the character).

    scale: target / source leg length; scaled: key point -> [T, 3] scaled source positions;
    targets: the same with feet pinned during contacts; quats: key point -> [T, 4] source
    orientations (feet flat, turned to the source foot's heading); rest: key point -> [4] zero-pose
    orientation relative to the root; contacts: foot -> [T] bool; foot_height: foot origin above
    its sole (m).
    """

    scale: float
    scaled: dict[str, np.ndarray]
    targets: dict[str, np.ndarray]
    quats: dict[str, np.ndarray]
    rest: dict[str, np.ndarray]
    contacts: dict[str, np.ndarray]
    foot_height: float


def ik_targets(motion: SourceMotion, kin: CharacterKinematics, fps: float) -> IkTargets:
    """Steps 1 and 2 of the method: scale the source key points, detect and pin foot contacts."""
    leg_t, foot_h, rest = target_geometry(kin)
    scale = leg_t / source_leg_length(motion)
    src = keypoint_positions(motion)
    _, jquat = forward_kinematics(motion.skeleton, motion.root_pos, motion.local_quat)
    quats = {k: jquat[:, motion.skeleton.index(j)] for k, (j, _) in motion.skeleton.keypoints.items()}
    for f in FEET:  # feet stay flat, turned to the source foot's heading
        quats[f] = yaw_quat(heading_angle(quats[f]))
    contact_level = min(np.percentile(src[f][:, 2], 5) for f in FEET)
    dz = foot_h - scale * contact_level
    scaled = {k: v * scale + np.array([0.0, 0.0, dz]) for k, v in src.items()}
    contacts = {f: contact_mask(src[f], fps) for f in FEET}
    targets = dict(scaled)
    for f in FEET:
        targets[f] = pin_contacts(scaled[f], contacts[f], foot_h)
    return IkTargets(scale, scaled, targets, quats, rest, contacts, foot_h)


def solve_ik(
    kin: CharacterKinematics,
    goal: IkTargets,
    fps: float,
    num_frames: int,
    max_joint_speed: float = MAX_JOINT_SPEED,
) -> np.ndarray:
    """Step 3: differential IK frame by frame, warm-started; returns qpos [T, nq]. Every actuated
    joint turns at most ``max_joint_speed`` rad/s between frames (0 = unbounded)."""
    model = kin.model
    config = mink.Configuration(model)
    tasks: dict[str, mink.FrameTask] = {}
    for key, (pc, oc) in COSTS.items():
        if key in kin.spec.keypoints:
            tasks[key] = mink.FrameTask(
                kin.spec.keypoints[key], "body", position_cost=pc, orientation_cost=oc
            )
    posture = mink.PostureTask(model, cost=POSTURE_COST)
    q0 = model.qpos0.copy()
    for name, angle in kin.spec.standing_pose.items():
        q0[kin.joint_qpos[kin.spec.joint_names().index(name)]] = angle
    q0[kin.root_qpos : kin.root_qpos + 3] = goal.targets["root"][0]
    q0[kin.root_qpos + 3 : kin.root_qpos + 7] = goal.quats["root"][0]
    posture.set_target(q0)
    config.update(q0)
    limits: list = [mink.ConfigurationLimit(model)]
    if max_joint_speed > 0:
        limits.append(mink.VelocityLimit(model, {n: max_joint_speed for n in kin.spec.joint_names()}))
    all_tasks = [*tasks.values(), posture]

    qpos = np.zeros((num_frames, model.nq))
    for t in range(num_frames):
        for key, task in tasks.items():
            rest = goal.rest[key]
            quat = quat_mul(goal.quats[key][t], rest) if key in goal.quats else rest
            task.set_target(mink.SE3.from_rotation_and_translation(mink.SO3(quat), goal.targets[key][t]))
        # The first frame converges from the standing pose without a speed bound; later frames
        # split one control period over their iterations, so the speed bound holds per frame.
        iters = ITERATIONS_FIRST if t == 0 else ITERATIONS
        dt = 1.0 if t == 0 else 1.0 / (fps * iters)
        for _ in range(iters):
            vel = mink.solve_ik(
                config, all_tasks, dt, solver="daqp", damping=DAMPING, limits=limits[:1] if t == 0 else limits
            )
            config.integrate_inplace(vel, dt)
        qpos[t] = config.q
    return qpos


def retarget_ik(
    motion: SourceMotion, kin: CharacterKinematics, max_joint_speed: float = MAX_JOINT_SPEED
) -> CharacterMotion:
    """Retarget a skeleton animation (uniform times) onto ``kin``'s character by key-point IK,
    every joint within ``max_joint_speed`` rad/s (``amorctl preprocess --max-joint-speed``)."""
    fps = (
        1.0 / float(motion.times[1] - motion.times[0])
        if motion.times.size > 1
        else float(kin.spec.control_hz)
    )
    goal = ik_targets(motion, kin, fps)
    qpos = solve_ik(kin, goal, fps, motion.times.shape[0], max_joint_speed)
    r = kin.root_qpos
    out = CharacterMotion.retargeted(
        motion,
        kin.spec.name,
        root_pos=qpos[:, r : r + 3].copy(),
        root_quat=qpos[:, r + 3 : r + 7].copy(),
        joint_pos=qpos[:, kin.joint_qpos].copy(),
        stats={"method": "ik", "scale": goal.scale, "max_joint_speed": max_joint_speed},
    )
    out = finish(out, motion, kin, lift=True, targets=goal.scaled)
    feet_pos, _ = kin.body_poses(
        kin.qpos(out.root_pos, out.root_quat, out.joint_pos), [kin.spec.keypoints[f] for f in FEET]
    )
    contacts = goal.contacts
    stats = dict(out.stats)
    stats["foot_sliding_source"] = float(np.mean([sliding(goal.scaled[f], contacts[f], fps) for f in FEET]))
    stats["foot_sliding"] = float(
        np.mean([sliding(feet_pos[:, i], contacts[f], fps) for i, f in enumerate(FEET)])
    )
    stats["contact_fraction"] = float(np.mean([contacts[f].mean() for f in FEET]))
    return replace(out, stats=stats)
