"""Termination on tracking error (``[env] termination_distance``, a training lever).

An episode that has drifted far from its reference teaches little: its rewards are near zero and
the states it visits are ones the reference never reaches. Motion-tracking recipes (DeepMimic,
ProtoMotions, BeyondMimic) therefore end such episodes early. Here the pose is compared in the
heading frame the rewards use: each end effector's position relative to the root, and the root
height. Global drift (position, heading) does not count, since no objective rewards it either.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from amorctl.core.frame_layout import FrameParts


def tracking_error(sim: FrameParts, ref: FrameParts, xp: Any = np) -> Any:
    """[N] metres: the largest of the end effectors' root-relative position errors and the root
    height error (ee_pos [N, E, 3], h [N] in both parts)."""
    ee = xp.sqrt(xp.sum((sim.ee_pos - ref.ee_pos) ** 2, axis=-1))  # [N, E]
    return xp.maximum(xp.max(ee, axis=-1), xp.abs(sim.h - ref.h))


def far_from_reference(sim: FrameParts, ref: FrameParts, distance: float, xp: Any = np) -> Any:
    """[N] bool: the tracking error exceeds ``distance`` metres (all False for ``distance`` 0: off)."""
    if distance <= 0:
        return xp.zeros(sim.h.shape, dtype=bool)
    return tracking_error(sim, ref, xp) > distance
