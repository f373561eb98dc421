"""Motion frames m_t exactly as the paper defines them, plus the world-frame state they come from.

Velocities are forward finite differences at the control rate: v_t = (x_{t+1} - x_t) / dt, and for
orientations ω_t = log(q_{t+1} q_t⁻¹) / dt (world frame). The last frame repeats the previous
velocity. So integrating the velocities from the first frame reproduces every position exactly
(x_{t+1} = x_t + v_t dt, q_{t+1} = exp(ω_t dt) q_t).

Frame vector layout (see :class:`amorctl.motion.clips.MotionLibrary`), all in the root's heading
frame: h [1], root_rot6d [6], root_vel [6] (linear, angular), joint_pos [J], joint_vel [J],
ee_pose [E * 9] (position relative to the root, then 6D rotation, per effector), ee_vel [E * 3]
(linear velocity relative to the root's, per effector).
"""

from __future__ import annotations

import numpy as np

from amorctl.core.frame_layout import frame_features
from amorctl.core.geometry import (
    quat_conj,
    quat_from_rotvec,
    quat_mul,
    quat_normalize,
    quat_to_rotvec,
)
from amorctl.motion.kinematics import CharacterKinematics
from amorctl.motion.source import CharacterMotion


def frame_layout(num_joints: int, num_effectors: int) -> dict[str, tuple[int, int]]:
    """Name -> (start, stop) columns of the frame vector; the last stop is D."""
    sizes = [
        ("h", 1),
        ("root_rot6d", 6),
        ("root_lin_vel", 3),
        ("root_ang_vel", 3),
        ("joint_pos", num_joints),
        ("joint_vel", num_joints),
        ("ee_pose", 9 * num_effectors),
        ("ee_vel", 3 * num_effectors),
    ]
    out, start = {}, 0
    for name, size in sizes:
        out[name] = (start, start + size)
        start += size
    return out


def forward_difference(x: np.ndarray, dt: float) -> np.ndarray:
    """(x_{t+1} - x_t) / dt along axis 0, the last row repeating the previous one. x: [T, ...]."""
    if x.shape[0] < 2:
        return np.zeros_like(x)
    v = np.diff(x, axis=0) / dt
    return np.concatenate([v, v[-1:]], axis=0)


def angular_velocity(quat: np.ndarray, dt: float) -> np.ndarray:
    """World angular velocities [T, ..., 3] from orientations [T, ..., 4] by forward difference."""
    if quat.shape[0] < 2:
        return np.zeros((*quat.shape[:-1], 3))
    rel = quat_mul(quat[1:], quat_conj(quat[:-1]))
    w = quat_to_rotvec(rel) / dt
    return np.concatenate([w, w[-1:]], axis=0)


def integrate(x0: np.ndarray, v: np.ndarray, dt: float) -> np.ndarray:
    """Positions [T, ...] from x0 [...] and forward-difference velocities v [T, ...]."""
    return np.concatenate([x0[None], x0[None] + np.cumsum(v[:-1], axis=0) * dt], axis=0)


def integrate_rotation(q0: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """Orientations [T, 4] from q0 [4] and world angular velocities w [T, 3]."""
    out = [quat_normalize(q0)]
    for t in range(w.shape[0] - 1):
        out.append(quat_normalize(quat_mul(quat_from_rotvec(w[t] * dt), out[-1])))
    return np.stack(out)


def frame_vectors(**state: np.ndarray) -> np.ndarray:
    """The paper's m_t [T, D] from world-frame state arrays with a leading [T].

    The one implementation is :func:`amorctl.core.frame_layout.frame_features` (the env computes
    the simulated character's frames with it every step), so datasets and observations agree
    exactly; this name keeps the keyword call used by the motion code.
    """
    return frame_features(**state)


def clip_arrays(motion: CharacterMotion, kin: CharacterKinematics, fps: float) -> dict[str, np.ndarray]:
    """World-frame state and frame vectors of one clip sampled at ``fps`` (its times must be uniform).

    Returns the :class:`MotionLibrary` per-frame arrays (without ``z``), each with a leading [T].
    """
    dt = 1.0 / fps
    root_quat = _continuous(quat_normalize(motion.root_quat))
    qpos = kin.qpos(motion.root_pos, root_quat, motion.joint_pos)
    ee_pos, ee_quat = kin.body_poses(qpos, list(kin.spec.end_effectors))
    ee_quat = _continuous(quat_normalize(ee_quat))
    arrays = {
        "root_pos": motion.root_pos,
        "root_quat": root_quat,
        "root_lin_vel": forward_difference(motion.root_pos, dt),
        "root_ang_vel": angular_velocity(root_quat, dt),
        "joint_pos": motion.joint_pos,
        "joint_vel": forward_difference(motion.joint_pos, dt),
        "ee_pos": ee_pos,
        "ee_quat": ee_quat,
        "ee_lin_vel": forward_difference(ee_pos, dt),
    }
    arrays["frames"] = frame_vectors(**arrays)
    return arrays


def _continuous(q: np.ndarray) -> np.ndarray:
    """Flip quaternion signs along time so consecutive frames lie in the same hemisphere. q: [T, ..., 4]."""
    q = q.copy()
    for t in range(1, q.shape[0]):
        flip = np.sum(q[t] * q[t - 1], axis=-1, keepdims=True) < 0
        q[t] = np.where(flip, -q[t], q[t])
    return q
