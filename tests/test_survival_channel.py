"""``[ppo] survival_channel``: the survival bonus shared by every objective gets its own critic and
advantage channel. The split must not change what the policy gradient means (GAE is linear, the
bonus has weight 1 = Σ w), the main critic must keep predicting whole objective values, and bad
setups must be refused with one clear message."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from amorctl.core.config import TrainConfig, override
from amorctl.core.errors import AmorError
from amorctl.core.gae import gae
from amorctl.core.levers import check_backend_levers
from amorctl.envs.toy import ToyTradeoffEnv
from amorctl.plugins.backends.torch_cpu import TorchCpuBackend
from amorctl.plugins.backends.torch_cpu.survival_channel import (
    channel_values,
    channel_weights,
    objective_values,
    split_rewards,
)
from amorctl.registry import get_registry

torch.set_num_threads(1)

BONUS = 0.7


class ToyWithBonus(ToyTradeoffEnv):
    """The toy env with a survival bonus added to both objectives, as ``tracking7`` adds it."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)
        self.reward_space = dataclasses.replace(
            self.reward_space, high=self.reward_space.high + BONUS, survival_bonus=BONUS
        )

    def step(self, actions: np.ndarray):  # type: ignore[no-untyped-def]
        obs, rewards, terminated, truncated, info = super().step(actions)
        rewards = rewards + np.float32(BONUS) * (~terminated)[:, None].astype(np.float32)
        return obs, rewards, terminated, truncated, info


def config(**changes: object) -> TrainConfig:
    base = dict(
        env__kind="toy",
        env__num_envs=32,
        network__actor_hidden=[16],
        network__critic_hidden=[16],
        ppo__num_steps=16,
        ppo__num_epochs=2,
        ppo__num_minibatches=2,
        ppo__precision="fp32",
        run__tensorboard=False,
    )
    base.update(changes)
    return override(TrainConfig(), **base)


def trainer_with(ppo: dict[str, object], env_cls: type = ToyWithBonus):  # type: ignore[no-untyped-def]
    cfg = config()
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, **ppo))  # past the config check
    env = env_cls(cfg.env.num_envs, max_steps=20, seed=0, hazard=0.1)
    return TorchCpuBackend().make_trainer(env, cfg)


def test_split_and_fold_are_inverse_and_the_bonus_is_zero_on_the_terminating_step() -> None:
    rewards = torch.tensor([[[1.5, 0.2]], [[0.9, -0.3]]])  # [T=2, N=1, m=2], bonus inside
    terminated = torch.tensor([[False], [True]])
    channels = split_rewards(rewards, terminated, bonus=1.0)
    torch.testing.assert_close(channels[..., -1], torch.tensor([[1.0], [0.0]]))
    torch.testing.assert_close(channels[0, 0, :2], torch.tensor([0.5, -0.8]))
    torch.testing.assert_close(objective_values(channels), rewards)
    v, s = torch.randn(5, 3), torch.randn(5, 1)
    torch.testing.assert_close(objective_values(channel_values(v, s)), v)
    w = torch.tensor([[0.25, 0.75, 0.0]])
    torch.testing.assert_close(channel_weights(w), torch.tensor([[0.25, 0.75, 0.0, 1.0]]))
    torch.testing.assert_close(channel_weights(w, 2.5), torch.tensor([[0.25, 0.75, 0.0, 2.5]]))


