"""The MO-Gymnasium adapter: any vector-reward Gymnasium env becomes a weight-conditioned VectorEnv."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.wrappers import TimeLimit

from amorctl.core.config import TrainConfig, override
from amorctl.core.errors import AmorError
from amorctl.core.vecenv import VectorEnv
from amorctl.envs.mo_gym import MOGymVectorEnv
from amorctl.plugins.backends.torch_cpu import TorchCpuBackend

torch.set_num_threads(1)


class Reach1D(gym.Env):
    """Move a point on a line: reward 0 = closeness to +1, reward 1 = -|action| (effort)."""

    reward_names = ("reach", "effort")

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-5, 5, (2,), np.float32)
        self.action_space = gym.spaces.Box(-1, 1, (1,), np.float32)
        self.reward_space = gym.spaces.Box(np.array([-np.inf, -1.0], np.float32), np.zeros(2, np.float32))
        self.x = 0.0

    def _obs(self) -> np.ndarray:
        return np.array([self.x, 1.0], dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(-1, 1))
        return self._obs(), {}

    def step(self, action):
        a = float(np.asarray(action).reshape(-1)[0])
        self.x += 0.2 * a
        reward = np.array([-abs(self.x - 1.0), -abs(a)], dtype=np.float32)
        return self._obs(), reward, abs(self.x) > 3.0, False, {}


def make() -> gym.Env:
    return TimeLimit(Reach1D(), max_episode_steps=5)


def test_adapter_follows_the_vector_env_contract() -> None:
    env = MOGymVectorEnv(make, num_envs=4, seed=1)
    assert isinstance(env, VectorEnv)
    assert env.reward_space.names == ("reach", "effort") and env.obs_dim == 4 and env.action_dim == 1
    assert env.reward_space.high.tolist() == [0.0, 0.0]
    obs, _ = env.reset(seed=1)
    w0 = env.weights
    assert obs.shape == (4, 4) and obs.dtype == np.float32
    np.testing.assert_array_equal(obs[:, -2:], w0)
    assert np.allclose(w0.sum(1), 1)
    for t in range(5):
        before = env.weights
        x_before = obs[:, 0].copy()
        obs, r, term, trunc, info = env.step(np.full((4, 1), 5.0))  # clipped to +1
        assert r.shape == (4, 2)
        np.testing.assert_allclose(r[:, 1], -1.0)
        np.testing.assert_allclose(info["final_obs"][:, 0], x_before + 0.2, atol=1e-6)
        np.testing.assert_array_equal(info["final_obs"][:, -2:], before)  # the ended episode's w
        if t < 4:
            assert not (term | trunc).any()
    assert trunc.all() and not term.any()  # TimeLimit at 5 steps -> truncated, bootstrappable
    assert not np.allclose(env.weights, w0)  # new episodes drew new weights
    np.testing.assert_array_equal(obs[:, -2:], env.weights)
    assert np.all(np.abs(obs[:, 0]) <= 1.0)  # reset states, not the final ones


def test_adapter_rejects_scalar_reward_envs() -> None:
    with pytest.raises(AmorError, match="vector reward"):
        MOGymVectorEnv(lambda: gym.make("Pendulum-v1"), num_envs=1)


def test_moppo_trains_on_the_adapter() -> None:
    env = MOGymVectorEnv(make, num_envs=16, seed=0)
    config = override(
        TrainConfig(),
        network__actor_hidden=[16],
        network__critic_hidden=[16],
        ppo__num_steps=10,
        ppo__num_minibatches=2,
        ppo__num_epochs=2,
    )
    trainer = TorchCpuBackend().make_trainer(env, config)
    metrics = [trainer.iteration() for _ in range(3)]
    assert metrics[-1]["env_steps"] == 3 * 16 * 10
    assert all(np.isfinite(m["loss/total"]) for m in metrics)
    assert metrics[-1]["episodes"] >= 16 * 5  # 30 steps of 5-step episodes


def test_known_mo_gymnasium_tasks_name_their_objectives_and_declare_the_survival_bonus() -> None:
    from amorctl.envs.mo_gym import known_rewards

    assert known_rewards("mo-hopper-v5", 3) == (("forward", "height", "energy"), 1.0)
    assert known_rewards("mo-hopper-v4", 3) == (("forward", "height", "energy"), 1.0)
    assert known_rewards("mo-hopper-v5", 2) == (None, 0.0)  # cost_objective=False: 2 objectives
    assert known_rewards("mo-halfcheetah-v5", 2) == (None, 0.0)
    assert known_rewards("", 3) == (None, 0.0)


def test_weight_levers_reach_the_gym_and_toy_envs() -> None:
    """[weights] options draw the gym adapter's and the toy envs' episode weights (corners only
    here), and the default config keeps the paper's Dirichlet(1) draws unchanged."""
    from amorctl.envs.factory import make_env
    from amorctl.envs.toy import ToyTradeoffEnv

    if "AmorctlReach1D-v0" not in gym.registry:
        gym.register("AmorctlReach1D-v0", entry_point=Reach1D, max_episode_steps=5)
    for kind in ("gym", "toy", "toy-smooth"):
        config = override(
            TrainConfig(),
            env__kind=kind,
            env__gym_id="AmorctlReach1D-v0" if kind == "gym" else "",
            env__num_envs=16,
            weights__corner_fraction=1.0,
        )
        env = make_env(config)
        try:
            env.reset(seed=3)
            w = env.weights
            assert np.isin(w, (0.0, 1.0)).all() and np.allclose(w.sum(1), 1), kind  # corners only
            assert len({tuple(row) for row in w.tolist()}) > 1, kind  # not one corner for all
        finally:
            getattr(env, "close", lambda: None)()
    plain = make_env(override(TrainConfig(), env__kind="toy", env__num_envs=16))
    plain.reset(seed=3)
    reference = ToyTradeoffEnv(16, max_steps=plain.max_steps)
    reference.reset(seed=3)
    np.testing.assert_array_equal(plain.weights, reference.weights)
    assert not np.isin(plain.weights, (0.0, 1.0)).all()


def test_adapter_refuses_a_sampler_for_another_number_of_objectives() -> None:
    from amorctl.core.weight_sampling import WeightSampler

    with pytest.raises(AmorError, match="a weight sampler for 3 objectives, the env has 2"):
        MOGymVectorEnv(make, num_envs=2, weight_sampler=WeightSampler(3))
