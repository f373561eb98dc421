"""The MJX tracking env's :class:`~amorctl.core.contracts.TrackingView` (what analysis reads).

The same view as torch-cpu's ``TrackingEnvView``, reading :class:`~.env.MjxTrackingEnv`'s device
state (copied to numpy on every call). Shapes: N envs, J joints, E end effectors, C clips.
"""

from __future__ import annotations

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

    def _pose_template(self) -> tuple[np.ndarray, int, np.ndarray]:
        core = self._env.core
        return np.asarray(core.model.qpos0, np.float64), core.root_qpos, np.asarray(core.joint_qpos)
