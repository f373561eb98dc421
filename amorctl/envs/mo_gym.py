"""Run MOPPO on any Gymnasium-style environment with a vector reward (MO-Gymnasium's API).

:class:`MOGymVectorEnv` turns N copies of a single ``gymnasium.Env`` whose ``step`` returns a
reward vector of shape ``[m]`` and which describes it by a ``reward_space`` Box (as every
MO-Gymnasium env does) into an :class:`~amorctl.core.vecenv.VectorEnv`:

- observations are flattened to float32 and the episode's weights ``w`` are appended;
- each copy draws ``w`` at every episode start from the adapter's own seeded generator,
  ``Dirichlet(1)`` unless a :class:`~amorctl.core.weight_sampling.WeightSampler` says otherwise
  (the ``[weights]`` levers); ``weights`` reports them;
- actions (Box action spaces only: the actor is Gaussian) are clipped to the space's bounds;
- ended episodes reset at once; ``info["final_obs"]`` holds their last observation so that
  truncated episodes (``TimeLimit``) can be bootstrapped.

Copies are stepped in a Python loop, which is fine for benchmark-sized tasks. Objective names come
from the env's ``reward_names`` attribute if it has one, else from :data:`KNOWN_REWARDS`
(MO-Gymnasium documents its reward vectors but does not name them), else ``r0, r1, ...``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from amorctl.core.env_random import Seed, env_random, is_per_env
from amorctl.core.errors import AmorError
from amorctl.core.vecenv import RewardSpace
from amorctl.core.weight_sampling import WeightSampler

#: MO-Gymnasium tasks whose reward vector is documented, by id without version: the objectives'
#: names and the survival bonus added to every objective on every step the agent is alive (the
#: ``[ppo] survival_channel`` lever splits it off)
KNOWN_REWARDS: dict[str, tuple[tuple[str, ...], float]] = {
    # forward velocity, 10 x jump height, -|a|^2, each + healthy_reward (1 per step)
    "mo-hopper": (("forward", "height", "energy"), 1.0),
}


def known_rewards(env_id: str, m: int) -> tuple[tuple[str, ...] | None, float]:
    """(names, survival bonus) of ``env_id``'s m objectives from :data:`KNOWN_REWARDS`;
    (None, 0.0) for an unknown task."""
    names, bonus = KNOWN_REWARDS.get(env_id.rsplit("-v", 1)[0], (None, 0.0))
    return (names, bonus) if names is not None and len(names) == m else (None, 0.0)


class MOGymVectorEnv:
    """N copies of a vector-reward Gymnasium env as a weight-conditioned VectorEnv."""

    def __init__(
        self,
        make_env: Callable[[], Any],
        num_envs: int,
        seed: int = 0,
        reward_names: Sequence[str] | None = None,
        weight_sampler: WeightSampler | None = None,
    ) -> None:
        """Args:
        make_env: builds one ``gymnasium.Env`` (called ``num_envs`` times).
        num_envs: N.
        seed: seeds copy i with ``seed + i`` on the first reset, and the weight draws.
        reward_names: names of the m objectives (default: the env's ``reward_names`` or r0..).
        weight_sampler: how episodes draw ``w`` (default Dirichlet(1); docs/moppo.md, Levers).
        """
        import gymnasium as gym

        self.envs = [make_env() for _ in range(num_envs)]
        first = self.envs[0]
        space = getattr(first.unwrapped, "reward_space", None) or getattr(first, "reward_space", None)
        if space is None or len(getattr(space, "shape", ())) != 1:
            raise AmorError(f"{first}: no vector reward_space of shape (m,); MOPPO needs a vector reward")
        m = int(space.shape[0])
        if not isinstance(first.action_space, gym.spaces.Box):
            raise AmorError(
                f"{first}: action space {first.action_space} is not a Box; the Gaussian actor needs "
                "continuous actions"
            )
        known_names, bonus = known_rewards(first.spec.id if first.spec else "", m)
        names = (
            reward_names
            or getattr(first.unwrapped, "reward_names", None)
            or known_names
            or [f"r{i}" for i in range(m)]
        )
        if len(names) != m:
            raise AmorError(f"{len(names)} reward names for {m} objectives")
        self.reward_space = RewardSpace(
            names=tuple(names),
            descriptions=tuple(
                f"objective {i} of {first.spec.id if first.spec else first}" for i in range(m)
            ),
            low=np.broadcast_to(np.asarray(space.low, dtype=np.float64), (m,)).copy(),
            high=np.broadcast_to(np.asarray(space.high, dtype=np.float64), (m,)).copy(),
            survival_bonus=bonus,
        )
        if weight_sampler is not None and weight_sampler.m != m:
            raise AmorError(
                f"{first.spec.id if first.spec else first}: a weight sampler for "
                f"{weight_sampler.m} objectives, the env has {m}"
            )
        self.weight_sampler = weight_sampler or WeightSampler(m)
        self.num_envs = num_envs
        self.num_objectives = m
        self.base_obs_dim = int(np.prod(first.observation_space.shape))
        self.obs_dim = self.base_obs_dim + m
        self.action_dim = int(np.prod(first.action_space.shape))
        self._low = np.asarray(first.action_space.low, dtype=np.float64).reshape(-1)
        self._high = np.asarray(first.action_space.high, dtype=np.float64).reshape(-1)
        self.seed = seed
        self.rand = env_random(seed, num_envs)
        self._w = np.full((num_envs, m), 1.0 / m, dtype=np.float32)
        self._obs = np.zeros((num_envs, self.base_obs_dim), dtype=np.float32)

    @property
    def weights(self) -> np.ndarray:
        """[N, m] float32: the weights of each copy's current episode."""
        return self._w.copy()

    def _full(self, base: np.ndarray, w: np.ndarray) -> np.ndarray:
        return np.concatenate([base, w], axis=1).astype(np.float32)

    def reset(self, seed: Seed = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every copy (copy i with ``seed + i``, or with ``seed[i]`` given one seed per copy,
        which then also draws its weights from its own generator) and draw new weights."""
        seed = self.seed if seed is None else seed
        self.rand = env_random(seed, self.num_envs)
        per_env = is_per_env(seed)
        seeds = [int(np.asarray(seed)[i]) if per_env else int(seed) + i for i in range(self.num_envs)]  # type: ignore[arg-type]
        for i, env in enumerate(self.envs):
            obs, _ = env.reset(seed=seeds[i])
            self._obs[i] = np.asarray(obs, dtype=np.float32).reshape(-1)
        self._w = self.weight_sampler.draw(self.rand, np.arange(self.num_envs))
        return self._full(self._obs, self._w), {}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every copy with actions [N, A] (clipped to the Box); auto-reset ended episodes."""
        actions = np.clip(
            np.asarray(actions, dtype=np.float64).reshape(self.num_envs, -1), self._low, self._high
        )
        rewards = np.zeros((self.num_envs, self.num_objectives), dtype=np.float32)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        final = self._obs.copy()
        for i, env in enumerate(self.envs):
            shaped = actions[i].reshape(env.action_space.shape).astype(env.action_space.dtype)
            obs, reward, term, trunc, _ = env.step(shaped)
            reward = np.asarray(reward, dtype=np.float32).reshape(-1)
            if reward.shape != (self.num_objectives,):
                raise AmorError(
                    f"{env}: step returned a reward of shape {reward.shape}, "
                    f"expected ({self.num_objectives},)"
                )
            rewards[i] = reward
            final[i] = np.asarray(obs, dtype=np.float32).reshape(-1)
            terminated[i], truncated[i] = bool(term), bool(trunc) and not bool(term)
            if term or trunc:
                obs, _ = env.reset()
            self._obs[i] = np.asarray(obs, dtype=np.float32).reshape(-1)
        final_obs = self._full(final, self._w)
        ended = terminated | truncated
        if ended.any():
            self._w[ended] = self.weight_sampler.draw(self.rand, np.flatnonzero(ended))
        return self._full(self._obs, self._w), rewards, terminated, truncated, {"final_obs": final_obs}

    def close(self) -> None:
        """Close every copy."""
        for env in self.envs:
            env.close()


def make_gym_env(
    env_id: str, num_envs: int, seed: int = 0, weight_sampler: WeightSampler | None = None
) -> MOGymVectorEnv:
    """The adapter over ``env_id``: made with ``mo_gymnasium.make`` when MO-Gymnasium is installed
    and knows the id, else ``gymnasium.make``.

    Raises:
        AmorError: neither knows ``env_id``.
    """
    import gymnasium as gym

    maker: Callable[[], Any] | None = None
    try:
        import mo_gymnasium

        if env_id in gym.registry:
            maker = lambda: mo_gymnasium.make(env_id)  # noqa: E731
    except ImportError:
        pass
    if maker is None:
        if env_id not in gym.registry:
            raise AmorError(
                f"unknown Gymnasium environment {env_id!r} (is its package installed? "
                "MO-Gymnasium tasks need `pip install mo-gymnasium`)"
            )
        maker = lambda: gym.make(env_id)  # noqa: E731
    return MOGymVectorEnv(maker, num_envs, seed=seed, weight_sampler=weight_sampler)
