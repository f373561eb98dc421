"""The contracts between layers: what a backend, its trainer, its policy and its env provide.

Everything after training (pareto, evaluate, tune, hlp, deploy) and the training loop itself talk
to a backend only through these protocols, so a second backend (``jax-mjx``) plugs in by
implementing them. Plugin authors import them from :mod:`amorctl.api`.

- :class:`Backend` — ``make_env``, ``make_trainer``, ``load_policy``; ``BackendSpec.make()``
  returns one.
- :class:`Trainer` — one MOPPO iteration at a time; ``state_dict()`` is a :class:`Snapshot`
  (numpy arrays + JSON, stored as safetensors + JSON, never pickles).
- :class:`Policy` — a trained, frozen policy: deterministic actions for observations that carry
  ``w`` in their last m entries, critic values, the objective names, the observation layout.
- :class:`Teacher` — frozen policies that teach a student each clip (``[distill] teachers``): the
  training loop builds it and hands it to the trainer through the env (:func:`vecenv.teacher_of`).
- :class:`SnapshotEnv` — an env that saves and restores its full state (bit-exact resume).
- :class:`ObjectiveSet` — what ``ObjectiveSetSpec.make(character)`` returns: r ``[N, m]``.
- :class:`TrackingView` — the read-only, backend-neutral view of a motion-tracking env that
  analysis reads (joint angles, reference frames and index, clips, end effectors, the model for
  rendering, the weights), plus the one control it needs: which clips the envs track.

Shapes: N = envs, m = objectives, D = observation size, A = action size, J = actuated joints,
E = end effectors, F = library frames, C = clips, nq = simulator position size.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    import mujoco

    from amorctl.core.config import TrainConfig
    from amorctl.core.frame_layout import TrackingInputs
    from amorctl.core.specs import CharacterSpec
    from amorctl.core.vecenv import VectorEnv


@dataclass
class Snapshot:
    """A saved state: named numpy arrays (stored in safetensors) and JSON-ready metadata."""

    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)


# ---------------------------------------------------------------------------- training
@runtime_checkable
class Trainer(Protocol):
    """One backend's training loop, stepped one iteration at a time.

    Optional: ``world_size`` (the data-parallel processes it trains across; 1 when absent), read
    through :func:`trainer_world_size`.
    """

    iteration_count: int  # iterations completed so far

    def iteration(self) -> dict[str, float]:
        """Collect one rollout, update the networks; return this iteration's metrics.

        Metric names are ``/``-separated (``loss/value``, ``return/up``, ``explained_variance/up``,
        ``env_steps_per_s``, ...), values are plain floats (NaN where undefined). ``iteration``
        (the count after this one) is always present: the run's metrics rows are keyed by it.
        """
        ...

    def state_dict(self) -> Snapshot:
        """Everything needed to continue training exactly: weights, normalizer, optimizer, RNG, the
        current observations and episode statistics."""
        ...

    def load_state_dict(self, state: Snapshot) -> None:
        """Restore a :meth:`state_dict` snapshot. Raises AmorError if it does not fit this trainer."""
        ...

    def reset_env(self, seed: int) -> None:
        """Restart every env episode with ``seed`` and take the new observations (used on resume
        when the env cannot snapshot itself)."""
        ...

    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Actions [N, A] for observations [N, D] (the mean when deterministic)."""
        ...


@runtime_checkable
class SnapshotEnv(Protocol):
    """A :class:`~amorctl.core.vecenv.VectorEnv` that can save and restore its full state."""

    def get_state(self) -> Snapshot:
        """The env's complete state, RNG included, as arrays plus JSON-ready metadata."""
        ...

    def set_state(self, state: Snapshot) -> None:
        """Restore :meth:`get_state`; the next ``step`` then equals the one the snapshot was taken before."""
        ...


