"""What both retargeting methods share: the floor lift and the key-point error report.

Both methods finish with :func:`finish`: :func:`lift_to_floor` raises the root in any frame where
the character's collision geometry goes below the floor (z = 0) until its lowest point touches it,
and the mean key-point error against the targets is recorded.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from amorctl.motion.kinematics import CharacterKinematics
from amorctl.motion.source import CharacterMotion, SourceMotion, keypoint_positions

#: A retargeting method: a skeleton animation and the character's kinematics -> its motion.
Retargeter = Callable[[SourceMotion, CharacterKinematics], CharacterMotion]


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
