"""What a robot user watches in a weight sweep: the action rate and the joint-velocity RMS per level.

Computed from a recorded rollout (:class:`~amorctl.analysis.rollout.Rollout`) whose envs are laid
out level-major (E envs per level, as :func:`~amorctl.analysis.level_sweep.weight_sweep` does). Only
differences between consecutive steps of the same counted episode on consecutive reference frames
count (:func:`step_pairs`), so episode ends and clip switches never show up as jerks.

The sums are kept per level (:class:`MotionSums`) so that sweeps split over processes add up.
Shapes: T = recorded steps, N = envs, J = actuated joints (A = action size for non-tracking envs),
L = levels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


def step_pairs(valid: np.ndarray, episode_id: np.ndarray, frame_index: np.ndarray | None) -> np.ndarray:
    """[T, N] bool: step t and step t-1 belong to the same counted episode and the reference
    advanced by one frame between them (no clip switch), so a finite difference is meaningful.
    Row 0 is all False."""
    ok = np.zeros(valid.shape, dtype=bool)
    same = valid[1:] & valid[:-1] & (episode_id[1:] == episode_id[:-1]) & (episode_id[1:] >= 0)
    if frame_index is not None:
        same &= frame_index[1:] == frame_index[:-1] + 1
    ok[1:] = same
    return ok


def smoothness_per_env(
    actions: np.ndarray,
    joint_pos: np.ndarray | None,
    ref_joint_pos: np.ndarray | None,
    pairs: np.ndarray,
    dt: float,
    residual: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Action rate and joint-velocity square sums per env, over the step pairs of :func:`step_pairs`.

    The PD target sent at step t is ``q*_t = ref_t + a_t`` (residual actions) or ``a_t``
    (absolute; also any non-tracking env's action); the action rate is ``||q*_t - q*_{t-1}||^2``
    (summed over joints), the quantity ``tracking7``'s action-rate term penalizes; joint velocity
    is ``(q_t - q_{t-1}) / dt`` (zero without ``joint_pos``).

    Args:
        actions: [T, N, J]; joint_pos, ref_joint_pos: [T, N, J] rad or None; pairs: [T, N] bool.

    Returns:
        (action-rate sum [N], joint-velocity squared sum [N] over pairs and joints); the pair
        count is ``pairs.sum(0)``.
    """
    target = actions + ref_joint_pos if (residual and ref_joint_pos is not None) else actions
    d_target = np.zeros(actions.shape[:2])
    d_target[1:] = ((target[1:] - target[:-1]) ** 2).sum(axis=-1)
    vel2 = np.zeros(actions.shape[:2])
    if joint_pos is not None:
        vel2[1:] = (((joint_pos[1:] - joint_pos[:-1]) / dt) ** 2).sum(axis=-1)
    return np.where(pairs, d_target, 0.0).sum(axis=0), np.where(pairs, vel2, 0.0).sum(axis=0)


@dataclass
class MotionSums:
    """Per-level sums of a sweep's recorded steps.

    Attributes:
        action_rate: [L] summed action rates; joint_vel2: [L] summed squared joint velocities;
        pairs: [L] step pairs counted; joints: J (None when the env has no joints: toy, gym).
    """

    action_rate: np.ndarray
    joint_vel2: np.ndarray
    pairs: np.ndarray
    joints: int | None

    def __add__(self, other: MotionSums) -> MotionSums:
        """The sums of two disjoint sets of episodes of the same levels (data-parallel sweeps)."""
        return MotionSums(
            self.action_rate + other.action_rate,
            self.joint_vel2 + other.joint_vel2,
            self.pairs + other.pairs,
            self.joints,
        )

    def to_dict(self) -> dict[str, Any]:
        """Per level: mean action rate per step and joint-velocity RMS (rad/s; None without
        joints), and whether each falls monotonically along the levels."""
        c = self.pairs.astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            rate = self.action_rate / c
            rms = np.sqrt(self.joint_vel2 / (c * self.joints)) if self.joints else None
        return {
            "action_rate": [_num(x) for x in rate],
            "joint_vel_rms": None if rms is None else [_num(x) for x in rms],
            "step_pairs": [int(x) for x in self.pairs],
            "action_rate_falls": bool(np.all(np.diff(rate) < 0)),
            "joint_vel_rms_falls": None if rms is None else bool(np.all(np.diff(rms) < 0)),
        }


def _num(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def motion_sums(rollout: Any, levels: int, residual: bool) -> MotionSums:
    """The :class:`MotionSums` of a level-major rollout recorded with ``record_steps``."""
    pairs = step_pairs(rollout.valid, rollout.episode_id, rollout.frame_index)
    rate, vel2 = smoothness_per_env(
        rollout.actions, rollout.joint_pos, rollout.ref_joint_pos, pairs, rollout.dt, residual
    )
    joints = None if rollout.joint_pos is None else int(rollout.joint_pos.shape[-1])
    return MotionSums(
        rate.reshape(levels, -1).sum(axis=1),
        vel2.reshape(levels, -1).sum(axis=1),
        pairs.sum(axis=0).reshape(levels, -1).sum(axis=1),
        joints,
    )
