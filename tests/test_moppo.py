"""MOPPO on the torch-cpu backend: one update lowers its own loss, w reaches both networks, the
policy's behaviour depends on w, and a state_dict round trip continues exactly."""

from __future__ import annotations

from pathlib import Path

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


# --- the levers (docs/moppo.md, Levers) ----------------------------------------------------------
def test_return_scale_tracks_per_objective_moments() -> None:
    from amorctl.core.return_scale import RATE
    from amorctl.plugins.backends.torch_cpu.return_scale import ReturnScale

    gen = torch.Generator().manual_seed(0)
    scale = ReturnScale(2, advantage=True)
    batches = [
        (torch.randn(4000, 2, generator=gen) * torch.tensor([50.0, 2.0]) + torch.tensor([100.0, -20.0]),
         torch.randn(4000, 2, generator=gen) * torch.tensor([5.0, 0.5]))
        for _ in range(3)
    ]  # fmt: skip
    for r, a in batches:
        scale.update(r, a)
    # first batch initializes, later ones move by RATE: the same recursion by hand, in float64
    mean, sq, adv_sq = (batches[0][0].double().mean(0), (batches[0][0].double() ** 2).mean(0),
                        (batches[0][1].double() ** 2).mean(0))  # fmt: skip
    for r, a in batches[1:]:
        r, a = r.double(), a.double()
        mean, sq, adv_sq = (x + RATE * (y - x) for x, y in ((mean, r.mean(0)), (sq, (r * r).mean(0)),
                                                              (adv_sq, (a * a).mean(0))))  # fmt: skip
    torch.testing.assert_close(scale.return_std(), torch.sqrt(sq - mean**2).float())
    torch.testing.assert_close(scale.advantage_std(), torch.sqrt(adv_sq).float())
    assert scale.return_std().tolist() == pytest.approx([50.0, 2.0], rel=0.05)
    assert scale.advantage_std().tolist() == pytest.approx([5.0, 0.5], rel=0.05)


def test_value_return_norm_divides_each_objectives_value_error_by_its_std() -> None:
    trainer = make_trainer(tiny_config(ppo__return_norm="value", ppo__clip_value_loss=False))
    batch, _ = trainer.collect_rollout()
    trainer.compute_returns(batch)  # folds this batch into the scale first
    assert trainer.return_scale is not None and trainer.return_scale.updates == 1
    sigma = batch.returns.double().std(0, correction=0).float()
    torch.testing.assert_close(trainer.return_scale.return_std(), sigma)
    idx = torch.arange(batch.obs.shape[0])
    with torch.no_grad():
        _, stats = trainer.minibatch_loss(batch, idx)
        _, values = trainer._forward(batch.obs)
    expected = 0.5 * (((values - batch.returns) / sigma) ** 2).mean()
    assert float(stats["loss/value"]) == pytest.approx(float(expected), rel=1e-5)
    metrics = trainer.iteration()
    assert metrics["return_scale/return_std/left"] > 0 and "return_scale/advantage_std/right" in metrics


def test_advantage_return_norm_equalizes_the_objectives_in_the_scalarized_advantage() -> None:
    off = make_trainer(tiny_config())
    on = make_trainer(tiny_config(ppo__return_norm="value+advantage"))
    batch, _ = off.collect_rollout()
    off.compute_returns(batch)
    batch.advantages = batch.advantages * torch.tensor([100.0, 1.0])  # objective 0 drowns objective 1
    batch.weights = torch.full_like(batch.weights, 0.5)
    on._update_return_scale(batch.returns, batch.advantages)
    rms = torch.sqrt((batch.advantages.double() ** 2).mean(0)).float()
    torch.testing.assert_close(on.return_scale.advantage_std(), rms)
    idx = torch.arange(batch.obs.shape[0])
    a0, a1 = batch.advantages[:, 0], batch.advantages[:, 1]

    def corr(x: torch.Tensor, y: torch.Tensor) -> float:
        return float(torch.corrcoef(torch.stack([x, y]))[0, 1])

    # without scaling the policy sees objective 0 only; with it both objectives count alike
    assert corr(off.scalarized_advantage(batch, idx), a0) > 0.99
    scaled = on.scalarized_advantage(batch, idx)
    assert abs(corr(scaled, a0 / rms[0]) - corr(scaled, a1 / rms[1])) < 0.2 * abs(corr(scaled, a1))
    expected = a0 / rms[0] * 0.5 + a1 / rms[1] * 0.5
    torch.testing.assert_close(scaled, (expected - expected.mean()) / (expected.std(correction=0) + 1e-8))


