"""The jax-mjx backend's MOPPO against torch-cpu's on the same batch (GAE, losses, gradients, a
whole update), its registration without the extra, and training on the toy env."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("jax")
pytest.importorskip("mujoco.mjx")
pytest.importorskip("flax")
pytest.importorskip("optax")

import jax
import jax.numpy as jnp

from amorctl.core.config import TrainConfig, override
from amorctl.core.gae import gae as core_gae
from amorctl.envs.toy import ToyTradeoffEnv
from amorctl.plugins.backends.jax_mjx import moppo_math as mm
from amorctl.plugins.backends.jax_mjx.networks import Networks, arrays_to_params, params_to_arrays
from amorctl.plugins.backends.torch_cpu import TorchCpuBackend
from amorctl.plugins.backends.torch_cpu.networks import modules_to_arrays

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


def torch_trainer_with_batch(config: TrainConfig):
    env = ToyTradeoffEnv(config.env.num_envs, max_steps=20, seed=config.run.seed)
    trainer = TorchCpuBackend().make_trainer(env, config)
    trainer.iteration()  # a normalizer and weights that are not the initial ones
    batch, _ = trainer.collect_rollout()
    trainer.compute_returns(batch)
    return trainer, batch


def jax_side(trainer, batch, config: TrainConfig):
    """The torch trainer's networks, normalizer and batch as the jax-mjx math takes them."""
    n = config.network
    nets = Networks(5, 1, 2, n.actor_hidden, n.critic_hidden, n.init_std)
    arrays = modules_to_arrays({"actor": trainer.actor, "critic": trainer.critic})
    params = arrays_to_params(arrays, nets.init(jax.random.key(0)))
    norm = trainer.normalizer
    stats = (
        jnp.asarray(norm.mean.numpy().astype(np.float32)),
        jnp.asarray((np.sqrt(norm.var.numpy()) + norm.eps).astype(np.float32)),
    )
    jb = mm.Batch(
        **{k: jnp.asarray(getattr(batch, k).numpy()) for k in mm.Batch._fields if k != "old_log_std"},
        old_log_std=jnp.asarray(batch.old_log_std.numpy()),
    )
    cfg = mm.LossConfig.from_config(config.ppo, n.obs_clip)
    return nets, params, stats, jb, cfg


def test_both_backends_name_their_parameters_through_one_function() -> None:
    """Checkpoint interchange rests on one naming rule (host.linear_param_name): torch-cpu's
    modules produce exactly those names, and jax-mjx writes the same set; a change to either
    side's network layout fails here."""
    from amorctl.plugins.backends.host import LOG_STD, linear_param_name

    config = tiny_config(network__actor_hidden=[32, 16], network__critic_hidden=[8])
    trainer = TorchCpuBackend().make_trainer(ToyTradeoffEnv(8, max_steps=5), config)
    torch_names = set(modules_to_arrays({"actor": trainer.actor, "critic": trainer.critic}))
    expected = {LOG_STD} | {
        linear_param_name(net, i, part)
        for net, layers in (("actor", 3), ("critic", 2))
        for i in range(layers)
        for part in ("weight", "bias")
    }
    assert torch_names == expected
    nets = Networks(5, 1, 2, [32, 16], [8], 1.0)
    jax_arrays = params_to_arrays(nets.init(jax.random.key(0)))
    assert set(jax_arrays) == expected
    for name in expected:
        assert jax_arrays[name].shape == trainer.state_dict().arrays[name].shape, name


def test_gae_matches_torch_with_truncation_and_termination() -> None:
    rng = np.random.default_rng(0)
    T, N, m = 12, 5, 3
    r, v, nv = (rng.normal(size=(T, N, m)).astype(np.float32) for _ in range(3))
    term = rng.random((T, N)) < 0.15
    trunc = (rng.random((T, N)) < 0.15) & ~term
    ta, tr = core_gae(*(torch.from_numpy(x) for x in (r, v, nv, term, trunc)), 0.99, 0.95, xp=torch)
    ja, jr = mm.gae(*(jnp.asarray(x) for x in (r, v, nv, term, trunc)), 0.99, 0.95)
    np.testing.assert_allclose(np.asarray(ja), ta.numpy(), atol=1e-5)
    np.testing.assert_allclose(np.asarray(jr), tr.numpy(), atol=1e-5)
    assert np.abs(ta.numpy()).max() > 1.0  # not a trivially small case


