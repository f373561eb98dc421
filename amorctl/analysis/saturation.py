"""How often a servo character's motors run out of torque while a policy tracks a clip.

A DC servo (:func:`amorctl.sim.actuators.torque_bounds`) cannot push harder than its driver's
current limit (the stall torque) and has no driving torque left at its motors' no-load speed. A
joint-step counts as **at the current limit** when the largest ``|tau|`` over the control step's
physics substeps reaches :data:`CURRENT_FRACTION` of the stall torque, and as **at the speed limit**
when ``|q̇|`` at the end of the step reaches :data:`SPEED_FRACTION` of the no-load speed (driving
torque down to a tenth of stall or less). Pure over arrays; the rollouts that feed it are in
``benchmarks/saturation.py``.

Shapes: T control steps, N envs, S physics substeps per control step, J actuated joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: |tau| at or above this share of the stall torque: the driver's current limit binds.
CURRENT_FRACTION = 0.95
#: |q̇| at or above this share of the no-load speed: at most a tenth of the stall torque left to drive.
SPEED_FRACTION = 0.9


@dataclass(frozen=True)
class Saturation:
    """Shares of the counted joint-steps at a motor limit.

    Attributes:
        current: [J] share of steps at the current limit, per joint.
        speed: [J] share of steps at the speed limit, per joint (zeros without a no-load speed).
        either: [J] share of steps at either limit, per joint.
        any_joint: share of steps with at least one joint at either limit.
        steps: counted (env, step) pairs.
    """

    current: np.ndarray
    speed: np.ndarray
    either: np.ndarray
    any_joint: float
    steps: int


def at_limits(
    torque: np.ndarray,
    joint_vel: np.ndarray,
    torque_limit: np.ndarray,
    no_load_speed: float | np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Which joint-steps sit at the current limit and which at the speed limit.

    Args:
        torque: [..., S, J] joint torques of every physics substep, N·m.
        joint_vel: [..., J] joint velocities at the end of each control step, rad/s.
        torque_limit: [J] stall torques, N·m.
        no_load_speed: rad/s, scalar or [J], or None (no speed limit).

    Returns:
        (current [..., J], speed [..., J]) bool.
    """
    current = np.abs(torque).max(axis=-2) >= CURRENT_FRACTION * np.asarray(torque_limit)
    if no_load_speed is None:
        return current, np.zeros_like(current)
    speed = np.abs(joint_vel) >= SPEED_FRACTION * np.asarray(no_load_speed)
    return current, speed


def saturation(
    torque: np.ndarray,
    joint_vel: np.ndarray,
    counted: np.ndarray,
    torque_limit: np.ndarray,
    no_load_speed: float | np.ndarray | None,
) -> Saturation:
    """Shares of the ``counted`` joint-steps at the current or the speed limit (:func:`at_limits`).

    Args:
        torque: [T, N, S, J] joint torques of every physics substep, N·m.
        joint_vel: [T, N, J] joint velocities at the end of each control step, rad/s.
        counted: [T, N] bool, the steps to count (e.g. a rollout's ``valid``).
        torque_limit: [J] stall torques, N·m.
        no_load_speed: rad/s, scalar or [J], or None.

    Returns:
        :class:`Saturation` (NaN shares when nothing is counted).
    """
    current, speed = at_limits(torque, joint_vel, torque_limit, no_load_speed)
    mask = np.asarray(counted, dtype=bool)
    steps = int(mask.sum())
    if steps == 0:
        nan = np.full(current.shape[-1], np.nan)
        return Saturation(nan, nan, nan, float("nan"), 0)
    either = current | speed
    return Saturation(
        current=current[mask].mean(axis=0),
        speed=speed[mask].mean(axis=0),
        either=either[mask].mean(axis=0),
        any_joint=float(either[mask].any(axis=-1).mean()),
        steps=steps,
    )


def before_falls(terminated: np.ndarray, episode_id: np.ndarray, window: int) -> np.ndarray:
    """[T, N] bool: the last ``window`` steps of every counted episode that ended in a fall.

    Args:
        terminated: [T, N] bool, the episode ended at this step by a fall or divergence.
        episode_id: [T, N] int, the counted episode a step belongs to (-1: not counted), as a
            rollout records it.
        window: steps up to and including the fall.
    """
    out = np.zeros(terminated.shape, dtype=bool)
    for t, n in zip(*np.nonzero(terminated & (episode_id >= 0)), strict=True):
        start = max(0, t - window + 1)
        out[start : t + 1, n] = episode_id[start : t + 1, n] == episode_id[t, n]
    return out
