"""Retargeting a source skeleton animation onto a character.

Two methods, chosen per character by :data:`RETARGETERS` (default: IK):

- ``direct`` (``humanoid36``): the character is the DeepMimic humanoid, so every ball joint's
  local rotation (already in MuJoCo axes, R_mj = C R_dm Cᵀ) becomes its hinge triplet by an
  intrinsic Euler decomposition along the triplet's axes; 1-DoF joints take the twist about their
  axis; joints the source lacks (the toes) stay at 0. Angle tracks are unwrapped in time (no 2π
  jumps) and moved by whole turns so their mean lies in the joint range. They are not clipped:
  past 90° about a triplet's middle axis (gimbal lock) the outer angles turn by π, which a hinge
  limited to ±π cannot always follow, and clipping would change the pose (a backflip's key points
  moved by up to 1.7 m). The pose stays exact; ``stats["frames_outside_range"]`` counts, per
  joint, the frames whose angle lies outside the joint's range.
- ``ik`` (any other character): inverse kinematics on key points, see :mod:`amorctl.motion.retarget.ik`.

Both finish with :func:`lift_to_floor`: in any frame where the character's collision geometry
goes below the floor (z = 0) the root is raised until its lowest point touches it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.geometry import mat_to_euler_xyz, quat_to_mat
from amorctl.motion.kinematics import CharacterKinematics
from amorctl.motion.source import CharacterMotion, SourceMotion, keypoint_positions

Retargeter = Callable[[SourceMotion, CharacterKinematics], CharacterMotion]


def retarget_direct(motion: SourceMotion, kin: CharacterKinematics) -> CharacterMotion:
    """Map canonical joints onto same-named hinges (``J_x, J_y, J_z`` or ``J``)."""
    skel = motion.skeleton
    num_frames = motion.times.shape[0]
    names = kin.spec.joint_names()
    joint_pos = np.zeros((num_frames, len(names)))
    done: set[int] = set()
    for j, source_joint in enumerate(skel.names):
        if j == 0:
            continue
        triplet = [f"{source_joint}_{a}" for a in "xyz"]
        local = motion.local_quat[:, j]
        if all(t in names for t in triplet):
            idx = [names.index(t) for t in triplet]
            axes = kin.joint_axes[idx]  # rows: the three hinge axes in the body frame
            if abs(np.linalg.det(axes) - 1.0) > 1e-6 or not np.allclose(axes @ axes.T, np.eye(3), atol=1e-6):
                raise AmorError(
                    f"{kin.spec.mjcf_path}: joints {', '.join(triplet)} are not a right-handed axis triplet"
                )
            mats = quat_to_mat(local)
            euler = mat_to_euler_xyz(axes @ mats @ axes.T)  # the rotation in the triplet's own axes
            joint_pos[:, idx] = np.unwrap(euler, axis=0)
            done.update(idx)
        elif source_joint in names:
            i = names.index(source_joint)
            axis = kin.joint_axes[i]
            twist = 2.0 * np.arctan2(local[:, 1:] @ axis, local[:, 0])
            joint_pos[:, i] = np.unwrap(twist)
            done.add(i)
        else:
            raise AmorError(f"character {kin.spec.name!r} has no joint(s) for source joint {source_joint!r}")
    joint_pos = _shift_into_range(joint_pos, kin.joint_ranges)
    lo, hi = kin.joint_ranges[:, 0], kin.joint_ranges[:, 1]
    outside = (joint_pos < lo - 1e-9) | (joint_pos > hi + 1e-9)
    out = CharacterMotion.retargeted(
        motion,
        kin.spec.name,
        root_pos=motion.root_pos.copy(),
        root_quat=motion.local_quat[:, 0].copy(),
        joint_pos=joint_pos,
        stats={
            "method": "direct",
            "unmapped_joints": [n for i, n in enumerate(names) if i not in done],
            "frames_outside_range": {
                names[j]: int(outside[:, j].sum()) for j in np.flatnonzero(outside.any(axis=0))
            },
        },
    )
    return finish(out, motion, kin, lift=True)


def _shift_into_range(joint_pos: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """Move each unwrapped angle track by whole turns so its mean lies inside the joint range."""
    mid = ranges.mean(axis=1)
    turns = np.round((joint_pos.mean(axis=0) - mid) / (2 * np.pi))
    return joint_pos - 2 * np.pi * turns


#: Half-width (frames) of the smoothing applied to the floor lift, so the root does not jump.
LIFT_SMOOTHING = 5


def smooth_lift(needed: np.ndarray, radius: int = LIFT_SMOOTHING) -> np.ndarray:
    """A smooth lift [T] that is >= ``needed`` [T] everywhere: a moving max, then a moving mean.

    Both windows have the same radius, so every mean covers the max filter's value at its centre.
    """
    if radius <= 0 or needed.size == 0:
        return needed
    pad = np.pad(needed, radius, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(pad, 2 * radius + 1)
    maxed = np.pad(windows.max(axis=1), radius, mode="edge")
    return np.lib.stride_tricks.sliding_window_view(maxed, 2 * radius + 1).mean(axis=1)


def lift_to_floor(motion: CharacterMotion, kin: CharacterKinematics) -> tuple[CharacterMotion, np.ndarray]:
    """Raise the root where the body dips below z = 0 (smoothly); returns the lift [T] (m, >= 0)."""
    low = kin.lowest_points(kin.qpos(motion.root_pos, motion.root_quat, motion.joint_pos))
    lift = smooth_lift(np.maximum(0.0, -low))
    root = motion.root_pos.copy()
    root[:, 2] += lift
    return replace(motion, root_pos=root), lift


def keypoint_errors(
    motion: CharacterMotion, targets: dict[str, np.ndarray], kin: CharacterKinematics
) -> np.ndarray:
    """[T, K] distance between the character's key-point bodies and target positions (m)."""
    keys = list(targets)
    pos, _ = kin.body_poses(
        kin.qpos(motion.root_pos, motion.root_quat, motion.joint_pos), [kin.spec.keypoints[k] for k in keys]
    )
    tgt = np.stack([targets[k] for k in keys], axis=1)
    return np.linalg.norm(pos - tgt, axis=-1)


