"""Batched deterministic rollouts of a trained policy with weights chosen per environment.

One call steps N environments together with the policy's deterministic action (the Gaussian
mean), each env with its own weight vector ``w`` that may change over time (a weight schedule,
live tuning), and records what evaluation, Pareto sweeps and tuning need:

- per step (``record_steps=True``): vector rewards (unscaled: the objectives' raw values, never
  multiplied by ``w``), done flags, weights, actions and, for tracking envs, simulated and
  reference joint positions and end-effector positions;
- per episode (always): the cumulative reward vector, the length, and whether the episode
  survived (reached the time limit without falling or diverging).

Every env runs ``episodes`` complete episodes; an env that has finished them keeps being
stepped (the batch moves together) but its further steps are masked out (``valid``) and never
counted. Envs auto-reset (the :class:`~amorctl.core.vecenv.VectorEnv` contract), so an episode ends
exactly at a ``terminated | truncated`` step.

Shapes: T = steps recorded, N = envs, m = objectives, A = action dim, J = actuated joints,
E = end effectors, k = episodes recorded (N * episodes when every env finished).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from amorctl.core.contracts import tracking_view
from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import split_frame
from amorctl.core.schedule import Schedule
from amorctl.core.vecenv import VectorEnv
from amorctl.envs.wrappers import FixedWeights

# t -> weights: t is [N] seconds since each env's episode began; returns [N, m] (or [m]).
WeightsFn = Callable[[np.ndarray], np.ndarray]
WeightsSource = np.ndarray | Sequence[float] | WeightsFn | Schedule


@dataclass
class Episodes:
    """Completed episodes, in the order they ended (ties by env index).

    Attributes:
        env: [k] int, the env each episode ran in.
        index: [k] int, the episode's number within its env (0 .. episodes-1).
        returns: [k, m] float64, cumulative unscaled reward per objective.
        length: [k] int, control steps.
        survived: [k] bool, ended by the time limit (truncated), not by a fall or divergence.
        weights: [k, m] float32, the weights in force at the episode's last step.
    """

    env: np.ndarray
    index: np.ndarray
    returns: np.ndarray
    length: np.ndarray
    survived: np.ndarray
    weights: np.ndarray

    @property
    def count(self) -> int:
        """k, the number of episodes."""
        return int(self.env.shape[0])

    def by_env(self, num_envs: int) -> np.ndarray:
        """Mean return per env over its episodes: [N, m] (NaN for an env with no episode)."""
        m = self.returns.shape[1]
        sums = np.zeros((num_envs, m))
        np.add.at(sums, self.env, self.returns)
        counts = np.bincount(self.env, minlength=num_envs).astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            return sums / counts[:, None]


@dataclass
class Rollout:
    """What :func:`rollout` recorded. Per-step arrays are None when not recorded.

    Attributes:
        objective_names: the m objective names, in reward order.
        dt: seconds per control step.
        episodes: the completed episodes (:class:`Episodes`).
        valid: [T, N] bool, the step belongs to a counted episode.
        episode_id: [T, N] int, row of ``episodes`` the step belongs to (-1 when not valid or
            the episode did not finish).
        rewards: [T, N, m] float32 unscaled vector rewards.
        done: [T, N] bool, the episode ended at this step (terminated or truncated).
        terminated: [T, N] bool, ended by a fall / divergence / terminal state.
        weights: [T, N, m] float32, the weights the policy saw at this step.
        actions: [T, N, A] float32, the policy's actions.
        joint_pos, ref_joint_pos: [T, N, J] float32 radians, simulated / reference joint angles
            after the step (tracking envs only).
        ee_pos, ref_ee_pos: [T, N, E, 3] float32 metres, end-effector positions relative to the
            root in its heading frame, simulated / reference (tracking envs only).
        frame_index: [T, N] int, the library frame the step tracked (tracking envs only).
        qpos: [T, N, nq] float64, simulator state after the step (only with ``record_qpos``;
            for an env that reset in the step, its new episode's first state).
        qpos_joint_pos: [T, N, J] float64, the joint angles of ``qpos`` (only with ``record_qpos``).
        batched_steps: control steps the batch took (T when per-step arrays were recorded).
    """

    objective_names: tuple[str, ...]
    dt: float
    episodes: Episodes
    valid: np.ndarray
    episode_id: np.ndarray
    rewards: np.ndarray | None = None
    done: np.ndarray | None = None
    terminated: np.ndarray | None = None
    weights: np.ndarray | None = None
    actions: np.ndarray | None = None
    joint_pos: np.ndarray | None = None
    ref_joint_pos: np.ndarray | None = None
    ee_pos: np.ndarray | None = None
    ref_ee_pos: np.ndarray | None = None
    frame_index: np.ndarray | None = None
    qpos: np.ndarray | None = None
    qpos_joint_pos: np.ndarray | None = None
    batched_steps: int = 0

    @property
    def num_steps(self) -> int:
        """T, the recorded steps (0 without ``record_steps``; see ``batched_steps``)."""
        return int(self.valid.shape[0])


def env_motion_names(env: Any) -> np.ndarray | None:
    """[N] object array: the clip name each env of a tracking env tracks now (None otherwise)."""
    view = tracking_view(env)
    if view is None:
        return None
    return np.array(view.clip_names, dtype=object)[view.clip_index()]


def schedule_weights(schedule: Schedule, t: np.ndarray, motions: np.ndarray | None) -> np.ndarray:
    """Weights [N, m] of ``schedule`` at episode times ``t`` [N] s, per env's motion name [N] (or None).

    Loops over the distinct motions (a handful), never over envs.
    """
    if motions is None:
        return schedule.weights_at_times(np.asarray(t, dtype=np.float64))
    out = np.empty((t.shape[0], len(schedule.objective_names)))
    for name in np.unique(motions):
        sel = motions == name
        out[sel] = schedule.weights_at_times(np.asarray(t[sel], dtype=np.float64), str(name))
    return out


def _weights_fn(source: WeightsSource, env: Any, n: int, m: int) -> tuple[WeightsFn, bool]:
    """A function t [N] -> [N, m] for any weight source, and whether it is constant in time."""
    if isinstance(source, Schedule):
        if tuple(source.objective_names) != tuple(env.reward_space.names):
            raise AmorError(
                f"schedule {source.source} is for objectives {list(source.objective_names)}, "
                f"the policy has {list(env.reward_space.names)}"
            )
        return (lambda t: schedule_weights(source, t, env_motion_names(env))), False
    if callable(source):
        return source, False
    w = np.asarray(source, dtype=np.float64)
    if w.ndim == 1:
        w = np.broadcast_to(w, (n, w.shape[0]))
    if w.shape != (n, m):
        raise AmorError(f"weights have shape {np.shape(source)}; expected ({m},) or ({n}, {m})")
    fixed = np.array(w)
    return (lambda t: fixed), True


def rollout(
    policy: Callable[[np.ndarray], np.ndarray],
    env: VectorEnv,
    weights: WeightsSource,
    *,
    episodes: int = 1,
    seed: int | Sequence[int] | np.ndarray | None = 0,
    max_steps: int | None = None,
    record_steps: bool = True,
    record_qpos: bool = False,
    on_step: Callable[[int, int], None] | None = None,
) -> Rollout:
    """Run ``policy`` deterministically on ``env`` with per-env weights until every env has
    completed ``episodes`` episodes.

    Args:
        policy: ``policy(obs [N, D]) -> actions [N, A]`` (deterministic, e.g. a
            :class:`~amorctl.core.contracts.Policy`).
        env: any :class:`VectorEnv` (wrapped in :class:`FixedWeights` here unless it already is);
            tracking envs are read through their :class:`~amorctl.core.contracts.TrackingView`.
        weights: ``[m]`` for every env, ``[N, m]`` one per env, a callable ``t [N] -> [N, m]``
            (t: seconds since each env's episode began), or a :class:`Schedule` (evaluated per
            env at its episode time and, for tracking envs, for its current motion).
        episodes: complete episodes per env (>= 1).
        seed: passed to ``env.reset``: one int for the batch, or [N] ints, one per env
            (each env's episodes then independent of the batch layout).
        max_steps: safety cap on control steps (default: ``episodes`` times the env's time limit
            plus one, or 100 000 when the env has none); episodes unfinished then are dropped.
        record_steps: keep the per-step arrays (memory T * N * ...); per-episode results are
            always kept.
        record_qpos: also keep the simulator's qpos and joint angles per step (tracking envs; for
            videos and tuning logs).
        on_step: called with (steps done, steps cap) after every step (progress bars).

    Returns:
        :class:`Rollout`.

    Raises:
        AmorError: ``episodes < 1``, weights of the wrong shape or off the simplex, or a schedule
            for other objectives.
    """
    if episodes < 1:
        raise AmorError(f"episodes must be >= 1, got {episodes}")
    n = env.num_envs
    names = tuple(env.reward_space.names)
    m = len(names)
    wrapped = env if isinstance(env, FixedWeights) else FixedWeights(env, np.full(m, 1.0 / m))
    weights_at, constant = _weights_fn(weights, wrapped, n, m)
    view = tracking_view(env)
    dt, cap = _timing(env, view, episodes, max_steps)
    rec = _Recorder(n, m, episodes, view if record_steps else None, record_qpos)

    obs, _ = wrapped.reset(seed=seed)
    t_env = np.zeros(n, dtype=np.int64)  # steps since each env's episode began
    wrapped.set_weights(np.asarray(weights_at(t_env * dt), dtype=np.float64))
    step = 0
    while step < cap and rec.running():
        if not constant and step > 0:
            wrapped.set_weights(np.asarray(weights_at(t_env * dt), dtype=np.float64))
        w_now = wrapped.weights  # [N, m] float32
        obs = np.array(obs, dtype=np.float32, copy=True)
        obs[:, -m:] = w_now  # the weights in force now (also when they just changed)
        actions = np.asarray(policy(obs), dtype=np.float32)
        frame = None if view is None else view.reference_index() + 1
        obs, rewards, terminated, truncated, info = wrapped.step(actions)
        terminated = np.asarray(terminated, dtype=bool)
        truncated = np.asarray(truncated, dtype=bool)
        if record_steps:
            rec.record_step(rewards, terminated, truncated, w_now, actions, info["final_obs"], frame)
        rec.count(rewards, terminated, truncated, w_now)
        t_env += 1
        t_env[terminated | truncated] = 0
        step += 1
        if on_step is not None:
            on_step(step, cap)
    return rec.result(names, dt, step)


def _timing(env: Any, view: Any, episodes: int, max_steps: int | None) -> tuple[float, int]:
    """(seconds per control step, step cap) of a rollout on ``env``."""
    dt = float(view.dt) if view is not None else float(getattr(env, "dt", 0.02))
    limit = view.max_episode_steps if view is not None else getattr(env, "max_episode_steps", None)
    if limit is None:
        limit = getattr(env, "max_steps", None)
    cap = max_steps if max_steps is not None else (episodes * int(limit) + 1 if limit else 100_000)
    return dt, cap


class _Recorder:
    """Accumulates a rollout: the episodes as they end and, optionally, the per-step arrays.

    Args:
        n, m: envs and objectives.
        episodes: episodes each env runs.
        view: the tracking env's view when its per-step tracking arrays are recorded, else None.
        record_qpos: also record qpos and joint angles (needs ``view``).
    """

    def __init__(self, n: int, m: int, episodes: int, view: Any, record_qpos: bool) -> None:
        self.n, self.m, self.episodes = n, m, episodes
        self.view, self.record_qpos = view, record_qpos
        self.ep_count = np.zeros(n, dtype=np.int64)
        self.ep_return = np.zeros((n, m))
        self.ep_len = np.zeros(n, dtype=np.int64)
        self.ep_rows: list[tuple[np.ndarray, ...]] = []
        self.steps: dict[str, list[np.ndarray]] = {}
        self.valid: list[np.ndarray] = []
        self.slots: list[np.ndarray] = []  # per step [N]: env * episodes + episode number, -1 if inactive
        if view is not None:
            self.joints, self.effectors = len(view.joint_names), len(view.character.end_effectors)
            self.proprio = slice(*view.observation_layout["proprio"])

    def running(self) -> bool:
        """Whether some env has episodes left to run."""
        return bool((self.ep_count < self.episodes).any())

    def _add(self, key: str, value: np.ndarray) -> None:
        self.steps.setdefault(key, []).append(value)

    def record_step(
        self,
        rewards: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
        w_now: np.ndarray,
        actions: np.ndarray,
        final_obs: np.ndarray,
        frame: np.ndarray | None,
    ) -> None:
        """Keep one step's per-step arrays (before :meth:`count` advances the episode counters)."""
        active = self.ep_count < self.episodes
        self._add("rewards", rewards.astype(np.float32))
        self._add("done", terminated | truncated)
        self._add("terminated", terminated)
        self._add("weights", w_now)
        self._add("actions", actions)
        self.valid.append(active.copy())
        self.slots.append(np.where(active, np.arange(self.n) * self.episodes + self.ep_count, -1))
        view = self.view
        if view is None or frame is None:
            return
        jn, ne = self.joints, self.effectors
        sim = split_frame(final_obs[:, self.proprio], jn, ne)
        ref = split_frame(view.reference_frames(frame), jn, ne)
        self._add("joint_pos", np.asarray(sim.joint_pos, dtype=np.float32))
        self._add("ref_joint_pos", ref.joint_pos.astype(np.float32))
        self._add("ee_pos", np.asarray(sim.ee_pos, dtype=np.float32))
        self._add("ref_ee_pos", ref.ee_pos.astype(np.float32))
        self._add("frame_index", frame)
        if self.record_qpos:
            self._add("qpos", view.qpos())
            self._add("qpos_joint_pos", view.joint_pos())

    def count(
        self, rewards: np.ndarray, terminated: np.ndarray, truncated: np.ndarray, w_now: np.ndarray
    ) -> None:
        """Add one step's rewards to the running episodes and close those that ended."""
        active = self.ep_count < self.episodes
        done = (terminated | truncated) & active
        self.ep_return[active] += rewards[active]
        self.ep_len[active] += 1
        ended = np.flatnonzero(done)
        if len(ended):
            self.ep_rows.append(
                (
                    ended,
                    self.ep_count[ended].copy(),
                    self.ep_return[ended].copy(),
                    self.ep_len[ended].copy(),
                    truncated[ended] & ~terminated[ended],
                    w_now[ended].copy(),
                )
            )
            self.ep_count[ended] += 1
            self.ep_return[ended] = 0.0
            self.ep_len[ended] = 0

    def result(self, names: tuple[str, ...], dt: float, batched_steps: int) -> Rollout:
        """The :class:`Rollout` of everything recorded."""
        n, episodes = self.n, self.episodes
        eps = _collect_episodes(self.ep_rows, self.m)
        valid = np.stack(self.valid) if self.valid else np.zeros((0, n), dtype=bool)
        episode_id = np.full(valid.shape, -1, dtype=np.int64)
        if self.slots:  # map (env, episode number) slots to rows of `eps`; unfinished episodes stay -1
            slots = np.stack(self.slots)
            row_of_slot = np.full(n * episodes + 1, -1, dtype=np.int64)
            row_of_slot[eps.env * episodes + eps.index] = np.arange(eps.count)
            episode_id = row_of_slot[np.where(slots >= 0, slots, n * episodes)]
        out = Rollout(names, dt, eps, valid, episode_id, batched_steps=batched_steps)
        for key, seq in self.steps.items():
            setattr(out, key, np.stack(seq))
        return out


def _collect_episodes(rows: list[tuple[np.ndarray, ...]], m: int) -> Episodes:
    if not rows:
        z = np.zeros(0, dtype=np.int64)
        return Episodes(z, z, np.zeros((0, m)), z, np.zeros(0, dtype=bool), np.zeros((0, m), np.float32))
    cols = [np.concatenate([r[i] for r in rows]) for i in range(6)]
    return Episodes(*cols)
