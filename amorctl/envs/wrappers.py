"""Wrappers around any :class:`~amorctl.vecenv.VectorEnv`."""

from __future__ import annotations

from typing import Any

import numpy as np

from amorctl.errors import AmorError
from amorctl.vecenv import VectorEnv


class FixedWeights:
    """Train plain PPO with one weight vector: every episode's ``w`` is replaced by ``fixed``.

    The env's own weight draw is ignored: the last m observation entries (also in
    ``info["final_obs"]``) and :attr:`weights` report ``fixed`` instead. Rewards stay vectors; the
    trainer scalarizes them with ``fixed``. Everything else (``get_state``, ``reward_space``, ...)
    is the wrapped env's.
    """

    def __init__(self, env: VectorEnv, fixed: np.ndarray) -> None:
        m = len(env.reward_space.names)
        fixed = np.asarray(fixed, dtype=np.float32).reshape(-1)
        if fixed.shape != (m,):
            raise AmorError(f"fixed weights have {fixed.shape[0]} entries, the env has {m} objectives")
        self.env = env
        self.fixed = fixed
        self._tiled = np.tile(fixed, (env.num_envs, 1))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    @property
    def weights(self) -> np.ndarray:
        """[N, m] float32: ``fixed`` in every row."""
        return self._tiled.copy()

    def _patch(self, obs: np.ndarray) -> np.ndarray:
        obs = np.array(obs, dtype=np.float32, copy=True)
        obs[:, -self._tiled.shape[1] :] = self._tiled
        return obs

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed)
        return self._patch(obs), info

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        obs, rewards, terminated, truncated, info = self.env.step(actions)
        info = dict(info)
        info["final_obs"] = self._patch(info["final_obs"])
        return self._patch(obs), rewards, terminated, truncated, info
