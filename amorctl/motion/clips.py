"""The in-memory motion library: every clip's frames as flat arrays, for fast random access.

This is the contract between motion data (``amorctl preprocess`` and the dataset loader) and the
environments that track it. All clips are concatenated along the frame axis F; clip ``k`` owns
frames ``starts[k] : starts[k] + lengths[k]``. Frames are at the character's control rate.
J = actuated joints (character order), E = end effectors (character order: hands then feet,
left then right), L = latent size. Quaternions (w, x, y, z); world frame is MuJoCo's (z up).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from amorctl.core.errors import AmorError


@dataclass(frozen=True)
class ClipInfo:
    """One clip's metadata."""

    name: str  # short name users type: "walk", "walker/turn_left", ...
    source: str  # file it came from (path or package-relative path)
    sha256: str  # of the source file's bytes
    licence: str
    start: int  # first frame index into the flat arrays
    num_frames: int
    source_fps: float
    retarget_error: float = 0.0  # mean key-point error of retargeting, m (0 for direct mapping)


@dataclass(frozen=True)
class MotionLibrary:
    """All frames of all clips, world-frame state plus the paper's heading-frame frame vector m_t.

    World-frame arrays (for reference-state initialization and reward targets):
        root_pos [F, 3], root_quat [F, 4], root_lin_vel [F, 3] (world), root_ang_vel [F, 3] (world),
        joint_pos [F, J], joint_vel [F, J], ee_pos [F, E, 3], ee_quat [F, E, 4], ee_lin_vel [F, E, 3].
    Paper frame m_t (all in the root's heading frame), flattened in ``frames`` [F, D] in this order:
        h [1], root_rot6d [6], root_vel [6] (linear then angular), joint_pos [J], joint_vel [J],
        ee_pose [E * 9] (per effector: position relative to the root, then 6D rotation),
        ee_vel [E * 3] (linear velocity relative to the root's, per effector).
    Latents: ``z`` [F, L], the motion-VAE mean of the window centred at each frame (L may be 0).
    """

    character: str
    fps: float
    joint_names: tuple[str, ...]
    end_effectors: tuple[str, ...]
    clips: tuple[ClipInfo, ...]
    root_pos: np.ndarray
    root_quat: np.ndarray
    root_lin_vel: np.ndarray
    root_ang_vel: np.ndarray
    joint_pos: np.ndarray
    joint_vel: np.ndarray
    ee_pos: np.ndarray
    ee_quat: np.ndarray
    ee_lin_vel: np.ndarray
    frames: np.ndarray
    z: np.ndarray
    metadata: dict = field(default_factory=dict)

    @property
    def num_frames(self) -> int:
        return int(self.root_pos.shape[0])

    @property
    def frame_dim(self) -> int:
        return int(self.frames.shape[1])

    @property
    def latent_dim(self) -> int:
        return int(self.z.shape[1])

    @property
    def starts(self) -> np.ndarray:
        """[K] first frame of each clip."""
        return np.array([c.start for c in self.clips], dtype=np.int64)

    @property
    def lengths(self) -> np.ndarray:
        """[K] frames per clip."""
        return np.array([c.num_frames for c in self.clips], dtype=np.int64)

    def clip_duration(self, clip: ClipInfo) -> float:
        """Seconds spanned by the clip's frames at ``fps``."""
        return (clip.num_frames - 1) / self.fps

    def subset(self, names: Sequence[str]) -> MotionLibrary:
        """The library of the named clips only (in this library's order): their frames, latents
        and clip records, renumbered. AmorError when none of the names is a clip here."""
        keep = [c for c in self.clips if c.name in set(names)]
        if not keep:
            raise AmorError(
                f"none of {', '.join(names) or 'no names'} is a clip of the {self.character} dataset"
            )
        index = np.concatenate([np.arange(c.start, c.start + c.num_frames) for c in keep])
        clips, start = [], 0
        for c in keep:
            clips.append(dataclasses.replace(c, start=start))
            start += c.num_frames
        arrays = {
            f.name: getattr(self, f.name)[index]
            for f in dataclasses.fields(self)
            if isinstance(getattr(self, f.name), np.ndarray)
        }
        return dataclasses.replace(self, clips=tuple(clips), **arrays)
