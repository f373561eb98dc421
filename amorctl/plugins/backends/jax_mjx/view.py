"""The MJX tracking env's :class:`~amorctl.core.contracts.TrackingView` (what analysis reads).

The same view as torch-cpu's ``TrackingEnvView``, reading :class:`~.env.MjxTrackingEnv`'s device
state (copied to numpy on every call). Shapes: N envs, J joints, E end effectors, C clips.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import jax.numpy as jnp
import mujoco
import numpy as np

from amorctl.core.frame_layout import frame_features, split_frame
from amorctl.envs.tracking_view import TrackingViewBase

if TYPE_CHECKING:
    from amorctl.plugins.backends.jax_mjx.env import MjxTrackingEnv


class MjxTrackingView(TrackingViewBase):
    """The read-only view of an :class:`~.env.MjxTrackingEnv` (plus ``select_clips``)."""

    def __init__(self, env: MjxTrackingEnv) -> None:
        super().__init__(env)

    @property
    def model(self) -> mujoco.MjModel:
        return self._env.model

    def _state(self):
        return self._env._require()

    def clip_index(self) -> np.ndarray:
        return np.asarray(self._state().clip_id, np.int64)

    def reference_index(self) -> np.ndarray:
        return np.asarray(self._state().ref_idx, np.int64)

    def qpos(self) -> np.ndarray:
        return np.asarray(self._state().data.qpos, np.float64)

    def joint_pos(self) -> np.ndarray:
        return np.asarray(self._state().data.qpos[:, self._env.core.joint_qpos], np.float64)

    def joint_vel(self) -> np.ndarray:
        return np.asarray(self._state().data.qvel[:, self._env.core.joint_dof], np.float64)

    def end_effector_pos(self) -> np.ndarray:
        st, core = self._state(), self._env.core
        pos, quat, lin, ang = core._root(st.data)
        frames = frame_features(
            pos,
            quat,
            lin,
            ang,
            st.data.qpos[:, core.joint_qpos],
            st.data.qvel[:, core.joint_dof],
            st.ee_pos,
            st.ee_quat,
            st.ee_lin_vel,
            jnp,
        )
        return np.array(split_frame(np.asarray(frames, np.float64), core.num_joints, core.num_ee).ee_pos)

    def reference_frames(self, frames: np.ndarray) -> np.ndarray:
        return np.asarray(self._env.core.ref_frames[np.asarray(frames, dtype=np.int64)], np.float64)

    def reference_joint_pos(self, frames: np.ndarray) -> np.ndarray:
        return np.array(self._env.library.joint_pos[np.asarray(frames, dtype=np.int64)])

    def reference_qpos(self, frames: np.ndarray) -> np.ndarray:
        """[T, nq] reference poses: root and joints from the library, the rest the model's qpos0."""
        core, lib = self._env.core, self._env.library
        f = np.asarray(frames, dtype=np.int64).reshape(-1)
        q = np.tile(np.asarray(core.model.qpos0, np.float64), (len(f), 1))
        r = core.root_qpos
        q[:, r : r + 3] = lib.root_pos[f]
        q[:, r + 3 : r + 7] = lib.root_quat[f]
        q[:, np.asarray(core.joint_qpos)] = lib.joint_pos[f]
        return q

    def select_clips(
        self,
        clips: Sequence[int] | None = None,
        env_clips: np.ndarray | None = None,
        from_start: bool = False,
    ) -> None:
        self._env.select_clips(clips, env_clips, from_start)
