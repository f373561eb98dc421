"""How fast each reference clip asks the character's joints to turn, against what its motors can.

A DC servo (``ActuatorModel(kind="servo")``) loses driving torque linearly with speed and has none
left at its no-load speed (:func:`amorctl.sim.actuators.torque_bounds`): a joint can pass that
speed only when gravity or momentum carries it, never under its own motor. A clip whose joints
spend much of their time above it cannot be tracked closely by that robot, however long the policy
trains. This module measures that demand per clip from the dataset's reference joint velocities
(``MotionLibrary.joint_vel``, the retargeted angles' forward differences at the control rate); it
needs no simulation. Shapes: F frames, J actuated joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amorctl.motion.clips import MotionLibrary


@dataclass(frozen=True)
class ClipSpeedDemand:
    """One clip's joint-speed demand.

    ``p50_rad_s``/``p95_rad_s``: median and 95th percentile of ``|q̇|`` over all its frames and
    joints. With a no-load speed: the same as fractions of it (``p50_ratio``, ``p95_ratio``),
    ``share_above`` = fraction of (frame, joint) samples faster than it, ``frames_above`` =
    fraction of frames with at least one such joint, and ``fastest_joint`` = the joint most often
    above it (None when none is). Without one these are None.
    """

    clip: str
    p50_rad_s: float
    p95_rad_s: float
    max_rad_s: float
    p50_ratio: float | None
    p95_ratio: float | None
    share_above: float | None
    frames_above: float | None
    fastest_joint: str | None


def clip_speed_demand(
    name: str, joint_vel: np.ndarray, joint_names: tuple[str, ...], no_load_speed: float | None
) -> ClipSpeedDemand:
    """The demand of one clip from its reference joint velocities [F, J] (rad/s)."""
    speed = np.abs(np.asarray(joint_vel, dtype=np.float64))
    p50, p95 = (float(np.percentile(speed, q)) for q in (50, 95))
    peak = float(speed.max()) if speed.size else 0.0
    if no_load_speed is None:
        return ClipSpeedDemand(name, p50, p95, peak, None, None, None, None, None)
    above = speed > no_load_speed  # [F, J]
    per_joint = above.mean(axis=0)  # [J]
    fastest = joint_names[int(per_joint.argmax())] if above.any() else None
    return ClipSpeedDemand(
        clip=name,
        p50_rad_s=p50,
        p95_rad_s=p95,
        max_rad_s=peak,
        p50_ratio=p50 / no_load_speed,
        p95_ratio=p95 / no_load_speed,
        share_above=float(above.mean()),
        frames_above=float(above.any(axis=1).mean()),
        fastest_joint=fastest,
    )


def speed_demand(lib: MotionLibrary, no_load_speed: float | None) -> list[ClipSpeedDemand]:
    """Every clip's demand, in the library's clip order (``no_load_speed`` in rad/s, None for
    motors without a torque–speed limit)."""
    if no_load_speed is not None and not no_load_speed > 0:
        raise ValueError(f"no_load_speed must be positive, got {no_load_speed}")
    return [
        clip_speed_demand(
            c.name, lib.joint_vel[c.start : c.start + c.num_frames], lib.joint_names, no_load_speed
        )
        for c in lib.clips
    ]
