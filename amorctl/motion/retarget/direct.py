"""Direct retargeting onto a character built on the canonical (DeepMimic) skeleton.

Used for characters whose spec says ``retarget="direct"`` (``humanoid36``): every ball joint's
local rotation (already in MuJoCo axes, R_mj = C R_dm Cᵀ) becomes its hinge triplet
``J_x, J_y, J_z`` by an intrinsic Euler decomposition along the triplet's axes; 1-DoF joints take
the twist about their axis; joints the source lacks (the toes) stay at 0. Angle tracks are
unwrapped in time (no 2π jumps) and moved by whole turns so their mean lies in the joint range.
They are not clipped: past 90° about a triplet's middle axis (gimbal lock) the outer angles turn
by π, which a hinge limited to ±π cannot always follow, and clipping would change the pose (a
backflip's key points moved by up to 1.7 m). The pose stays exact; ``stats["frames_outside_range"]``
counts, per joint, the frames whose angle lies outside the joint's range.
"""

from __future__ import annotations

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.geometry import mat_to_euler_xyz, quat_to_mat
from amorctl.motion.kinematics import CharacterKinematics
from amorctl.motion.retarget.common import finish
from amorctl.motion.source import CharacterMotion, SourceMotion


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