def finish(
    out: CharacterMotion,
    source: SourceMotion,
    kin: CharacterKinematics,
    lift: bool,
    targets: dict[str, np.ndarray] | None = None,
) -> CharacterMotion:
    """Lift onto the floor and record the mean key-point error against ``targets`` (default: source)."""
    lifted = np.zeros(out.times.shape[0])
    if lift:
        out, lifted = lift_to_floor(out, kin)
    if targets is None:
        targets = keypoint_positions(source)
    errors = keypoint_errors(out, targets, kin)
    stats = dict(out.stats)
    stats.update(
        keypoint_error_mean=float(errors.mean()),
        keypoint_error_max=float(errors.max()),
        keypoint_error_per_point={k: float(e) for k, e in zip(targets, errors.mean(axis=0), strict=True)},
        floor_lift_max=float(lifted.max()),
        floor_lift_frames=int((lifted > 0).sum()),
    )
    return replace(out, retarget_error=float(errors.mean()), stats=stats)


def _ik(motion: SourceMotion, kin: CharacterKinematics) -> CharacterMotion:
    from amorctl.motion.retarget.ik import retarget_ik

    return retarget_ik(motion, kin)


#: Character name -> retargeter; characters not listed use inverse kinematics.
RETARGETERS: dict[str, Retargeter] = {"humanoid36": retarget_direct}


def retarget(motion: SourceMotion, kin: CharacterKinematics) -> CharacterMotion:
    """Retarget with the method registered for the character (IK when none is)."""
    return RETARGETERS.get(kin.spec.name, _ik)(motion, kin)