# ---------------------------------------------------------------------------- inference
@runtime_checkable
class Policy(Protocol):
    """A trained policy, frozen, for inference (pareto, evaluate, tune, hlp, deploy).

    Observations are raw (unnormalized) ``[N, D]`` float32 whose last m entries are the weights
    ``w`` (see ``observation_layout``); the policy normalizes them itself.
    """

    objectives: tuple[str, ...]  # the m objective names, in reward order
    obs_dim: int  # D
    action_dim: int  # A

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions (the Gaussian mean) [N, A] float32."""
        ...

    def values(self, obs: np.ndarray) -> np.ndarray:
        """Critic values V(s, c, w) [N, m] float32 (one per objective, unscalarized)."""
        ...

    @property
    def observation_layout(self) -> Mapping[str, tuple[int, int]]:
        """Named slices of the observation as ``(start, stop)``: at least ``"weights"`` (the last m
        entries); tracking policies also ``"proprio"``, ``"targets"``, ``"context"``..."""
        ...

    def export_arrays(self) -> Snapshot:
        """The inference parameters as arrays + metadata (actor, critic, normalizer), backend-neutral
        names documented by the backend: what ``deploy export`` bakes into ONNX."""
        ...


@runtime_checkable
class Teacher(Protocol):
    """Per-clip teacher policies for distillation: the Gaussian action of the teacher of each
    sample's clip (docs/distill.md)."""

    def __call__(self, obs: np.ndarray, clips: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw observations [B, D] and the clip index of each [B] (into the env's clips) ->
        (action mean [B, A], action log std [B, A]), float32."""
        ...

    def fingerprint(self) -> list[str]:
        """One string per teacher naming its run and checkpoint: a resumed student checks it."""
        ...


# ---------------------------------------------------------------------------- backends
@runtime_checkable
class Backend(Protocol):
    """What a backend plugin provides (``BackendSpec.make()`` returns one)."""

    name: str

    def make_env(
        self,
        *,
        character: str,
        dataset: str | None = None,
        objective_set: str = "tracking7",
        num_envs: int = 256,
        episode_seconds: float = 10.0,
        seed: int = 0,
        **options: Any,
    ) -> VectorEnv:
        """A batched motion-tracking :class:`~amorctl.core.vecenv.VectorEnv` whose
        ``tracking_view()`` returns a :class:`TrackingView`."""
        ...

    def make_trainer(self, env: VectorEnv, config: TrainConfig) -> Trainer:
        """A :class:`Trainer` for ``env`` with the config's network and PPO settings."""
        ...

    def load_policy(self, trainer_state: Snapshot, config: TrainConfig) -> Policy:
        """The :class:`Policy` of a checkpoint's trainer snapshot (inference only)."""
        ...


# ---------------------------------------------------------------------------- objectives
class ObjectiveSet(Protocol):
    """What ``ObjectiveSetSpec.make(character)`` returns for the tracking environment.

    ``names``/``descriptions`` index the m objectives; ``low``/``high`` [m] bound one step's
    reward; calling it returns r [N, m] (weights are never applied here). Optional:
    ``alive_bonus``, the bonus it adds to every objective on each step that does not terminate
    (0 when absent), read through :func:`survival_bonus_of`; a tracking env publishes it as
    ``reward_space.survival_bonus``.
    """

    names: tuple[str, ...]
    descriptions: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray

    def __call__(self, inputs: TrackingInputs, alive: Any, xp: Any = np) -> Any:
        """r [N, m] for one transition; ``alive`` [N] is 1.0 where the step did not terminate."""
        ...


# ---------------------------------------------------------------------------- tracking view
@runtime_checkable
class TrackingView(Protocol):
    """The read-only view of a batched motion-tracking env that analysis needs.

    Get it with :func:`tracking_view` (works through wrappers). Arrays are numpy copies; frame
    indices index the env's motion library (all clips concatenated, F frames).
    """

    character: CharacterSpec
    dt: float  # seconds per control step
    max_episode_steps: int
    num_envs: int
    fall_drop: float  # m: terminated when the root is this far below the reference's root
    future_frames: tuple[int, ...]  # extra reference frames in the observation (offsets, control steps)

    @property
    def model(self) -> mujoco.MjModel:
        """The compiled MuJoCo model of one character (rendering, forward kinematics)."""
        ...

    @property
    def clip_names(self) -> tuple[str, ...]:
        """The C clip names of the motion library, in library order."""
        ...

    @property
    def clip_seconds(self) -> np.ndarray:
        """[C] float64, each clip's duration in seconds."""
        ...

    @property
    def clip_frame_counts(self) -> np.ndarray:
        """[C] int, frames per clip."""
        ...

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The J actuated joint names, in action order."""
        ...

    @property
    def weights(self) -> np.ndarray:
        """[N, m] float32, the weights of each env's current episode."""
        ...

    @property
    def observation_layout(self) -> Mapping[str, tuple[int, int]]:
        """Named ``(start, stop)`` slices of the observation (``proprio`` is a frame vector)."""
        ...

    def clip_index(self) -> np.ndarray:
        """[N] int, the clip each env tracks now."""
        ...

    def reference_index(self) -> np.ndarray:
        """[N] int, the library frame the current simulator state should match."""
        ...

    def reference_frames(self, frames: np.ndarray) -> np.ndarray:
        """[..., Df] frame vectors (heading frame, :mod:`amorctl.core.frame_layout`) of library frames."""
        ...

    def reference_joint_pos(self, frames: np.ndarray) -> np.ndarray:
        """[..., J] reference joint angles (rad) of library frames."""
        ...

    def reference_qpos(self, frames: np.ndarray) -> np.ndarray:
        """[T, nq] the reference poses of library ``frames`` [T] as simulator qpos."""
        ...

    def qpos(self) -> np.ndarray:
        """[N, nq] float64, the simulator positions now."""
        ...

    def joint_pos(self) -> np.ndarray:
        """[N, J] joint angles now (rad)."""
        ...

    def joint_vel(self) -> np.ndarray:
        """[N, J] joint velocities now (rad/s)."""
        ...

    def end_effector_pos(self) -> np.ndarray:
        """[N, E, 3] end-effector positions relative to the root, in its heading frame (m)."""
        ...

    def select_clips(
        self,
        clips: Sequence[int] | None = None,
        env_clips: np.ndarray | None = None,
        from_start: bool = False,
    ) -> None:
        """Restrict which clips episodes draw (``clips``), or pin one clip per env (``env_clips``
        [N]); ``from_start`` starts episodes at the clip's first frame instead of a random one.
        Takes effect at the next reset."""
        ...


def tracking_view(env: Any) -> TrackingView | None:
    """The :class:`TrackingView` of ``env`` (through wrappers), or None for envs without motions."""
    view = getattr(env, "tracking_view", None)
    return view() if callable(view) else None


def trainer_world_size(trainer: Any) -> int:
    """The processes ``trainer`` trains across (:class:`Trainer`'s optional ``world_size``; 1)."""
    return int(getattr(trainer, "world_size", 1))


def survival_bonus_of(objectives: Any) -> float:
    """The survival bonus an :class:`ObjectiveSet` adds to every objective (its optional
    ``alive_bonus``; 0.0 when it declares none)."""
    return float(getattr(objectives, "alive_bonus", 0.0))