def test_tracking_run_with_every_lever_resumes_bit_exactly(tmp_path) -> None:
    import csv

    from amorctl.core.config import merge
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.motion.dataset import write_dataset
    from amorctl.registry import get_registry
    from amorctl.train.checkpoint import list_checkpoints, load_checkpoint
    from amorctl.train.loop import train_run

    lib = synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=0.3, seed=3)
    write_dataset(tmp_path / "ds.mcap", lib)
    config = merge(
        TrainConfig(),
        {
            "run": {"iterations": 3, "checkpoint_every": 10, "tensorboard": False, "threads": 1},
            "env": {"kind": "tracking", "character": "biped20", "dataset": str(tmp_path / "ds.mcap"),
                    "num_envs": 4, "episode_seconds": 0.06},
            "network": {"actor_hidden": [16], "critic_hidden": [16]},
            "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 1, "return_norm": "value+advantage",
                    "survival_channel": True},
            "weights": {"alpha": 0.5, "corner_fraction": 0.2, "edge_fraction": 0.1, "axis_fraction": 0.2,
                        "adaptive_fraction": 0.3},
        },
        "levers test",
    )  # fmt: skip
    full = train_run(config, tmp_path / "full")
    assert train_run(config, tmp_path / "part", stop_after=1).interrupted
    ckpt = load_checkpoint(list_checkpoints(tmp_path / "part" / "checkpoints")[-1][1])
    assert ckpt.env is not None and sum(ckpt.env.meta["weight_sampler"]["count"]) > 0  # episodes fed back
    assert "return_scale.ret_mean" in ckpt.trainer.arrays and "feedback.start_value" in ckpt.trainer.arrays
    assert "survival_critic.net.0.weight" in ckpt.trainer.arrays
    resumed = train_run(config, tmp_path / "part", resume=True)
    assert (full.end_iteration, resumed.start_iteration, resumed.end_iteration) == (3, 1, 3)

    def rows(out):
        with (out / "metrics.csv").open(newline="", encoding="utf-8") as f:
            return list(csv.DictReader(f))

    a, b = rows(tmp_path / "full"), rows(tmp_path / "part")
    keys = [k for k in a[-1] if k.startswith(("loss/", "return", "weights/", "explained_variance/"))]
    assert "weights/anchor_entropy" in keys and "return_scale/return_std/smooth" in keys
    assert "explained_variance/survival" in keys
    for ra, rb in zip(a, b, strict=True):
        for key in keys:
            assert ra[key] == rb[key], (ra["iteration"], key)
    end_a = load_checkpoint(list_checkpoints(tmp_path / "full" / "checkpoints")[-1][1])
    end_b = load_checkpoint(list_checkpoints(tmp_path / "part" / "checkpoints")[-1][1])
    assert end_a.env.meta["weight_sampler"] == end_b.env.meta["weight_sampler"]
    for key, value in end_a.trainer.arrays.items():
        np.testing.assert_array_equal(value, end_b.trainer.arrays[key], err_msg=key)


def test_toy_run_with_adaptive_weights_resumes_bit_exactly(tmp_path: Path) -> None:
    """The toy env draws w through the [weights] sampler and checkpoints its adaptive state."""
    from amorctl.train.checkpoint import list_checkpoints, load_checkpoint
    from amorctl.train.loop import train_run

    config = tiny_config(
        run__iterations=4,
        run__checkpoint_every=10,
        run__threads=1,
        env__num_envs=8,
        ppo__num_steps=8,
        weights__corner_fraction=0.2,
        weights__adaptive_fraction=0.5,
    )
    train_run(config, tmp_path / "full")
    assert train_run(config, tmp_path / "part", stop_after=2).interrupted
    middle = load_checkpoint(list_checkpoints(tmp_path / "part" / "checkpoints")[-1][1])
    assert middle.env is not None and sum(middle.env.meta["weight_sampler"]["count"]) > 0
    train_run(config, tmp_path / "part", resume=True)
    end_a = load_checkpoint(list_checkpoints(tmp_path / "full" / "checkpoints")[-1][1])
    end_b = load_checkpoint(list_checkpoints(tmp_path / "part" / "checkpoints")[-1][1])
    assert end_a.env.meta["weight_sampler"] == end_b.env.meta["weight_sampler"]
    np.testing.assert_array_equal(end_a.env.arrays["w"], end_b.env.arrays["w"])
    for key, value in end_a.trainer.arrays.items():
        np.testing.assert_array_equal(value, end_b.trainer.arrays[key], err_msg=key)


