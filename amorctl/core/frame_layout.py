"""What a tracking environment hands to an objective set, and the frame vector both sides share.

The paper's frame ``m_t = (h, θ, v, q, q̇, p, ṗ)`` is a flat vector laid out as
:class:`amorctl.motion.clips.MotionLibrary` documents (all in the root's heading frame):
``h [1], root_rot6d [6], root_vel [6] (linear then angular), joint_pos [J], joint_vel [J],
ee_pose [E*9] (per effector: position relative to the root, then 6D rotation), ee_vel [E*3]``.
:func:`frame_features` computes it from world-frame state (the simulator's or the motion
library's), :func:`split_frame` cuts it into named parts, and an objective set receives a
:class:`TrackingInputs` holding the simulated and the reference parts plus the actuation history.

All functions take the array namespace ``xp`` (numpy or jax.numpy).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


def frame_dim(num_joints: int, num_ee: int) -> int:
    """D, the length of a frame vector for J joints and E end effectors."""
    return 1 + 6 + 6 + 2 * num_joints + 12 * num_ee


@dataclass(frozen=True)
class FrameParts:
    """A frame vector cut into named parts (all heading-frame quantities).

    Shapes (N = batch): h [N], root_rot6d [N, 6], root_lin_vel [N, 3], root_ang_vel [N, 3],
    joint_pos [N, J], joint_vel [N, J], ee_pos [N, E, 3], ee_rot6d [N, E, 6], ee_vel [N, E, 3].
    """

    h: Any
    root_rot6d: Any
    root_lin_vel: Any
    root_ang_vel: Any
    joint_pos: Any
    joint_vel: Any
    ee_pos: Any
    ee_rot6d: Any
    ee_vel: Any


def split_frame(frames: Any, num_joints: int, num_ee: int, xp: Any = np) -> FrameParts:
    """Cut flat frames [N, D] into :class:`FrameParts` (views, no copies in numpy)."""
    j, e, n = num_joints, num_ee, frames.shape[0]
    o = 13
    pose = xp.reshape(frames[:, o + 2 * j : o + 2 * j + 9 * e], (n, e, 9))
    return FrameParts(
        h=frames[:, 0],
        root_rot6d=frames[:, 1:7],
        root_lin_vel=frames[:, 7:10],
        root_ang_vel=frames[:, 10:13],
        joint_pos=frames[:, o : o + j],
        joint_vel=frames[:, o + j : o + 2 * j],
        ee_pos=pose[:, :, :3],
        ee_rot6d=pose[:, :, 3:],
        ee_vel=xp.reshape(frames[:, o + 2 * j + 9 * e :], (n, e, 3)),
    )


def _rot_columns(q: Any, xp: Any) -> tuple[Any, Any]:
    """First two columns of R(q) for unit quaternions (w, x, y, z). q: [..., 4] -> 2 x [..., 3]."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    c0 = xp.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=-1)
    c1 = xp.stack([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], axis=-1)
    return c0, c1


def _unyaw(v: Any, c: Any, s: Any, xp: Any) -> Any:
    """Rotate vectors v [..., 3] by -heading, given cos/sin of the heading broadcastable to [...]."""
    return xp.stack([c * v[..., 0] + s * v[..., 1], c * v[..., 1] - s * v[..., 0], v[..., 2]], axis=-1)


#: The world-frame state arrays :func:`frame_features` reads, in its argument order (also the
#: per-frame state a motion library stores under these names).
STATE_ARRAYS: tuple[str, ...] = (
    "root_pos", "root_quat", "root_lin_vel", "root_ang_vel", "joint_pos", "joint_vel",
    "ee_pos", "ee_quat", "ee_lin_vel",
)  # fmt: skip


def frame_features(
    root_pos: Any,
    root_quat: Any,
    root_lin_vel: Any,
    root_ang_vel: Any,
    joint_pos: Any,
    joint_vel: Any,
    ee_pos: Any,
    ee_quat: Any,
    ee_lin_vel: Any,
    xp: Any = np,
) -> Any:
    """The heading-frame frame vector m_t from world-frame state.

    The heading is :func:`amorctl.core.geometry.heading_angle` of the root (yaw of its x axis); every
    vector and orientation is rotated by minus that yaw (``heading_quat_inv``), written out in
    closed form because this runs on every env step.

    Args:
        root_pos: [N, 3] world root position (z up; the ground is z = 0), m.
        root_quat: [N, 4] world root orientation (w, x, y, z), unit norm.
        root_lin_vel: [N, 3] world root linear velocity, m/s.
        root_ang_vel: [N, 3] world root angular velocity, rad/s.
        joint_pos: [N, J] rad.  joint_vel: [N, J] rad/s.
        ee_pos: [N, E, 3] world end-effector positions.  ee_quat: [N, E, 4] world orientations.
        ee_lin_vel: [N, E, 3] world end-effector linear velocities.
    Returns:
        [N, D] frames, D = 13 + 2J + 12E, laid out as the module docstring says.
    """
    n, e = ee_pos.shape[0], ee_pos.shape[1]
    r0, r1 = _rot_columns(root_quat, xp)
    norm = xp.sqrt(r0[:, 0] ** 2 + r0[:, 1] ** 2)
    flat = norm < 1e-12  # x axis vertical: heading 0, as atan2(0, 0)
    safe = xp.where(flat, 1.0, norm)
    c = xp.where(flat, 1.0, r0[:, 0] / safe)
    s = xp.where(flat, 0.0, r0[:, 1] / safe)
    ce, se = c[:, None], s[:, None]
    e0, e1 = _rot_columns(ee_quat, xp)
    pose = xp.concatenate(
        [_unyaw(ee_pos - root_pos[:, None, :], ce, se, xp), _unyaw(e0, ce, se, xp), _unyaw(e1, ce, se, xp)],
        axis=-1,
    )
    rel_vel = _unyaw(ee_lin_vel - root_lin_vel[:, None, :], ce, se, xp)
    return xp.concatenate(
        [
            root_pos[:, 2:3],
            _unyaw(r0, c, s, xp),
            _unyaw(r1, c, s, xp),
            _unyaw(root_lin_vel, c, s, xp),
            _unyaw(root_ang_vel, c, s, xp),
            joint_pos,
            joint_vel,
            xp.reshape(pose, (n, 9 * e)),
            xp.reshape(rel_vel, (n, 3 * e)),
        ],
        axis=-1,
    )


@dataclass(frozen=True)
class TrackingInputs:
    """Everything an objective set may read for one transition (s_t, a_t, s_{t+1}, c_t).

    ``sim`` is the simulated state after the step, ``ref`` the reference frame it should match.
    Actuation (J = actuated joints, S = physics substeps per control step):
        torque [N, S, J] joint torques of every substep, N·m;
        pd_target [N, J] this step's PD targets a_t; pd_target_prev [N, J] a_{t-1};
        pd_target_prev2 [N, J] a_{t-2} (rad; at an episode start the history is the initial pose);
        joint_acc [N, J] (q̇_{t+1} - q̇_t) / Δt_control, rad/s².
    """

    sim: FrameParts
    ref: FrameParts
    torque: Any
    pd_target: Any
    pd_target_prev: Any
    pd_target_prev2: Any
    joint_acc: Any
