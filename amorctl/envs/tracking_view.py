"""The torch-cpu tracking env's :class:`~amorctl.core.contracts.TrackingView`.

Analysis (rollouts, evaluation, Pareto sweeps, tuning, videos) reads a tracking env only through
this view (``env.tracking_view()``, or :func:`amorctl.core.contracts.tracking_view` through
wrappers), never through the env's attributes, so a second backend's env plugs in by providing
its own view. Every array returned is a copy.

Shapes: N = envs, J = actuated joints, E = end effectors, C = clips, Df = frame vector size,
nq = simulator position size.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from amorctl.core.frame_layout import split_frame
from amorctl.core.specs import CharacterSpec

if TYPE_CHECKING:
    from amorctl.envs.tracking_env import TrackingEnv


class TrackingViewBase(ABC):
    """What every backend's view reads alike from its env: the facts fixed for the env's life
    (character, control period, clips, joints, observation layout) and the current weights. A
    backend's view subclasses it and adds ``model`` and the simulated state.

    Args:
        env: a tracking env with ``character``, ``dt``, ``max_episode_steps``, ``num_envs``,
            ``fall_drop``, ``future_frames``, ``library``, ``obs_layout`` and ``weights``.
    """

    def __init__(self, env: Any) -> None:
        self._env = env
        self.character: CharacterSpec = env.character
        self.dt = float(env.dt)
        self.max_episode_steps = int(env.max_episode_steps)
        self.num_envs = int(env.num_envs)
        self.fall_drop = float(env.fall_drop)
        self.future_frames = tuple(int(o) for o in env.future_frames)
        lib = env.library
        self._clip_names = tuple(c.name for c in lib.clips)
        self._clip_seconds = np.array([lib.clip_duration(c) for c in lib.clips], dtype=np.float64)
        self._layout = MappingProxyType({k: (s.start, s.stop) for k, s in env.obs_layout.items()})

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.character.name!r}, num_envs={self.num_envs})"

    # --- fixed for the env's life --------------------------------------------------------------
    @property
    def clip_names(self) -> tuple[str, ...]:
        """The C clip names, in library order."""
        return self._clip_names

    @property
    def clip_seconds(self) -> np.ndarray:
        """[C] float64 clip durations (seconds from the first to the last frame)."""
        return self._clip_seconds.copy()

    @property
    def clip_frame_counts(self) -> np.ndarray:
        """[C] int64 frames per clip."""
        return self._env.library.lengths

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The J actuated joint names, in action order."""
        return tuple(self._env.library.joint_names)

    @property
    def observation_layout(self) -> Mapping[str, tuple[int, int]]:
        """Named ``(start, stop)`` slices of the observation (docs/observations.md)."""
        return self._layout

    def reference_joint_pos(self, frames: np.ndarray) -> np.ndarray:
        """[..., J] reference joint angles (rad) of library ``frames`` [...]."""
        return np.array(self._env.library.joint_pos[np.asarray(frames, dtype=np.int64)])

    def reference_qpos(self, frames: np.ndarray) -> np.ndarray:
        """[T, nq] float64 reference poses of library ``frames`` [T]: root and joints from the
        library, every other entry from the model's initial state. The root quaternion is left as
        stored (MuJoCo's kinematics normalizes it)."""
        template, r, joint_qpos = self._pose_template()
        lib = self._env.library
        f = np.asarray(frames, dtype=np.int64).reshape(-1)
        q = np.tile(np.asarray(template, np.float64), (len(f), 1))
        q[:, r : r + 3] = lib.root_pos[f]
        q[:, r + 3 : r + 7] = lib.root_quat[f]
        q[:, joint_qpos] = lib.joint_pos[f]
        return q

    @abstractmethod
    def _pose_template(self) -> tuple[np.ndarray, int, np.ndarray]:
        """(the model's initial qpos [nq], the root's qpos address, the joints' [J])."""

    # --- the current state ---------------------------------------------------------------------
    @property
    def weights(self) -> np.ndarray:
        """[N, m] float32 weights of each env's current episode."""
        return self._env.weights

    # --- the one control -----------------------------------------------------------------------
    def select_clips(
        self,
        clips: Sequence[int] | None = None,
        env_clips: np.ndarray | None = None,
        from_start: bool = False,
    ) -> None:
        """Restrict the clips episodes draw, or pin one per env, from the next reset on
        (:meth:`TrackingEnv.select_clips`)."""
        self._env.select_clips(clips, env_clips, from_start)


class TrackingEnvView(TrackingViewBase):
    """The read-only view of a :class:`~amorctl.envs.tracking_env.TrackingEnv` (plus ``select_clips``).

    Args:
        env: the env it reads; the view holds no state of its own.
    """

    def __init__(self, env: TrackingEnv) -> None:
        super().__init__(env)

    @property
    def model(self) -> mujoco.MjModel:
        """The compiled MuJoCo model of one character."""
        return self._env.sim.model

    def clip_index(self) -> np.ndarray:
        """[N] int64, the clip each env tracks now."""
        return self._env.clip_id.copy()

    def reference_index(self) -> np.ndarray:
        """[N] int64, the library frame the current simulator state should match."""
        return self._env.ref_idx.copy()

    def qpos(self) -> np.ndarray:
        """[N, nq] float64 simulator positions now."""
        return self._env.sim.qpos.copy()

    def joint_pos(self) -> np.ndarray:
        """[N, J] float64 joint angles now (rad)."""
        return self._env.sim.joint_pos().copy()

    def joint_vel(self) -> np.ndarray:
        """[N, J] float64 joint velocities now (rad/s)."""
        return self._env.sim.joint_vel().copy()

    def end_effector_pos(self) -> np.ndarray:
        """[N, E, 3] end-effector positions relative to the root, in its heading frame (m)."""
        env = self._env
        return np.array(split_frame(env._sim_frames(), env.num_joints, env.num_ee).ee_pos)

    # --- the reference -------------------------------------------------------------------------
    def reference_frames(self, frames: np.ndarray) -> np.ndarray:
        """[..., Df] heading-frame frame vectors of library ``frames`` [...] (what rewards compare)."""
        return np.array(self._env.ref_frames[np.asarray(frames, dtype=np.int64)])

    def _pose_template(self) -> tuple[np.ndarray, int, np.ndarray]:
        sim = self._env.sim
        return sim.template[sim.s_qpos], sim.root_qpos, np.asarray(sim.joint_qpos)