def test_levers_are_refused_where_they_are_not_implemented(tmp_path: Path) -> None:
    from amorctl.core.errors import AmorError
    from amorctl.core.levers import check_backend_levers, levers_in_use
    from amorctl.registry import get_registry
    from amorctl.train.loop import train_run

    jax_levers = get_registry().backend("jax-mjx").levers
    torch_levers = get_registry().backend("torch-cpu").levers
    config = tiny_config(run__backend="jax-mjx", env__kind="tracking", weights__adaptive_fraction=0.2)
    with pytest.raises(
        AmorError,
        match=r"\[weights\] adaptive_fraction = 0.2 needs a backend that implements it; "
        r"run.backend = 'jax-mjx' does not",
    ):
        check_backend_levers(config, jax_levers)
    with pytest.raises(AmorError, match=r"adaptive_fraction = 0.2 needs a backend"):  # nothing written
        train_run(config, tmp_path / "never")
    assert not (tmp_path / "never").exists()
    check_backend_levers(config, torch_levers)  # torch-cpu declares every lever
    # jax-mjx implements the science preset's levers (return_norm, the weight mixture)
    science = tiny_config(run__backend="jax-mjx", env__kind="tracking", ppo__return_norm="value+advantage",
                          weights__corner_fraction=0.1, weights__axis_fraction=0.3)  # fmt: skip
    assert set(levers_in_use(science)) == {"return_norm", "weight_sampling"}
    check_backend_levers(science, jax_levers)
    # the toy and gym envs draw w themselves: only the tracking env's draws need the backend
    assert levers_in_use(tiny_config(weights__corner_fraction=0.1)) == {}
    tracking = tiny_config(env__kind="tracking", weights__corner_fraction=0.1, weights__adaptive_fraction=0.2)
    assert set(levers_in_use(tracking)) == {"weight_sampling", "adaptive_weights"}
    with pytest.raises(AmorError, match=r"adaptive_fraction needs an env whose state is checkpointed"):
        tiny_config(env__kind="gym", env__gym_id="mo-hopper-v5", weights__adaptive_fraction=0.2)
    with pytest.raises(AmorError, match="exceed 1"):
        tiny_config(env__kind="tracking", weights__corner_fraction=0.6, weights__axis_fraction=0.6)


def test_science_preset_is_quick_plus_the_levers() -> None:
    import dataclasses

    from amorctl.core.config import WeightsConfig, load_preset

    quick, science = load_preset("quick"), load_preset("science")
    assert dataclasses.replace(science, weights=WeightsConfig(), ppo=quick.ppo) == quick
    assert dataclasses.replace(science.ppo, return_norm="off", entropy_coef=0.0) == quick.ppo
    assert (science.ppo.return_norm, science.ppo.entropy_coef) == ("value+advantage", 0.005)
    assert not science.weights.plain and science.ppo.return_norm != "off"


def test_science_sc_preset_is_science_plus_the_survival_channel() -> None:
    import dataclasses

    from amorctl.core.config import load_preset

    science, sc = load_preset("science"), load_preset("science_sc")
    assert sc.ppo.survival_channel and sc.ppo.return_norm == "value+advantage"
    assert dataclasses.replace(sc, ppo=science.ppo) == science
    # science_sc keeps the entropy coefficient it was measured with (0); science has 0.005 since
    assert sc.ppo.entropy_coef == 0.0
    assert dataclasses.replace(sc.ppo, survival_channel=False, entropy_coef=0.005) == science.ppo


@pytest.mark.parametrize("floor", [1e-6, 1e-8])
def test_the_adaptive_learning_rate_stops_at_its_configured_floor(floor: float) -> None:
    """A KL far above ``desired_kl`` divides the rate by 1.5 per minibatch step down to
    ``[ppo] min_learning_rate`` and no further."""
    from amorctl.core.ppo_math import adapt_learning_rate

    trainer = make_trainer(tiny_config(ppo__desired_kl=1e-9, ppo__min_learning_rate=floor))
    trainer.iteration()  # a real update: its KL is far above 2e-9, so each step divides the rate
    assert trainer.learning_rate < 3e-3 / 1.5**7
    for _ in range(60):  # 3e-3 / 1.5**60 is far below either floor
        trainer._adapt_learning_rate(1.0)
    assert trainer.learning_rate == pytest.approx(floor)
    assert trainer.optimizer.param_groups[0]["lr"] == pytest.approx(floor)
    assert adapt_learning_rate(1.2e-8, 1.0, 0.02, lr_min=1e-8) == pytest.approx(1e-8)
    assert adapt_learning_rate(1.2e-8, 1.0, 0.02) == pytest.approx(1e-6)  # rsl_rl's floor by default
