"""Resampling clips onto a uniform time grid (the character's control rate).

The new grid is t_k = k / hz for k = 0 .. floor(duration * hz), duration = the source's last frame
time, so the clip keeps its duration up to one control period. Positions and joint angles are
interpolated linearly, rotations by slerp between the bracketing source frames.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from amorctl.core.geometry import quat_slerp
from amorctl.motion.source import CharacterMotion, SourceMotion


def uniform_times(times: np.ndarray, hz: float) -> np.ndarray:
    """[K] uniform grid at ``hz`` covering times [T]."""
    duration = float(times[-1] - times[0])
    count = int(np.floor(duration * hz + 1e-6)) + 1
    return np.arange(count) / hz


def _brackets(times: np.ndarray, new: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices (i0, i1) of the source frames around each new time and the blend factor [K]."""
    rel = times - times[0]
    i1 = np.clip(np.searchsorted(rel, new, side="right"), 1, max(len(rel) - 1, 1))
    i0 = i1 - 1
    if len(rel) == 1:
        return np.zeros_like(i0), np.zeros_like(i0), np.zeros(len(new))
    span = rel[i1] - rel[i0]
    alpha = np.clip((new - rel[i0]) / span, 0.0, 1.0)
    return i0, i1, alpha


def lerp(values: np.ndarray, i0: np.ndarray, i1: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Linear blend of values [T, ...] -> [K, ...]."""
    a = alpha.reshape((-1,) + (1,) * (values.ndim - 1))
    return (1.0 - a) * values[i0] + a * values[i1]


def slerp(quats: np.ndarray, i0: np.ndarray, i1: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Slerp of quaternions [T, ..., 4] -> [K, ..., 4]."""
    a = np.broadcast_to(alpha.reshape((-1,) + (1,) * (quats.ndim - 2)), quats[i0].shape[:-1])
    return quat_slerp(quats[i0], quats[i1], a)


def resample_source(motion: SourceMotion, hz: float) -> SourceMotion:
    """A skeleton animation on the uniform grid at ``hz``."""
    new = uniform_times(motion.times, hz)
    i0, i1, alpha = _brackets(motion.times, new)
    return replace(
        motion,
        times=new,
        root_pos=lerp(motion.root_pos, i0, i1, alpha),
        local_quat=slerp(motion.local_quat, i0, i1, alpha),
    )


def resample_character(motion: CharacterMotion, hz: float) -> CharacterMotion:
    """Character poses on the uniform grid at ``hz``; joint angles are unwrapped first."""
    new = uniform_times(motion.times, hz)
    i0, i1, alpha = _brackets(motion.times, new)
    return replace(
        motion,
        times=new,
        root_pos=lerp(motion.root_pos, i0, i1, alpha),
        root_quat=slerp(motion.root_quat, i0, i1, alpha),
        joint_pos=lerp(np.unwrap(motion.joint_pos, axis=0), i0, i1, alpha),
    )
