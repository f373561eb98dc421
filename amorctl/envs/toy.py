"""A two-objective toy :class:`~amorctl.core.vecenv.VectorEnv` whose best action depends on ``w``.

Each step the agent picks one number ``a``. Objective 0 (``right``) rewards ``a`` near ``+1 + s``,
objective 1 (``left``) rewards ``a`` near ``-1 + s``, both as ``exp(-(a - target)^2)``, where
``s`` is a slowly drifting state the agent observes. Under ``w = (1, 0)`` the best action is
about ``+1 + s``, under ``w = (0, 1)`` about ``-1 + s``: a policy that ignores ``w`` cannot do
well on both, so a trained MOPPO policy's action sign visibly flips with ``w``.

Episodes end by a random hazard (terminated, 1% per step, independent of the action) or at the
time limit (truncated). It is fully seeded and snapshotable (:class:`amorctl.core.contracts.SnapshotEnv`),
so runs on it resume bit-exactly; ``reset(seed=[s_0, ...])`` gives every env its own generator
(:mod:`amorctl.core.env_random`). Used by tests and as ``[env] kind = "toy"``.

:class:`ToySmoothEnv` (``[env] kind = "toy-smooth"``) is a second toy task whose objectives are
``track`` and ``smooth`` (an action-rate penalty), for tests of the ``smooth`` trade-off.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from amorctl.core.contracts import Snapshot
from amorctl.core.env_random import BatchRandom, PerEnvRandom, Seed, env_random, restore_random
from amorctl.core.errors import AmorError
from amorctl.core.vecenv import RewardSpace
from amorctl.core.weight_sampling import WeightSampler
from amorctl.core.weights import check_simplex_rows

TOY_REWARD_SPACE = RewardSpace(
    names=("right", "left"),
    descriptions=(
        "exp(-(a - (1 + s))^2): act to the right of s",
        "exp(-(a - (-1 + s))^2): act to the left of s",
    ),
    low=np.zeros(2),
    high=np.ones(2),
)


class _ToyEnv(ABC):
    """What both toy envs share: N copies of a 1-D task whose state is a target ``s`` and one more
    per-env number (``second``), a step counter, the episode weights, and the seeded draws
    (``rand``: one generator for the batch, or one per env after ``reset`` with per-env seeds).

    Subclasses set ``second`` (the attribute name), ``reward_space`` and implement ``_start_task``
    (new target for the envs in a mask) and ``_transition(a) -> rewards [N, 2]``.
    """

    obs_dim = 5
    action_dim = 1
    action_limit = 3.0
    second = "s_prev"

    def _init_common(
        self, num_envs: int, max_steps: int, hazard: float, seed: int, weight_sampler: WeightSampler | None
    ) -> None:
        if weight_sampler is not None and weight_sampler.m != 2:
            raise AmorError(f"toy env: a weight sampler for {weight_sampler.m} objectives, the toy has 2")
        self.weight_sampler = weight_sampler or WeightSampler(2)
        self.num_envs = num_envs
        self.max_steps = max_steps
        self.hazard = hazard
        self.rand: BatchRandom | PerEnvRandom = env_random(seed, num_envs)
        self.all_ids = np.arange(num_envs)
        self.s = np.zeros(num_envs)
        setattr(self, self.second, np.zeros(num_envs))
        self.t = np.zeros(num_envs, dtype=np.int64)
        self._w = np.full((num_envs, 2), 0.5, dtype=np.float32)

    @property
    def weights(self) -> np.ndarray:
        """[N, 2] float32: the weights of each env's current episode."""
        return self._w.copy()

    def _obs(self) -> np.ndarray:
        """[N, 5] float32: s, the second number, t / max_steps, w0, w1."""
        phase = self.t / self.max_steps
        columns = np.stack([self.s, getattr(self, self.second), phase], axis=1)
        return np.concatenate([columns, self._w], axis=1).astype(np.float32)

    def _start(self, mask: np.ndarray) -> None:
        self._start_task(mask)
        self.t[mask] = 0
        self._w[mask] = self.weight_sampler.draw(self.rand, np.flatnonzero(mask))

    def reset(self, seed: Seed = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every env anew, reseeding when ``seed`` is given: one int for the batch's
        generator, or [N] ints, one generator per env."""
        if seed is not None:
            self.rand = env_random(seed, self.num_envs)
        self._start(np.ones(self.num_envs, dtype=bool))
        return self._obs(), {}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Actions [N, 1] (clipped to ±action_limit); rewards [N, 2]; auto-resets ended episodes."""
        lim = self.action_limit
        a = np.clip(np.asarray(actions, dtype=np.float64).reshape(self.num_envs), -lim, lim)
        rewards = self._transition(a).astype(np.float32)
        self.t += 1
        terminated = self.rand.random(self.all_ids) < self.hazard
        truncated = (self.t >= self.max_steps) & ~terminated
        final_obs = self._obs()
        ended = terminated | truncated
        if ended.any():
            self._start(ended)
        return self._obs(), rewards, terminated, truncated, {"final_obs": final_obs}

    def get_state(self) -> Snapshot:
        """Everything the next step depends on: generator state, s, the second number, t, w."""
        arrays = {"s": self.s, self.second: getattr(self, self.second), "t": self.t, "w": self._w}
        meta: dict[str, Any] = {"rng": self.rand.state()}
        if self.weight_sampler.adaptive:
            meta["weight_sampler"] = self.weight_sampler.state()
        return Snapshot({k: v.copy() for k, v in arrays.items()}, meta)

    def set_state(self, state: Snapshot) -> None:
        """Restore :meth:`get_state`; AmorError if a row of weights ``w`` is off the simplex."""
        check_simplex_rows(state.arrays["w"], "env snapshot array 'w'")
        self.rand = restore_random(state.meta["rng"])
        self.s = state.arrays["s"].copy()
        setattr(self, self.second, state.arrays[self.second].copy())
        self.t = state.arrays["t"].copy()
        self._w = state.arrays["w"].copy()
        if self.weight_sampler.adaptive:
            self.weight_sampler.load_state(state.meta["weight_sampler"])

    @abstractmethod
    def _start_task(self, mask: np.ndarray) -> None:
        """Draw new targets (and reset the second number) for the envs where ``mask`` [N] is true."""

    @abstractmethod
    def _transition(self, a: np.ndarray) -> np.ndarray:
        """Rewards [N, 2] of actions ``a`` [N]; advances the targets."""


class ToyTradeoffEnv(_ToyEnv):
    """N copies of the toy task. obs = [s, s_prev, t / max_steps, w0, w1] (obs_dim 5), action_dim 1."""

    reward_space = TOY_REWARD_SPACE
    second = "s_prev"

    def __init__(
        self,
        num_envs: int,
        max_steps: int = 20,
        hazard: float = 0.01,
        seed: int = 0,
        weight_sampler: WeightSampler | None = None,
    ) -> None:
        self._init_common(num_envs, max_steps, hazard, seed, weight_sampler)

    def _start_task(self, mask: np.ndarray) -> None:
        self.s[mask] = self.rand.uniform(np.flatnonzero(mask), -0.5, 0.5)
        self.s_prev[mask] = self.s[mask]

    def _transition(self, a: np.ndarray) -> np.ndarray:
        targets = np.stack([1.0 + self.s, -1.0 + self.s], axis=1)
        rewards = np.exp(-((a[:, None] - targets) ** 2))
        self.s_prev = self.s.copy()
        self.s = np.clip(0.95 * self.s + 0.05 * self.rand.normal(self.all_ids), -1.0, 1.0)
        return rewards


# ---------------------------------------------------------------------------- toy-smooth

TOY_SMOOTH_REWARD_SPACE = RewardSpace(
    names=("track", "smooth"),
    descriptions=(
        "exp(-((a - s) / width)^2): follow the jumping target s",
        "-(a_t - a_{t-1})^2: the action-rate penalty (a_{-1} = 0)",
    ),
    low=np.array([0.0, -16.0]),
    high=np.array([1.0, 0.0]),
)


class ToySmoothEnv(_ToyEnv):
    """N copies of a tracking-versus-smoothness toy task (``[env] kind = "toy-smooth"``).

    Each step the agent picks one number ``a`` (clipped to [-2, 2]). The target ``s`` is a random
    square wave: a level of magnitude U(0.25, 1) that, with probability ``jump`` per step (every
    few steps), jumps across 0 to a fresh level of the other sign. Objective 0 (``track``) is
    ``exp(-((a - s) / width)^2)``, objective 1 (``smooth``) the action-rate penalty
    ``-(a_t - a_{t-1})^2`` (``a_{-1} = 0``), as the tracking objective set's ``smooth`` penalizes
    action changes. Under ``w = (1, 0)`` the best policy follows ``s`` (a large action rate, about
    ``0.5`` per step for ``jump = 0.3``), under ``w = (0, 1)`` it holds still; in between it moves
    part of the way. The observation carries the previous action
    so the policy can be smooth: obs = [s, a_prev, t / max_steps, w0, w1] (obs_dim 5), action_dim 1.

    Episodes end at the time limit (truncated), or by a random hazard (terminated; 0 by default).
    Seeded and snapshotable like :class:`ToyTradeoffEnv`.
    """

    reward_space = TOY_SMOOTH_REWARD_SPACE
    action_limit = 2.0
    second = "a_prev"

    def __init__(
        self,
        num_envs: int,
        max_steps: int = 50,
        jump: float = 0.3,
        width: float = 0.5,
        hazard: float = 0.0,
        seed: int = 0,
        weight_sampler: WeightSampler | None = None,
    ) -> None:
        self.jump = jump
        self.width = width
        self._init_common(num_envs, max_steps, hazard, seed, weight_sampler)

    def _start_task(self, mask: np.ndarray) -> None:
        ids = np.flatnonzero(mask)
        sign = np.where(self.rand.random(ids) < 0.5, -1.0, 1.0)
        self.s[mask] = sign * self.rand.uniform(ids, 0.25, 1.0)
        self.a_prev[mask] = 0.0

    def _transition(self, a: np.ndarray) -> np.ndarray:
        track = np.exp(-(((a - self.s) / self.width) ** 2))
        smooth = -((a - self.a_prev) ** 2)
        self.a_prev = a
        jumps = self.rand.random(self.all_ids) < self.jump
        levels = -np.sign(self.s) * self.rand.uniform(self.all_ids, 0.25, 1.0)  # across 0
        self.s = np.where(jumps, levels, self.s)
        return np.stack([track, smooth], axis=1)
