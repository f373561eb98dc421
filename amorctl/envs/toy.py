"""A two-objective toy :class:`~amorctl.vecenv.VectorEnv` whose best action depends on ``w``.

Each step the agent picks one number ``a``. Objective 0 (``right``) rewards ``a`` near ``+1 + s``,
objective 1 (``left``) rewards ``a`` near ``-1 + s``, both as ``exp(-(a - target)^2)``, where
``s`` is a slowly drifting state the agent observes. Under ``w = (1, 0)`` the best action is
about ``+1 + s``, under ``w = (0, 1)`` about ``-1 + s``: a policy that ignores ``w`` cannot do
well on both, so a trained MOPPO policy's action sign visibly flips with ``w``.

Episodes end by a random hazard (terminated, 1% per step, independent of the action) or at the
time limit (truncated). It is fully seeded and snapshotable (:class:`amorctl.trainer.SnapshotEnv`),
so runs on it resume bit-exactly. Used by tests and as ``[env] kind = "toy"``.

:class:`ToySmoothEnv` (``[env] kind = "toy-smooth"``) is a second toy task whose objectives are
``track`` and ``smooth`` (an action-rate penalty), for tests of the ``smooth`` trade-off.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from amorctl.trainer import State
from amorctl.vecenv import RewardSpace
from amorctl.weights import sample_dirichlet

TOY_REWARD_SPACE = RewardSpace(
    names=("right", "left"),
    descriptions=(
        "exp(-(a - (1 + s))^2): act to the right of s",
        "exp(-(a - (-1 + s))^2): act to the left of s",
    ),
    low=np.zeros(2),
    high=np.ones(2),
)


class ToyTradeoffEnv:
    """N copies of the toy task. obs = [s, s_prev, t / max_steps, w0, w1] (obs_dim 5), action_dim 1."""

    obs_dim = 5
    action_dim = 1
    reward_space = TOY_REWARD_SPACE

    def __init__(self, num_envs: int, max_steps: int = 20, hazard: float = 0.01, seed: int = 0) -> None:
        self.num_envs = num_envs
        self.max_steps = max_steps
        self.hazard = hazard
        self.rng = np.random.default_rng(seed)
        n = num_envs
        self.s = np.zeros(n)
        self.s_prev = np.zeros(n)
        self.t = np.zeros(n, dtype=np.int64)
        self._w = np.full((n, 2), 0.5, dtype=np.float32)

    @property
    def weights(self) -> np.ndarray:
        """[N, 2] float32: the weights of each env's current episode."""
        return self._w.copy()

    def _obs(self) -> np.ndarray:
        phase = self.t / self.max_steps
        return np.concatenate([np.stack([self.s, self.s_prev, phase], axis=1), self._w], axis=1).astype(
            np.float32
        )

    def _start(self, mask: np.ndarray) -> None:
        k = int(mask.sum())
        self.s[mask] = self.rng.uniform(-0.5, 0.5, size=k)
        self.s_prev[mask] = self.s[mask]
        self.t[mask] = 0
        self._w[mask] = sample_dirichlet(self.rng, k, 2)

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every env anew (reseeding the env's generator when ``seed`` is given)."""
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self._start(np.ones(self.num_envs, dtype=bool))
        return self._obs(), {}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Actions [N, 1] (clipped to [-3, 3]); rewards [N, 2]; auto-resets ended episodes."""
        a = np.clip(np.asarray(actions, dtype=np.float64).reshape(self.num_envs), -3.0, 3.0)
        targets = np.stack([1.0 + self.s, -1.0 + self.s], axis=1)
        rewards = np.exp(-((a[:, None] - targets) ** 2)).astype(np.float32)
        self.s_prev = self.s.copy()
        self.s = np.clip(0.95 * self.s + 0.05 * self.rng.normal(size=self.num_envs), -1.0, 1.0)
        self.t += 1
        terminated = self.rng.random(self.num_envs) < self.hazard
        truncated = (self.t >= self.max_steps) & ~terminated
        final_obs = self._obs()
        ended = terminated | truncated
        if ended.any():
            self._start(ended)
        return self._obs(), rewards, terminated, truncated, {"final_obs": final_obs}

    def get_state(self) -> State:
        """Everything the next step depends on: generator state, s, s_prev, t, w."""
        arrays = {"s": self.s.copy(), "s_prev": self.s_prev.copy(), "t": self.t.copy(), "w": self._w.copy()}
        return State(arrays, {"rng": self.rng.bit_generator.state})

    def set_state(self, state: State) -> None:
        """Restore :meth:`get_state`."""
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = state.meta["rng"]
        self.s = state.arrays["s"].copy()
        self.s_prev = state.arrays["s_prev"].copy()
        self.t = state.arrays["t"].copy()
        self._w = state.arrays["w"].copy()


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


class ToySmoothEnv:
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

    obs_dim = 5
    action_dim = 1
    reward_space = TOY_SMOOTH_REWARD_SPACE
    action_limit = 2.0

    def __init__(
        self,
        num_envs: int,
        max_steps: int = 50,
        jump: float = 0.3,
        width: float = 0.5,
        hazard: float = 0.0,
        seed: int = 0,
    ) -> None:
        self.num_envs = num_envs
        self.width = width
        self.max_steps = max_steps
        self.jump = jump
        self.hazard = hazard
        self.rng = np.random.default_rng(seed)
        n = num_envs
        self.s = np.zeros(n)
        self.a_prev = np.zeros(n)
        self.t = np.zeros(n, dtype=np.int64)
        self._w = np.full((n, 2), 0.5, dtype=np.float32)

    @property
    def weights(self) -> np.ndarray:
        """[N, 2] float32: the weights of each env's current episode."""
        return self._w.copy()

    def _obs(self) -> np.ndarray:
        phase = self.t / self.max_steps
        return np.concatenate([np.stack([self.s, self.a_prev, phase], axis=1), self._w], axis=1).astype(
            np.float32
        )

    def _start(self, mask: np.ndarray) -> None:
        k = int(mask.sum())
        sign = np.where(self.rng.random(k) < 0.5, -1.0, 1.0)
        self.s[mask] = sign * self.rng.uniform(0.25, 1.0, size=k)
        self.a_prev[mask] = 0.0
        self.t[mask] = 0
        self._w[mask] = sample_dirichlet(self.rng, k, 2)

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every env anew (reseeding the env's generator when ``seed`` is given)."""
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self._start(np.ones(self.num_envs, dtype=bool))
        return self._obs(), {}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Actions [N, 1] (clipped to [-2, 2]); rewards [N, 2]; auto-resets ended episodes."""
        lim = self.action_limit
        a = np.clip(np.asarray(actions, dtype=np.float64).reshape(self.num_envs), -lim, lim)
        track = np.exp(-(((a - self.s) / self.width) ** 2))
        smooth = -((a - self.a_prev) ** 2)
        rewards = np.stack([track, smooth], axis=1).astype(np.float32)
        self.a_prev = a
        jumps = self.rng.random(self.num_envs) < self.jump
        levels = -np.sign(self.s) * self.rng.uniform(0.25, 1.0, size=self.num_envs)  # across 0
        self.s = np.where(jumps, levels, self.s)
        self.t += 1
        terminated = self.rng.random(self.num_envs) < self.hazard
        truncated = (self.t >= self.max_steps) & ~terminated
        final_obs = self._obs()
        ended = terminated | truncated
        if ended.any():
            self._start(ended)
        return self._obs(), rewards, terminated, truncated, {"final_obs": final_obs}

    def get_state(self) -> State:
        """Everything the next step depends on: generator state, s, a_prev, t, w."""
        arrays = {"s": self.s.copy(), "a_prev": self.a_prev.copy(), "t": self.t.copy(), "w": self._w.copy()}
        return State(arrays, {"rng": self.rng.bit_generator.state})

    def set_state(self, state: State) -> None:
        """Restore :meth:`get_state`."""
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = state.meta["rng"]
        self.s = state.arrays["s"].copy()
        self.a_prev = state.arrays["a_prev"].copy()
        self.t = state.arrays["t"].copy()
        self._w = state.arrays["w"].copy()
