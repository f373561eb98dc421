"""Wrappers around any :class:`~amorctl.core.vecenv.VectorEnv`."""

from __future__ import annotations

from typing import Any

import numpy as np

from amorctl.core.contracts import tracking_view
from amorctl.core.env_random import Seed
from amorctl.core.errors import AmorError
from amorctl.core.vecenv import VectorEnv
from amorctl.core.weights import check_simplex_rows


class FixedWeights:
    """Run any env with weights the caller chooses instead of the env's Dirichlet draws.

    ``fixed`` is one weight vector ``[m]`` for every env (plain PPO, evaluation) or one per env
    ``[N, m]`` (a Pareto sweep: one ``w`` per environment). :meth:`set_weights` changes them at
    any time (weight schedules, live tuning): the next observation carries the new weights. The
    last m observation entries (also in ``info["final_obs"]``) and :attr:`weights` report them.
    Rewards stay vectors; the trainer scalarizes them with these weights. Everything else
    (``get_state``, ``reward_space``, ...) is the wrapped env's.
    """

    def __init__(self, env: VectorEnv, fixed: np.ndarray) -> None:
        self.env = env
        self._tiled = np.zeros((env.num_envs, len(env.reward_space.names)), dtype=np.float32)
        self.set_weights(fixed)

    @property
    def fixed(self) -> np.ndarray:
        """[N, m] float32: the weights in force."""
        return self._tiled.copy()

    def set_weights(self, weights: np.ndarray) -> None:
        """Use ``weights`` ([m] for all envs, or [N, m]) from the next observation on.

        Raises:
            AmorError: wrong shape, or a row that is not on the simplex.
        """
        n, m = self._tiled.shape
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim == 1:
            w = np.broadcast_to(w, (n, w.shape[0]))
        if w.shape != (n, m):
            raise AmorError(f"weights have shape {tuple(np.shape(weights))}; expected ({m},) or ({n}, {m})")
        check_simplex_rows(w)
        self._tiled[:] = w

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def tracking_view(self) -> Any:
        """The wrapped env's :class:`~amorctl.core.contracts.TrackingView` reporting these weights
        (None when the wrapped env has none)."""
        view = tracking_view(self.env)
        return None if view is None else _WeightsOf(view, self)

    @property
    def weights(self) -> np.ndarray:
        """[N, m] float32: ``fixed`` in every row."""
        return self._tiled.copy()

    def _patch(self, obs: np.ndarray) -> np.ndarray:
        obs = np.array(obs, dtype=np.float32, copy=True)
        obs[:, -self._tiled.shape[1] :] = self._tiled
        return obs

    def reset(self, seed: Seed = None) -> tuple[np.ndarray, dict[str, Any]]:
        """The wrapped env's reset (``seed``: one int, or [N] ints, one per env) with these weights."""
        obs, info = self.env.reset(seed=seed)
        return self._patch(obs), info

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        obs, rewards, terminated, truncated, info = self.env.step(actions)
        info = dict(info)
        info["final_obs"] = self._patch(info["final_obs"])
        return self._patch(obs), rewards, terminated, truncated, info


class _WeightsOf:
    """A :class:`~amorctl.core.contracts.TrackingView` whose ``weights`` are a wrapper's."""

    def __init__(self, view: Any, wrapper: FixedWeights) -> None:
        self._view = view
        self._wrapper = wrapper

    def __getattr__(self, name: str) -> Any:
        return getattr(self._view, name)

    @property
    def weights(self) -> np.ndarray:
        """[N, m] float32, the wrapper's weights in force."""
        return self._wrapper.weights
