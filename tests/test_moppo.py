"""MOPPO on the torch-cpu backend: one update lowers its own loss, w reaches both networks, the
policy's behaviour depends on w, and a state_dict round trip continues exactly."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from amorctl.core.config import TrainConfig, override
from amorctl.envs.toy import ToyTradeoffEnv
from amorctl.plugins.backends.torch_cpu import TorchCpuBackend, bf16_supported
from amorctl.plugins.backends.torch_cpu.moppo import MOPPOTrainer

torch.set_num_threads(1)


def tiny_config(**changes: object) -> TrainConfig:
    base = dict(
        env__kind="toy",
        env__num_envs=64,
        env__episode_seconds=0.4,
        network__actor_hidden=[32, 32],
        network__critic_hidden=[32, 32],
        network__init_std=1.0,
        ppo__num_steps=16,
        ppo__num_epochs=4,
        ppo__num_minibatches=2,
        ppo__learning_rate=3e-3,
        ppo__precision="fp32",
        run__tensorboard=False,
    )
    base.update(changes)
    return override(TrainConfig(), **base)


def make_trainer(config: TrainConfig) -> MOPPOTrainer:
    env = ToyTradeoffEnv(config.env.num_envs, max_steps=20, seed=config.run.seed)
    return TorchCpuBackend().make_trainer(env, config)


def test_one_update_decreases_the_loss_on_its_own_batch() -> None:
    trainer = make_trainer(tiny_config(ppo__lr_schedule="fixed"))
    batch, _ = trainer.collect_rollout()
    trainer.compute_returns(batch)
    everything = torch.arange(batch.obs.shape[0])
    with torch.no_grad():
        before, stats = trainer.minibatch_loss(batch, everything)
    assert float(stats["loss/policy"]) == pytest.approx(0.0, abs=1e-6)  # ratio 1 on normalized advantages
    trainer.update(batch)
    with torch.no_grad():
        after, stats_after = trainer.minibatch_loss(batch, everything)
    assert float(after) < float(before) - 0.05
    assert float(stats_after["loss/policy"]) < 0  # the surrogate improved
    assert float(stats_after["loss/value"]) < float(stats["loss/value"])


def test_dirichlet_weights_reach_actor_and_critic_inputs() -> None:
    trainer = make_trainer(tiny_config())
    seen: dict[str, list[torch.Tensor]] = {"actor": [], "critic": []}
    trainer.actor.register_forward_pre_hook(lambda _, args: seen["actor"].append(args[0].detach().clone()))
    trainer.critic.register_forward_pre_hook(lambda _, args: seen["critic"].append(args[0].detach().clone()))
    weights = trainer.env.weights
    obs = trainer.obs.clone()
    trainer._forward(obs)
    norm = trainer.normalizer
    for name in ("actor", "critic"):
        x = seen[name][0]
        raw = x * (torch.sqrt(norm.var) + norm.eps).float() + norm.mean.float()  # undo the normalization
        np.testing.assert_allclose(raw[:, -2:].numpy(), weights, atol=1e-5)
    assert np.allclose(weights.sum(1), 1, atol=1e-6)
    assert weights[:, 0].std() > 0.1  # Dirichlet draws differ between envs
    batch, _ = trainer.collect_rollout()  # and the rollout records each step's episode weights
    np.testing.assert_allclose(batch.weights.numpy(), batch.obs[:, -2:].numpy(), atol=0)


def test_trained_policy_action_sign_flips_with_the_weights() -> None:
    trainer = make_trainer(tiny_config())
    for _ in range(30):
        metrics = trainer.iteration()
    assert metrics["return/scalarized"] > 10  # of at most 20 per 20-step episode
    obs = np.array([[0, 0, 0.5, 1, 0], [0, 0, 0.5, 0, 1], [0, 0, 0.5, 0.5, 0.5]], dtype=np.float32)
    a = trainer.act(obs)[:, 0]
    assert a[0] > 0.5 and a[1] < -0.5, a  # w = (1, 0): act right; w = (0, 1): act left
    assert abs(a[2]) < abs(a[0]) and abs(a[2]) < abs(a[1])


def test_state_dict_round_trip_continues_bit_exactly() -> None:
    config = tiny_config()
    a = make_trainer(config)
    for _ in range(2):
        a.iteration()
    state, env_state = a.state_dict(), a.env.get_state()
    expected = a.iteration()

    b = make_trainer(override(config, run__seed=123))  # different init, noise and env draws
    b.load_state_dict(state)
    b.env.set_state(env_state)
    got = b.iteration()
    for key in ("loss/total", "loss/policy", "loss/value", "kl", "return/scalarized", "learning_rate"):
        assert got[key] == expected[key], key
    for p, q in zip(a.actor.parameters(), b.actor.parameters(), strict=True):
        assert torch.equal(p, q)


@pytest.mark.skipif(not bf16_supported(), reason="no native bf16 on this CPU")
def test_bf16_autocast_keeps_fp32_weights_and_finite_losses() -> None:
    trainer = make_trainer(tiny_config(ppo__precision="bf16"))
    metrics = trainer.iteration()
    assert all(p.dtype == torch.float32 for p in trainer.actor.parameters())
    assert np.isfinite(metrics["loss/total"]) and np.isfinite(metrics["kl"])


def test_moppo_iterates_on_the_tracking_env() -> None:
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.envs.tracking_env import TrackingEnv
    from amorctl.registry import get_registry

    spec = get_registry().character("biped20")
    env = TrackingEnv(
        spec,
        synthetic_library(spec, num_clips=2, seconds=1.0),
        "tracking7",
        num_envs=8,
        max_episode_steps=20,
        action_mode="residual",
        nthread=1,
    )
    config = tiny_config(ppo__num_steps=25, network__init_std=0.1)
    trainer = TorchCpuBackend().make_trainer(env, config)
    metrics = trainer.iteration()
    env.close()
    names = ("up", "lo", "feet", "rbs", "root", "vel", "smooth")
    assert trainer.names == names
    assert all(np.isfinite(metrics[f"reward/{n}"]) for n in names)
    assert np.isfinite(metrics["loss/total"]) and metrics["episodes"] >= 8  # 25 steps > 20-step limit
    assert metrics["env_steps"] == 8 * 25
