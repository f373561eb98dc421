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
    batched_steps: int = 0

    @property
    def num_steps(self) -> int:
        """T, the recorded steps (0 without ``record_steps``; see ``batched_steps``)."""
        return int(self.valid.shape[0])


def tracking_env(env: Any) -> Any | None:
    """The :class:`~amorctl.envs.tracking_env.TrackingEnv` inside ``env`` (through wrappers), or None."""
    from amorctl.envs.tracking_env import TrackingEnv

    seen = 0
    while env is not None and seen < 16:
        if isinstance(env, TrackingEnv):
            return env
        env = env.__dict__.get("env")
        seen += 1
    return None


def env_motion_names(env: Any) -> np.ndarray | None:
    """[N] object array: the clip name each env of a tracking env tracks now (None otherwise)."""
    inner = tracking_env(env)
    if inner is None:
        return None
    names = np.array([c.name for c in inner.library.clips], dtype=object)
    return names[inner.clip_id]


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
    seed: int | None = 0,
    max_steps: int | None = None,
    record_steps: bool = True,
    record_qpos: bool = False,
    on_step: Callable[[int, int], None] | None = None,
) -> Rollout:
    """Run ``policy`` deterministically on ``env`` with per-env weights until every env has
    completed ``episodes`` episodes.

    Args:
        policy: ``policy(obs [N, D]) -> actions [N, A]`` (deterministic, e.g. from
            :func:`amorctl.train.loop.load_policy`).
        env: any :class:`VectorEnv` (wrapped in :class:`FixedWeights` here unless it already is).
        weights: ``[m]`` for every env, ``[N, m]`` one per env, a callable ``t [N] -> [N, m]``
            (t: seconds since each env's episode began), or a :class:`Schedule` (evaluated per
            env at its episode time and, for tracking envs, for its current motion).
        episodes: complete episodes per env (>= 1).
        seed: passed to ``env.reset``.
        max_steps: safety cap on control steps (default: ``episodes`` times the env's time limit
            plus one, or 100 000 when the env has none); episodes unfinished then are dropped.
        record_steps: keep the per-step arrays (memory T * N * ...); per-episode results are
            always kept.
        record_qpos: also keep the simulator's qpos per step (tracking envs; for videos).
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
    inner = tracking_env(env)
    dt = float(inner.dt) if inner is not None else float(getattr(env, "dt", 0.02))
    limit = getattr(inner if inner is not None else env, "max_episode_steps", None)
    if limit is None:
        limit = getattr(env, "max_steps", None)
    cap = max_steps if max_steps is not None else (episodes * int(limit) + 1 if limit else 100_000)

    obs, _ = wrapped.reset(seed=seed)
    t_env = np.zeros(n, dtype=np.int64)  # steps since each env's episode began
    ep_count = np.zeros(n, dtype=np.int64)
    ep_return = np.zeros((n, m))
    ep_len = np.zeros(n, dtype=np.int64)
    ep_rows: list[tuple[np.ndarray, ...]] = []
    steps: dict[str, list[np.ndarray]] = {}
    valid_l: list[np.ndarray] = []
    slot_l: list[np.ndarray] = []  # per step [N]: env * episodes + episode number, -1 if inactive

    if inner is not None and record_steps:
        jn, ne = inner.num_joints, inner.num_ee
        proprio = inner.obs_layout["proprio"]

    w = np.asarray(weights_at(t_env * dt), dtype=np.float64)
    wrapped.set_weights(w)
    step = 0
    while step < cap and (ep_count < episodes).any():
        if not constant and step > 0:
            w = np.asarray(weights_at(t_env * dt), dtype=np.float64)
            wrapped.set_weights(w)
        w_now = wrapped.weights  # [N, m] float32
        obs = np.array(obs, dtype=np.float32, copy=True)
        obs[:, -m:] = w_now  # the weights in force now (also when they just changed)
        actions = np.asarray(policy(obs), dtype=np.float32)
        frame = None if inner is None else inner.ref_idx + 1
        obs, rewards, terminated, truncated, info = wrapped.step(actions)
        active = ep_count < episodes
        done = (terminated | truncated) & active
        ep_return[active] += rewards[active]
        ep_len[active] += 1
        t_env += 1

        if record_steps:
            steps.setdefault("rewards", []).append(rewards.astype(np.float32))
            steps.setdefault("done", []).append(terminated | truncated)
            steps.setdefault("terminated", []).append(np.asarray(terminated, dtype=bool))
            steps.setdefault("weights", []).append(w_now)
            steps.setdefault("actions", []).append(actions)
            valid_l.append(active.copy())
            slot_l.append(np.where(active, np.arange(n) * episodes + ep_count, -1))
            if inner is not None:
                sim = split_frame(info["final_obs"][:, proprio], jn, ne)
                ref = split_frame(inner.ref_frames[frame], jn, ne)
                steps.setdefault("joint_pos", []).append(np.asarray(sim.joint_pos, dtype=np.float32))
                steps.setdefault("ref_joint_pos", []).append(ref.joint_pos.astype(np.float32))
                steps.setdefault("ee_pos", []).append(np.asarray(sim.ee_pos, dtype=np.float32))
                steps.setdefault("ref_ee_pos", []).append(ref.ee_pos.astype(np.float32))
                steps.setdefault("frame_index", []).append(frame)
                if record_qpos:
                    steps.setdefault("qpos", []).append(inner.sim.qpos.copy())

        ended = np.flatnonzero(done)
        if len(ended):
            ep_rows.append(
                (
                    ended,
                    ep_count[ended].copy(),
                    ep_return[ended].copy(),
                    ep_len[ended].copy(),
                    np.asarray(truncated, dtype=bool)[ended] & ~np.asarray(terminated, dtype=bool)[ended],
                    w_now[ended].copy(),
                )
            )
            ep_count[ended] += 1
            ep_return[ended] = 0.0
            ep_len[ended] = 0
        reset = np.flatnonzero(terminated | truncated)
        t_env[reset] = 0
        step += 1
        if on_step is not None:
            on_step(step, cap)

    eps = _collect_episodes(ep_rows, m)
    valid = np.stack(valid_l) if valid_l else np.zeros((0, n), dtype=bool)
    episode_id = np.full(valid.shape, -1, dtype=np.int64)
    if slot_l:  # map (env, episode number) slots to rows of `eps`; unfinished episodes stay -1
        slots = np.stack(slot_l)
        row_of_slot = np.full(n * episodes + 1, -1, dtype=np.int64)
        row_of_slot[eps.env * episodes + eps.index] = np.arange(eps.count)
        episode_id = row_of_slot[np.where(slots >= 0, slots, n * episodes)]
    out = Rollout(names, dt, eps, valid, episode_id, batched_steps=step)
    for key, seq in steps.items():
        setattr(out, key, np.stack(seq))
    return out


def _collect_episodes(rows: list[tuple[np.ndarray, ...]], m: int) -> Episodes:
    if not rows:
        z = np.zeros(0, dtype=np.int64)
        return Episodes(z, z, np.zeros((0, m)), z, np.zeros(0, dtype=bool), np.zeros((0, m), np.float32))
    cols = [np.concatenate([r[i] for r in rows]) for i in range(6)]
    return Episodes(*cols)