def test_losses_and_gradients_match_torch_on_the_same_batch() -> None:
    config = tiny_config()
    trainer, batch = torch_trainer_with_batch(config)
    nets, params, norm, jb, cfg = jax_side(trainer, batch, config)
    T, N, m = batch.rewards.shape
    adv, ret = mm.gae(
        jb.rewards, jb.values.reshape(T, N, m), jb.next_values, jb.terminated, jb.truncated,
        cfg.gamma, cfg.gae_lambda,
    )  # fmt: skip
    adv, ret = adv.reshape(T * N, m), ret.reshape(T * N, m)
    np.testing.assert_allclose(np.asarray(adv), batch.advantages.numpy(), atol=1e-5)
    np.testing.assert_allclose(np.asarray(ret), batch.returns.numpy(), atol=1e-5)

    idx = torch.randperm(T * N, generator=torch.Generator().manual_seed(1))[: T * N // 2]
    # a changed policy, so ratio, clipping and KL are not trivial
    with torch.no_grad():
        for p in trainer.actor.parameters():
            p.add_(0.05 * torch.randn(p.shape, generator=torch.Generator().manual_seed(2)))
    nets, params, norm, jb, cfg = jax_side(trainer, batch, config)
    loss, stats = trainer.minibatch_loss(batch, idx)
    trainer.optimizer.zero_grad()
    loss.backward()
    ids = jnp.asarray(idx.numpy())
    mb = {
        "obs": jb.obs[ids], "actions": jb.actions[ids], "means": jb.means[ids],
        "log_probs": jb.log_probs[ids], "values": jb.values[ids], "weights": jb.weights[ids],
        "advantages": adv[ids], "returns": ret[ids], "old_log_std": jb.old_log_std,
        "mask": jnp.ones(len(idx), jnp.float32),
    }  # fmt: skip
    jloss, jstats = mm.minibatch_loss(params, nets, norm, mb, cfg)
    assert float(jloss) == pytest.approx(float(loss.detach()), abs=1e-5)
    assert float(stats["clip_fraction"]) > 0.01  # clipping is exercised
    for key, value in stats.items():
        assert float(jstats[key]) == pytest.approx(float(value), abs=1e-5), key
    grads = jax.grad(lambda p: mm.minibatch_loss(p, nets, norm, mb, cfg)[0])(params)
    torch_grads = {
        name: p.grad.numpy()
        for prefix, module in (("actor", trainer.actor), ("critic", trainer.critic))
        for name, p in ((f"{prefix}.{k}", v) for k, v in module.named_parameters())
    }
    jax_grads = params_to_arrays(grads)
    assert jax_grads.keys() == torch_grads.keys()
    for key, g in torch_grads.items():
        np.testing.assert_allclose(jax_grads[key], g, atol=1e-5, err_msg=key)
    assert max(np.abs(g).max() for g in torch_grads.values()) > 1e-2


def test_padded_minibatch_equals_the_unpadded_one() -> None:
    config = tiny_config()
    trainer, batch = torch_trainer_with_batch(config)
    nets, params, norm, jb, cfg = jax_side(trainer, batch, config)
    B = jb.obs.shape[0]
    adv = jnp.asarray(batch.advantages.numpy())
    ret = jnp.asarray(batch.returns.numpy())
    ids = jnp.arange(B - 7)
    padded = jnp.concatenate([ids, jnp.zeros(7, ids.dtype)])
    mask = jnp.concatenate([jnp.ones(B - 7), jnp.zeros(7)]).astype(jnp.float32)

    def mb(i: jax.Array, msk: jax.Array) -> dict[str, jax.Array]:
        return {
            "obs": jb.obs[i], "actions": jb.actions[i], "means": jb.means[i], "log_probs": jb.log_probs[i],
            "values": jb.values[i], "weights": jb.weights[i], "advantages": adv[i], "returns": ret[i],
            "old_log_std": jb.old_log_std, "mask": msk,
        }  # fmt: skip

    a, sa = mm.minibatch_loss(params, nets, norm, mb(ids, jnp.ones(B - 7)), cfg)
    b, sb = mm.minibatch_loss(params, nets, norm, mb(padded, mask), cfg)
    assert float(a) == pytest.approx(float(b), abs=1e-6)
    for key in sa:
        assert float(sa[key]) == pytest.approx(float(sb[key]), abs=1e-6), key


@pytest.mark.parametrize(("minibatches", "return_norm"), [(2, "off"), (3, "off"), (3, "value+advantage")])
def test_a_whole_update_matches_torch(minibatches: int, return_norm: str) -> None:
    """Same batch, same minibatch order: every Adam step, clipped gradient and learning-rate
    adaptation of torch-cpu's update, within float32 rounding (also with per-objective return
    normalization, given torch's running stds)."""
    config = tiny_config(ppo__num_minibatches=minibatches, ppo__num_epochs=2, ppo__return_norm=return_norm)
    trainer, batch = torch_trainer_with_batch(config)
    nets, params, norm, jb, cfg = jax_side(trainer, batch, config)
    state = trainer.generator.get_state()
    B = jb.obs.shape[0]
    perms = np.stack([torch.randperm(B, generator=trainer.generator).numpy() for _ in range(cfg.num_epochs)])
    trainer.generator.set_state(state)
    lr0 = trainer.learning_rate
    trainer.optimizer = torch.optim.Adam(trainer.params, lr=lr0)  # both start from a fresh Adam
    torch_stats = trainer.update(batch)

    optimizer = mm.make_optimizer(lr0)
    ts = mm.TrainState(params, optimizer.init(params))
    adv, ret = jnp.asarray(batch.advantages.numpy()), jnp.asarray(batch.returns.numpy())
    stds = None
    if trainer.return_scale is not None:
        scale = trainer.return_scale
        stds = (jnp.asarray(scale.return_std()), jnp.asarray(scale.advantage_std()))
        assert np.abs(np.log(np.asarray(stds[0]))).min() > 0.3  # stds ~1.5, not 1: the test can fail
    ts, stats = mm.update(ts, nets, optimizer, norm, jb, adv, ret, jnp.asarray(perms), cfg, stds)
    for key, value in torch_stats.items():
        assert float(stats[key]) == pytest.approx(value, abs=1e-5), key
    assert float(mm.learning_rate(ts.opt_state)) == pytest.approx(trainer.learning_rate, rel=1e-5)
    after = params_to_arrays(ts.params)
    for key, value in modules_to_arrays({"actor": trainer.actor, "critic": trainer.critic}).items():
        np.testing.assert_allclose(after[key], value, atol=1e-5, err_msg=key)
    moved = np.abs(after["actor.net.0.weight"] - params_to_arrays(params)["actor.net.0.weight"]).max()
    assert moved > 1e-3  # the update did change the weights


# ---------------------------------------------------------------------------- the toy env path
def jax_trainer(config: TrainConfig):
    from amorctl.plugins.backends.jax_mjx import JaxMjxBackend

    env = ToyTradeoffEnv(config.env.num_envs, max_steps=20, seed=config.run.seed)
    return JaxMjxBackend().make_trainer(env, config)


def test_trained_policy_action_sign_flips_with_the_weights() -> None:
    """On the toy env jax-mjx learns torch-cpu's trade-off (tests/test_moppo.py's same check)."""
    trainer = jax_trainer(tiny_config())
    for _ in range(30):
        metrics = trainer.iteration()
    assert metrics["return/scalarized"] > 10  # of at most 20 per 20-step episode
    obs = np.array([[0, 0, 0.5, 1, 0], [0, 0, 0.5, 0, 1], [0, 0, 0.5, 0.5, 0.5]], dtype=np.float32)
    a = trainer.act(obs)[:, 0]
    assert a[0] > 0.5 and a[1] < -0.5, a  # w = (1, 0): act right; w = (0, 1): act left
    assert abs(a[2]) < abs(a[0]) and abs(a[2]) < abs(a[1])


@pytest.mark.parametrize("return_norm", ["off", "value+advantage"])
def test_metrics_have_torch_cpus_names(return_norm: str) -> None:
    config = tiny_config(ppo__return_norm=return_norm)
    a = jax_trainer(config).iteration()
    env = ToyTradeoffEnv(config.env.num_envs, max_steps=20, seed=0)
    b = TorchCpuBackend().make_trainer(env, config).iteration()
    assert set(a) == set(b)
    assert all(np.isfinite(a[k]) for k in ("loss/total", "kl", "explained_variance/left", "learning_rate"))


JAX_TOY_RUN = {
    "run": {"iterations": 4, "checkpoint_every": 2, "keep_checkpoints": 0, "tensorboard": False,
            "backend": "jax-mjx"},
    "env": {"kind": "toy", "num_envs": 32, "episode_seconds": 0.3},
    "network": {"actor_hidden": [16, 16], "critic_hidden": [16, 16], "init_std": 0.5},
    "ppo": {"num_steps": 8, "num_epochs": 2, "num_minibatches": 3, "learning_rate": 3e-3,
            "precision": "fp32"},
}  # fmt: skip


@pytest.mark.parametrize("return_norm", ["off", "value+advantage"])
def test_run_resumes_exactly_and_its_policy_acts_the_same_through_torch(tmp_path, return_norm: str) -> None:
    import csv

    from amorctl.core.config import merge
    from amorctl.plugins.backends.torch_cpu.policy import TorchPolicy
    from amorctl.train.checkpoint import load_checkpoint
    from amorctl.train.loop import train_run
    from amorctl.train.rundir import RunDir

    config = override(merge(TrainConfig(), JAX_TOY_RUN, "test"), ppo__return_norm=return_norm)
    train_run(config, tmp_path / "full")
    part = train_run(config, tmp_path / "part", stop_after=3)
    assert part.interrupted and part.end_iteration == 3
    resumed = train_run(config, tmp_path / "part", resume=True)
    assert (resumed.start_iteration, resumed.end_iteration) == (3, 4)

    def rows(run: str) -> list[dict[str, str]]:
        with open(tmp_path / run / "metrics.csv") as f:
            return list(csv.DictReader(f))

    a, b = rows("full"), rows("part")
    assert [r["iteration"] for r in a] == [r["iteration"] for r in b] == ["1.0", "2.0", "3.0", "4.0"]
    for ra, rb in zip(a, b, strict=True):
        for key in ("loss/total", "loss/policy", "loss/value", "kl", "return/right", "learning_rate"):
            assert ra[key] == rb[key], (ra["iteration"], key)
    wa = load_checkpoint(tmp_path / "full/checkpoints/iter_000004.json").trainer.arrays
    wb = load_checkpoint(tmp_path / "part/checkpoints/iter_000004.json").trainer.arrays
    assert wa.keys() == wb.keys()
    assert ("return_scale.adv_sq" in wa) == (return_norm != "off")
    for key in wa:
        np.testing.assert_array_equal(wa[key], wb[key], err_msg=key)

    run = RunDir.open(tmp_path / "full")
    policy = run.policy()
    assert type(policy).__name__ == "JaxPolicy" and policy.objectives == ("right", "left")
    torch_policy = TorchPolicy(run.checkpoint().trainer, run.config.network)
    obs = np.random.default_rng(0).normal(size=(50, 5)).astype(np.float32)
    obs[:, 3:] = np.random.default_rng(1).dirichlet([1, 1], size=50)
    np.testing.assert_allclose(policy(obs), torch_policy(obs), atol=1e-5)
    np.testing.assert_allclose(policy.values(obs), torch_policy.values(obs), atol=1e-5)
    assert np.abs(policy(obs)).max() > 1e-3
    assert policy.observation_layout["weights"] == (3, 5)
    exported, torch_exported = policy.export_arrays(), torch_policy.export_arrays()
    assert exported.arrays.keys() == torch_exported.arrays.keys()
    for key, value in torch_exported.arrays.items():
        np.testing.assert_allclose(exported.arrays[key], value, atol=1e-6, err_msg=key)
    assert {k: v for k, v in exported.meta.items() if k != "observation_layout"} == {
        k: v for k, v in torch_exported.meta.items() if k != "observation_layout"
    }


def test_plugins_list_jax_mjx_and_train_without_the_extra_names_it(tmp_path) -> None:
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['jax'] = None\n"  # as if the extra were not installed
        "from amorctl.cli.main import main\n"
        "from amorctl.registry import get_registry\n"
        "assert 'jax-mjx' in get_registry().names('backend')\n"
        f"out = {str(tmp_path / 'r')!r}\n"
        "sys.exit(main(['train', '--env', 'toy', '--backend', 'jax-mjx', '--out', out]))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "amorctl[jax]" in proc.stderr and "jax" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "r").exists()  # nothing written


# ---------------------------------------------------------------------------- devices
TWO_DEVICE_SCRIPT = r"""
import json, sys
import jax, numpy as np
from amorctl.core.config import TrainConfig, override
from amorctl.envs.toy import ToyTradeoffEnv
from amorctl.plugins.backends.jax_mjx import JaxMjxBackend, devices
from amorctl.plugins.backends.jax_mjx.networks import params_to_arrays

assert jax.device_count() == 2, jax.devices()
config = override(
    TrainConfig(), env__kind="toy", env__num_envs=32, network__actor_hidden=[16, 16],
    network__critic_hidden=[16, 16], ppo__num_steps=8, ppo__num_epochs=2, ppo__num_minibatches=3,
    ppo__learning_rate=3e-3, run__tensorboard=False,
)
results = {}
make_mesh = devices.local_mesh
for count in (1, 2):
    mesh = make_mesh(count)
    devices.local_mesh = lambda num_devices=None, _m=mesh: _m  # the trainer's mesh
    env = ToyTradeoffEnv(32, max_steps=20, seed=0)
    trainer = JaxMjxBackend().make_trainer(env, config)
    assert trainer.mesh.size == count
    metrics = [trainer.iteration() for _ in range(2)]
    results[count] = {
        "params": {k: v.tolist() for k, v in params_to_arrays(trainer.params).items()},
        "loss": [m["loss/total"] for m in metrics],
        "sharding": str(trainer.state.params["actor"]["log_std"].sharding),
    }
print(json.dumps(results))
"""


def test_two_device_update_equals_the_one_device_update() -> None:
    """XLA_FLAGS=--xla_force_host_platform_device_count=2: envs and batch split over 2 CPU
    devices give the one-device iterations (same rollout, same update) within float32 rounding."""
    import json
    import os
    import subprocess
    import sys

    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    proc = subprocess.run(
        [sys.executable, "-c", TWO_DEVICE_SCRIPT], capture_output=True, text=True, timeout=300, env=env
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    one, two = out["1"], out["2"]
    np.testing.assert_allclose(two["loss"], one["loss"], rtol=1e-5, atol=1e-6)
    for key, value in one["params"].items():
        np.testing.assert_allclose(np.array(two["params"][key]), np.array(value), atol=1e-5, err_msg=key)
    assert "'envs': 2" in two["sharding"] and "spec=P()" in two["sharding"]  # replicated parameters


MULTI_PROCESS_SCRIPT = r"""
import json, os
import jax
from amorctl.core.config import TrainConfig, override
from amorctl.envs.toy import ToyTradeoffEnv
from amorctl.plugins.backends.jax_mjx import JaxMjxBackend
from amorctl.plugins.backends.jax_mjx.networks import params_to_arrays

config = override(
    TrainConfig(), env__kind="toy", env__num_envs=32, network__actor_hidden=[16, 16],
    network__critic_hidden=[16, 16], ppo__num_steps=8, ppo__num_epochs=2, ppo__num_minibatches=3,
    ppo__learning_rate=3e-3, run__tensorboard=False,
)
trainer = JaxMjxBackend().make_trainer(ToyTradeoffEnv(32, max_steps=20, seed=0), config)
metrics = trainer.iteration()
print(json.dumps({
    "processes": jax.process_count(), "process": jax.process_index(), "devices": jax.device_count(),
    "local": jax.local_device_count(), "loss": metrics["loss/total"],
    "params": {k: v.tolist() for k, v in params_to_arrays(trainer.params).items()},
}))
"""


@pytest.mark.slow
def test_two_processes_give_the_one_process_two_device_update() -> None:
    """Multi-host on loopback: 2 JAX processes (one CPU device each, gloo collectives, coordinator
    127.0.0.1) joined by ``AMORCTL_JAX_DISTRIBUTED=1`` end one training iteration with identical
    parameters, equal to 1 process with 2 devices on the same total batch within 1e-5."""
    import json
    import os
    import socket
    import subprocess
    import sys

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    base = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    base["JAX_PLATFORMS"] = "cpu"
    procs = []
    for pid in range(2):
        env = dict(
            base, AMORCTL_JAX_DISTRIBUTED="1", JAX_COORDINATOR_ADDRESS=f"127.0.0.1:{port}",
            JAX_NUM_PROCESSES="2", JAX_PROCESS_ID=str(pid),
        )  # fmt: skip
        procs.append(
            subprocess.Popen(
                [sys.executable, "-c", MULTI_PROCESS_SCRIPT],
                env=env,
                text=True,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
            )
        )
    one = dict(base, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    command = [sys.executable, "-c", MULTI_PROCESS_SCRIPT]
    ref = subprocess.run(command, env=one, capture_output=True, text=True, timeout=300)
    outs = []
    for proc in procs:
        stdout, stderr = proc.communicate(timeout=300)
        assert proc.returncode == 0, stderr[-3000:]
        outs.append(json.loads(stdout.strip().splitlines()[-1]))
    assert ref.returncode == 0, ref.stderr[-3000:]
    single = json.loads(ref.stdout.strip().splitlines()[-1])
    assert single["processes"] == 1 and single["devices"] == 2
    assert [o["process"] for o in outs] == [0, 1]
    assert all(o["processes"] == 2 and o["devices"] == 2 and o["local"] == 1 for o in outs)
    for key, value in outs[0]["params"].items():
        assert outs[1]["params"][key] == value, key  # identical in both processes
        np.testing.assert_allclose(np.array(value), np.array(single["params"][key]), atol=1e-5, err_msg=key)
    np.testing.assert_allclose(outs[0]["loss"], single["loss"], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("character", ["biped20", "humanoid36"])
def test_tracking_checkpoint_acts_the_same_through_torch(character: str, tmp_path) -> None:
    """Both characters: a jax-mjx trainer's checkpoint (default network sizes, a normalizer fed
    with the character's tracking observations) read back from disk acts and values identically
    (1e-5) through the jax and torch-cpu inference paths, on that character's observations."""
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.envs.tracking_env import TrackingEnv
    from amorctl.plugins.backends.jax_mjx import JaxMjxBackend
    from amorctl.plugins.backends.jax_mjx.policy import JaxPolicy
    from amorctl.plugins.backends.torch_cpu.policy import TorchPolicy
    from amorctl.registry import get_registry
    from amorctl.train.checkpoint import load_checkpoint, save_checkpoint

    ch = get_registry().character(character)
    lib = synthetic_library(ch, num_clips=2, seconds=1.0, seed=3)
    env = TrackingEnv(ch, lib, num_envs=8, max_episode_steps=40, action_mode="residual", seed=0, nthread=1)
    config = override(TrainConfig(), ppo__precision="fp32")
    trainer = JaxMjxBackend().make_trainer(env, config)  # host path: the C env is a numpy VectorEnv
    seen = [trainer.obs]
    for _ in range(5):
        obs = env.step(trainer.act(trainer.obs, deterministic=False))[0]
        trainer.obs = np.asarray(obs, np.float32)
        trainer.normalizer.update(obs)
        seen.append(trainer.obs)
    meta = dict(
        backend="jax-mjx",
        env_kind="tracking",
        character=character,
        objective_set="tracking7",
        objectives=list(env.reward_space.names),
        obs_dim=env.obs_dim,
        action_dim=env.action_dim,
    )
    path = save_checkpoint(tmp_path, 0, meta, trainer.state_dict(), None)
    state = load_checkpoint(path).trainer
    jp, tp = JaxPolicy(state, config.network), TorchPolicy(state, config.network)
    obs = np.concatenate(seen)  # [48, D]
    assert jp.obs_dim == env.obs_dim and jp.action_dim == ch.num_joints
    a = jp(obs)
    np.testing.assert_allclose(a, tp(obs), atol=1e-5)
    np.testing.assert_allclose(jp.values(obs), tp.values(obs), atol=1e-5)
    np.testing.assert_allclose(a, trainer.act(obs), atol=1e-6)  # the checkpoint is the trainer's policy
    assert np.abs(a).max() > 1e-3
    assert (
        jp.observation_layout
        == tp.observation_layout
        == {k: (s.start, s.stop) for k, s in env.obs_layout.items()}
    )