def test_split_leaves_the_scalarized_advantage_unchanged_without_advantage_scaling() -> None:
    trainer = trainer_with({"survival_channel": True})
    assert trainer.channel_names == ("right", "left", "survival")
    batch, _ = trainer.collect_rollout()
    trainer.compute_returns(batch)
    assert batch.advantages is not None and batch.advantages.shape[-1] == 3
    # GAE on the channels, folded, is GAE on the whole objectives with the whole values
    T, N = batch.terminated.shape
    whole_adv, whole_ret = gae(
        batch.rewards,
        objective_values(batch.values).reshape(T, N, 2),
        objective_values(batch.next_values),
        batch.terminated,
        batch.truncated,
        trainer.cfg.gamma,
        trainer.cfg.gae_lambda,
        xp=torch,
    )
    close = dict(atol=1e-5, rtol=0)
    torch.testing.assert_close(objective_values(batch.advantages), whole_adv.reshape(T * N, 2), **close)
    torch.testing.assert_close(objective_values(batch.returns), whole_ret.reshape(T * N, 2), **close)
    idx = torch.arange(T * N)
    scalar = (whole_adv.reshape(T * N, 2) * batch.weights).sum(-1)
    expected = (scalar - scalar.mean()) / (scalar.std(correction=0) + 1e-8)
    torch.testing.assert_close(trainer.scalarized_advantage(batch, idx), expected, atol=1e-4, rtol=0)
    # the bonus's channel carries real returns: every step that did not terminate earns BONUS
    alive = (~batch.terminated).float().reshape(-1)
    assert float(batch.returns[:, -1][alive == 0].abs().max()) < float(batch.returns[:, -1].max())


@pytest.mark.parametrize("survival_weight", [1.0, 3.0])
def test_advantage_scaling_scales_the_bonus_apart_from_the_objectives(survival_weight: float) -> None:
    trainer = trainer_with(
        {"survival_channel": True, "return_norm": "value+advantage", "survival_weight": survival_weight}
    )
    batch, _ = trainer.collect_rollout()
    trainer.compute_returns(batch)
    assert trainer.return_scale is not None
    stds = trainer.return_scale.advantage_std()
    assert stds.shape == (3,)
    idx = torch.arange(batch.obs.shape[0])
    raw = (batch.advantages / stds * channel_weights(batch.weights, survival_weight)).sum(-1)
    expected = (raw - raw.mean()) / (raw.std(correction=0) + 1e-8)
    torch.testing.assert_close(trainer.scalarized_advantage(batch, idx), expected)
    metrics = trainer.iteration()
    assert np.isfinite(metrics["explained_variance/survival"])
    assert metrics["return_scale/advantage_std/survival"] > 0
    assert {"explained_variance/right", "explained_variance/left"} <= set(metrics)


def test_the_main_critic_still_predicts_whole_objective_values() -> None:
    trainer = trainer_with({"survival_channel": True})
    for _ in range(3):
        trainer.iteration()
    obs = trainer.obs[:8]
    with torch.no_grad():
        x = trainer.normalizer(obs)
        whole = trainer.critic(x)
    np.testing.assert_allclose(trainer.values(obs.numpy()), whole.numpy(), atol=1e-6)
    # and the survival critic's prediction is part of the checkpointed training state
    arrays = trainer.state_dict().arrays
    assert any(k.startswith("survival_critic.") for k in arrays)
    assert not any(k.startswith("critic.") and "survival" in k for k in arrays)


def test_survival_channel_is_refused_without_a_shared_bonus_or_off_torch_cpu() -> None:
    with pytest.raises(AmorError, match=r"survival_channel = true needs objectives that share a survival"):
        trainer_with({"survival_channel": True}, env_cls=ToyTradeoffEnv)
    with pytest.raises(AmorError, match=r"\[ppo\] survival_channel = true needs objectives that share"):
        config(ppo__survival_channel=True)  # the toy env
    with pytest.raises(AmorError, match=r"survival_channel = true needs a backend that implements it; run.b"):
        check_backend_levers(
            config(env__kind="tracking", run__backend="jax-mjx", ppo__survival_channel=True),
            get_registry().backend("jax-mjx").levers,
        )
    with pytest.raises(AmorError, match=r"\[ppo\] survival_weight = 2 needs survival_channel = true"):
        config(env__kind="tracking", ppo__survival_weight=2.0)
    with pytest.raises(AmorError, match=r"survival_weight"):
        config(env__kind="tracking", ppo__survival_channel=True, ppo__survival_weight=0.0)
