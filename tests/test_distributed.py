"""Data-parallel MOPPO over ``torch.distributed``, on loopback with 2 processes.

Each test starts two ranks as plain subprocesses with torchrun's environment variables (RANK,
WORLD_SIZE, MASTER_ADDR=127.0.0.1, a free MASTER_PORT, gloo bound to ``lo``); the ranks run
this file's ``__main__`` in one of the modes below. The toy env and tiny nets keep each launch to
a few seconds, most of it importing torch.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from amorctl.core.config import TrainConfig, merge
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.process_exit import end_process
from amorctl.train import distributed
from amorctl.train.checkpoint import list_checkpoints, load_checkpoint

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]
TINY = {
    "run": {"iterations": 6, "checkpoint_every": 2, "keep_checkpoints": 0, "tensorboard": False,
            "threads": 1},
    "env": {"kind": "toy", "num_envs": 32, "episode_seconds": 0.3},
    "network": {"actor_hidden": [16, 16], "critic_hidden": [16, 16]},
    "ppo": {"precision": "fp32", "num_steps": 8, "num_epochs": 2, "num_minibatches": 2},
}  # fmt: skip
TIMEOUT_S = 20.0  # AMORCTL_DIST_TIMEOUT of the launched ranks
B, MINIBATCHES, EPOCHS = 64, 4, 2  # the fixed batch of the update test
SWEEP_K, SWEEP_E = 15, 8  # weight vectors and episodes of the Pareto test (blocks 8 + 7)
SWEEP_LEVEL_E = 5  # episodes per level of the weight sweep (blocks 3 + 2)
TRACK_K, TRACK_E, TRACK_LEVEL_E = 7, 2, 3  # the same on the tracking env (blocks 4 + 3, 2 + 1)


def tiny_config(**sections: dict) -> TrainConfig:
    data = {k: dict(v) for k, v in TINY.items()}
    for key, values in sections.items():
        data[key].update(values)
    return merge(TrainConfig(), data, "test")


# ---------------------------------------------------------------------------- launching
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def launch(mode: str, directory: Path, world: int = 2, timeout: float = TIMEOUT_S) -> list[subprocess.Popen]:
    """Start ``world`` ranks of this file's ``mode`` (stdout/stderr to files in ``directory``)."""
    port = free_port()
    procs = []
    for rank in range(world):
        env = {
            **os.environ,
            "RANK": str(rank),
            "LOCAL_RANK": str(rank),
            "WORLD_SIZE": str(world),
            "LOCAL_WORLD_SIZE": str(world),
            "MASTER_ADDR": "127.0.0.1",
            "MASTER_PORT": str(port),
            "GLOO_SOCKET_IFNAME": "lo",
            "OMP_NUM_THREADS": "1",
            distributed.TIMEOUT_ENV: str(timeout),
            "PYTHONPATH": str(ROOT),
        }
        out = (directory / f"rank{rank}.out").open("w")
        err = (directory / f"rank{rank}.err").open("w")
        procs.append(
            subprocess.Popen(
                [sys.executable, str(HERE), mode, str(directory)], env=env, stdout=out, stderr=err
            )
        )
    return procs


def wait_all(procs: list[subprocess.Popen], directory: Path, timeout: float = 120.0) -> list[int]:
    codes = []
    for p in procs:
        try:
            codes.append(p.wait(timeout=timeout))
        except subprocess.TimeoutExpired:
            for q in procs:
                q.kill()
            raise
    return codes


def logs(directory: Path, rank: int) -> str:
    return (directory / f"rank{rank}.err").read_text() + (directory / f"rank{rank}.out").read_text()


def rows(run: Path) -> list[dict[str, str]]:
    if not (run / "metrics.csv").exists():
        return []
    return list(csv.DictReader((run / "metrics.csv").open()))


# ---------------------------------------------------------------------------- the fixed batch
def fixed_batch(trainer, seed: int = 7):
    """B samples with actions, log-probs, values, advantages and returns made from ``trainer``'s
    current networks (so the PPO ratio starts at 1), identical wherever it is built."""
    from amorctl.core.ppo_math import gaussian_log_prob
    from amorctl.plugins.backends.torch_cpu.moppo import Batch

    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(B, 5, generator=g)
    w = torch.rand(B, 2, generator=g)
    obs[:, 3:] = w / w.sum(1, keepdim=True)
    with torch.no_grad():
        means, values = trainer._forward(obs)
        log_std = trainer.actor.log_std.detach().clone()
        actions = means + torch.exp(log_std) * torch.randn(B, 1, generator=g)
        log_probs = gaussian_log_prob(actions, means, log_std, xp=torch)
    zeros = torch.zeros(1, B, 2)
    return Batch(
        obs=obs, actions=actions, log_probs=log_probs, means=means, values=values, weights=obs[:, 3:],
        rewards=zeros, next_values=zeros, terminated=torch.zeros(1, B, dtype=torch.bool),
        truncated=torch.zeros(1, B, dtype=torch.bool), old_log_std=log_std,
        advantages=torch.randn(B, 2, generator=g) * 3 + 1, returns=values + torch.randn(B, 2, generator=g),
    )  # fmt: skip


def rank_plans() -> list[list[torch.Tensor]]:
    """Each rank's minibatch plan over its B/2 rows (fixed seeds)."""
    plans = []
    for rank in range(2):
        g = torch.Generator().manual_seed(100 + rank)
        plans.append(
            [
                idx
                for _ in range(EPOCHS)
                for idx in torch.randperm(B // 2, generator=g).tensor_split(MINIBATCHES)
            ]
        )
    return plans


def half(batch, rank: int):
    from dataclasses import replace

    rows_ = slice(rank * B // 2, (rank + 1) * B // 2)
    fields = ("obs", "actions", "log_probs", "means", "values", "weights", "advantages", "returns")
    return replace(batch, **{f: getattr(batch, f)[rows_] for f in fields})


def update_trainer(distributed_: bool):
    from amorctl.envs.toy import ToyTradeoffEnv
    from amorctl.plugins.backends.torch_cpu.moppo import MOPPOTrainer

    config = tiny_config(ppo={"normalize_obs": False, "learning_rate": 3e-3, "desired_kl": 0.001,
                              "num_epochs": EPOCHS, "num_minibatches": MINIBATCHES})  # fmt: skip
    return MOPPOTrainer(
        ToyTradeoffEnv(4, seed=1), config.network, config.ppo, seed=0, distributed=distributed_
    )


def module_arrays(trainer) -> dict[str, np.ndarray]:
    from amorctl.plugins.backends.torch_cpu.networks import modules_to_arrays

    return modules_to_arrays(trainer._modules())


# ---------------------------------------------------------------------------- rank programs
def main_update(directory: Path, world: distributed.World) -> None:
    """One update of 2 ranks × B/2 samples; the normalizer's all-reduced fold; a planted mismatch."""
    trainer = update_trainer(True)
    batch = fixed_batch(trainer)
    stats = trainer.update(half(batch, world.rank), rank_plans()[world.rank])
    trainer._update_normalizer(half(batch, world.rank).obs)
    arrays = module_arrays(trainer)
    mine = half(batch, world.rank)
    moments = trainer.replicas.return_moments(mine.returns, mine.advantages)  # the return scale's
    arrays.update({f"moments.{i}": m.numpy() for i, m in enumerate(moments)})
    arrays["learning_rate"] = np.array(trainer.learning_rate)
    arrays["kl"] = np.array(stats["kl"])
    np.savez(directory / f"update{world.rank}.npz", **arrays)
    if world.rank == 1:
        with torch.no_grad():
            trainer.actor.log_std += 1e-3
    try:
        trainer.replicas.check_identical(trainer._modules(), 1)
        found = "no mismatch found"
    except AmorError as err:
        found = str(err)
    (directory / f"mismatch{world.rank}.txt").write_text(found)


def main_train(directory: Path, world: distributed.World) -> None:
    """A 6-iteration run, and the same run interrupted after 3 iterations and resumed; the ranks
    compare their parameters after every iteration (``CHECK_EVERY = 1``) and count the checks."""
    from amorctl.plugins.backends.torch_cpu import moppo
    from amorctl.plugins.backends.torch_cpu.replicas import Replicas
    from amorctl.train.loop import train_run

    checks: list[int] = []
    check = Replicas.check_identical
    moppo.CHECK_EVERY = 1
    Replicas.check_identical = lambda self, modules, it: (checks.append(it), check(self, modules, it))[1]  # type: ignore[method-assign]
    config = tiny_config()
    train_run(config, directory / "full")
    part = train_run(config, directory / "part", stop_after=3)
    assert part.interrupted and part.end_iteration == 3
    notes: list[str] = []
    resumed = train_run(config, directory / "part", resume=True, on_note=notes.append)
    assert (resumed.start_iteration, resumed.end_iteration) == (3, 6) and not notes
    (directory / f"checks{world.rank}.json").write_text(json.dumps(checks))


def main_cli(directory: Path, world: distributed.World) -> None:
    """``amorctl train`` on this rank (the CLI joins the group from the environment itself)."""
    from amorctl.cli.main import run as amorctl  # the console script's entry point

    run = directory / "run"
    how = ["--resume"] if (run / "config.toml").exists() else ["--config", str(directory / "long.toml")]
    amorctl(["train", "--out", str(run), "--json", *how])


def sweep_commands(directory: Path) -> tuple[list[str], list[str]]:
    """``amorctl pareto`` and ``amorctl evaluate --sweep`` of the run in ``directory/run``."""
    run, out = str(directory / "run"), str(directory)
    pareto = ["pareto", run, "--samples", str(SWEEP_K), "--episodes", str(SWEEP_E), "--out", f"{out}/p"]
    evaluate = ["evaluate", run, "--sweep", "right", "--episodes", str(SWEEP_LEVEL_E), "--out", f"{out}/e"]
    return pareto, evaluate  # fmt: skip


def tracking_sweep_commands(directory: Path) -> tuple[list[str], list[str]]:
    """The same two commands for the biped20 tracking run in ``directory/run``: a front over
    random clips (RSI and clip switches drawn per episode), a weight sweep on two named motions."""
    run, out = str(directory / "run"), str(directory)
    pareto = ["pareto", run, "--samples", str(TRACK_K), "--episodes", str(TRACK_E), "--out", f"{out}/p"]
    evaluate = [
        "evaluate",
        run,
        "--sweep",
        "up",
        "--episodes",
        str(TRACK_LEVEL_E),
        "--motion",
        "sway_a",
        "--motion",
        "sway_b",
        "--out",
        f"{out}/e",
    ]
    return pareto, evaluate  # fmt: skip


def main_pareto(directory: Path, world: distributed.World) -> None:
    """``amorctl pareto`` and ``amorctl evaluate --sweep`` of the toy run in ``directory/run``."""
    from amorctl.cli.main import main

    for command in sweep_commands(directory):
        assert main([*command, "--seed", "3", "--json"]) == 0


def main_pareto_tracking(directory: Path, world: distributed.World) -> None:
    """The same for the tracking run in ``directory/run``."""
    from amorctl.cli.main import main

    for command in tracking_sweep_commands(directory):
        assert main([*command, "--seed", "3", "--json"]) == 0


# ---------------------------------------------------------------------------- tests
def test_local_config_splits_envs_and_seeds_per_rank() -> None:
    config = tiny_config()
    assert distributed.local_config(config, distributed.World()) is config
    parts = [distributed.local_config(config, distributed.World(r, 4)) for r in range(4)]
    assert [p.env.num_envs for p in parts] == [8] * 4
    assert parts[0].run.seed == config.run.seed and len({p.run.seed for p in parts}) == 4
    with pytest.raises(AmorError, match="num_envs = 32 is not divisible by the 3 processes"):
        distributed.local_config(config, distributed.World(0, 3))


SEEDS, SUB = np.array([5, 6, 7, 8, 9, 10]), [4, 1, 5]  # per-env seeds; a smaller batch's envs


def step_both(big, small, steps: int, scale: float) -> int:
    """Step a batch of 6 and one of 3 (the big one's envs SUB, seeded alike) with the same
    actions; every output of the shared envs must be bit-identical. Returns the episodes ended."""
    ob, _ = big.reset(seed=SEEDS)
    os_, _ = small.reset(seed=SEEDS[SUB])
    np.testing.assert_array_equal(ob[SUB], os_)
    rng, ended = np.random.default_rng(0), 0
    for _ in range(steps):
        a = scale * rng.normal(size=(6, big.action_dim))
        one, two = big.step(a), small.step(a[SUB])
        for x, y in zip(one[:4], two[:4], strict=True):  # obs, rewards, terminated, truncated
            np.testing.assert_array_equal(np.asarray(x)[SUB], y)
        ended += int((one[2] | one[3])[SUB].sum())
    return ended


def test_per_env_seeds_make_every_toy_env_independent_of_its_batch() -> None:
    """``reset(seed=[s_0, ...])``: env i draws from its own generator, so the same seed gives the
    same episodes (hazards, noise, resets, weights) in any batch, at any position; a snapshot
    keeps the per-env generators; one int seed still draws from one generator."""
    from amorctl.core.env_random import BatchRandom
    from amorctl.envs.toy import ToySmoothEnv, ToyTradeoffEnv

    for make in (
        lambda n: ToyTradeoffEnv(n, max_steps=7, hazard=0.2),
        lambda n: ToySmoothEnv(n, max_steps=5),
    ):
        big, small = make(6), make(3)
        assert step_both(big, small, 30, 1.0) >= 12  # several episodes each, resets included
        state, a = small.get_state(), np.ones((3, 1))
        first = small.step(a)
        small.set_state(state)
        np.testing.assert_array_equal(small.step(a)[0], first[0])
        small.reset(seed=4)
        assert isinstance(small.rand, BatchRandom)
    ob, _ = ToyTradeoffEnv(3).reset(seed=SEEDS[:3])
    assert not np.array_equal(ob, ToyTradeoffEnv(3).reset(seed=5)[0])
    with pytest.raises(AmorError, match="expected 3 seeds"):
        ToyTradeoffEnv(3).reset(seed=SEEDS)


def test_per_env_seeds_make_every_tracking_env_independent_of_its_batch() -> None:
    """The torch-cpu tracking env: RSI (random clip and frame) and the clip switches of short
    clips come from each env's generator; MuJoCo steps every env on its own, so the shared envs'
    observations, rewards and terminations are bit-identical in a batch of 6 and one of 3."""
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.envs.tracking_env import TrackingEnv
    from amorctl.registry import get_registry

    ch = get_registry().character("biped20")
    lib = synthetic_library(ch, num_clips=3, seconds=0.3, seed=3)  # 15-frame clips: switches
    big, small = (TrackingEnv(ch, lib, num_envs=n, max_episode_steps=12, nthread=1) for n in (6, 3))
    assert step_both(big, small, 26, 0.05) >= 6
    assert (big.tracking_view().clip_index()[SUB] == small.tracking_view().clip_index()).all()
    big.reset(seed=SEEDS)
    start = big.tracking_view().reference_index()
    big.reset(seed=SEEDS[::-1])
    assert not np.array_equal(start, big.tracking_view().reference_index())  # the seeds matter


def test_per_env_seeds_make_every_gymnasium_copy_independent_of_its_batch() -> None:
    """The Gymnasium adapter (``[env] kind = "gym"``): copy i is reset with ``seed[i]`` and then
    auto-resets from its own generator; its weights come from its own generator too."""
    import gymnasium as gym
    from gymnasium.wrappers import TimeLimit

    from amorctl.envs.mo_gym import MOGymVectorEnv

    class Drift(gym.Env):
        """x += 0.3 a + noise; rewards (-|x - 1|, -|a|); ends when |x| > 2 or after 4 steps."""

        observation_space = gym.spaces.Box(-9, 9, (1,), np.float32)
        action_space = gym.spaces.Box(-1, 1, (1,), np.float32)
        reward_space = gym.spaces.Box(-np.inf, 0, (2,), np.float32)

        def reset(self, *, seed: int | None = None, options: dict | None = None):
            super().reset(seed=seed)
            self.x = float(self.np_random.uniform(-1, 1))
            return np.array([self.x], np.float32), {}

        def step(self, action):
            a = float(np.asarray(action).reshape(-1)[0])
            self.x += 0.3 * a + 0.1 * float(self.np_random.normal())
            reward = np.array([-abs(self.x - 1.0), -abs(a)], np.float32)
            return np.array([self.x], np.float32), reward, abs(self.x) > 2.0, False, {}

    big, small = (MOGymVectorEnv(lambda: TimeLimit(Drift(), 4), num_envs=n) for n in (6, 3))
    assert step_both(big, small, 20, 1.0) >= 15
    np.testing.assert_array_equal(big.weights[SUB], small.weights)


@pytest.mark.slow
def test_per_env_seeds_give_the_jax_mjx_env_per_env_keys() -> None:
    """jax-mjx: [N] seeds become one key per env, so RSI and every later clip draw of an env are
    the same in a batch of 6 and one of 3 (its physics is compared with torch-cpu elsewhere)."""
    pytest.importorskip("jax")
    pytest.importorskip("mujoco.mjx")
    import jax

    from amorctl.envs.synthetic import synthetic_library
    from amorctl.plugins.backends.jax_mjx.core import _split
    from amorctl.plugins.backends.jax_mjx.env import MjxTrackingEnv
    from amorctl.registry import get_registry

    ch = get_registry().character("biped20")
    lib = synthetic_library(ch, num_clips=3, seconds=0.3, seed=3)
    big, small = (MjxTrackingEnv(ch, lib, num_envs=n, max_episode_steps=12) for n in (6, 3))
    ob, _ = big.reset(seed=SEEDS)
    os_, _ = small.reset(seed=SEEDS[SUB])
    np.testing.assert_array_equal(ob[SUB], os_)
    np.testing.assert_array_equal(np.asarray(big.state.key)[SUB], small.state.key)
    keys = [big.state.key, small.state.key]
    for _ in range(3):  # the clip draws of three steps (switches and resets)
        drawn = []
        for i, env in enumerate((big, small)):
            keys[i], k_clip = _split(keys[i], 2)
            drawn.append([np.asarray(x) for x in jax.jit(env.core._start_clips)(k_clip, env.sel, False)])
        for x, y in zip(*drawn, strict=True):
            np.testing.assert_array_equal(x[SUB], y)
    assert len(set(np.asarray(drawn[0][0]).tolist())) > 1  # the envs draw different clips
    with pytest.raises(AmorError, match="per-env seeds"):
        small.reset(seed=SEEDS)


def test_sweeps_call_the_policy_on_fixed_shape_blocks() -> None:
    from amorctl.analysis.sweeps import fixed_shape_policy

    shapes: list[tuple[int, ...]] = []

    def policy(obs: np.ndarray) -> np.ndarray:
        shapes.append(obs.shape)
        return obs[:, :1] * 2

    x = np.arange(22.0).reshape(11, 2)
    np.testing.assert_array_equal(fixed_shape_policy(policy, rows=4)(x), x[:, :1] * 2)
    assert shapes == [(4, 2)] * 3


def test_a_rank_that_joined_a_group_ends_without_finalization(monkeypatch: pytest.MonkeyPatch) -> None:
    from amorctl.cli import main as cli_main

    ended: list[int] = []

    def end(code: int) -> None:
        ended.append(code)
        raise SystemExit(code)

    monkeypatch.setattr(cli_main, "end_process", end)
    with pytest.raises(SystemExit) as exit_:
        cli_main.run(["--version"])
    assert exit_.value.code == 0 and not ended  # no group joined: a normal exit
    monkeypatch.setattr(distributed, "_joined_a_group", True)
    assert cli_main.main(["--version"]) == 0 and not ended  # main() itself only returns
    with pytest.raises(SystemExit):
        cli_main.run(["train", "--no-such-option"])
    assert ended == [2]  # the command's own status (a usage error here), after it returned


def test_rank_rows_cover_every_row_once_in_order() -> None:
    for count in (0, 1, 7, 10):
        for size in (1, 2, 3):
            blocks = [distributed.rank_rows(count, distributed.World(r, size)) for r in range(size)]
            assert [i for s in blocks for i in range(count)[s]] == list(range(count))
            assert max(len(range(count)[s]) for s in blocks) - min(len(range(count)[s]) for s in blocks) <= 1


def test_rank_snapshot_cuts_a_merged_snapshot_back_per_rank() -> None:
    ranks = [{"iteration": 4, "p": 0}, {"iteration": 4, "p": 1}]
    merged = Snapshot(
        {"actor.w": np.ones(3), "rank0/obs": np.zeros(2), "rank1/obs": np.ones(2)},
        {"iteration": 4, distributed.WORLD_KEY: 2, distributed.RANKS_KEY: ranks},
    )
    one = distributed.rank_snapshot(merged, 1)
    assert sorted(one.arrays) == ["actor.w", "obs"] and one.arrays["obs"].tolist() == [1, 1]
    assert one.meta == {"iteration": 4, "p": 1} and distributed.snapshot_world_size(merged) == 2
    plain = Snapshot({"obs": np.zeros(1)}, {"iteration": 1})
    assert distributed.rank_snapshot(plain, 0) is plain and distributed.snapshot_world_size(plain) == 1
    with pytest.raises(AmorError, match="holds 2 ranks, not rank 2"):
        distributed.rank_snapshot(merged, 2)


def test_two_rank_update_equals_the_one_process_update_on_the_same_samples(tmp_path: Path) -> None:
    procs = launch("update", tmp_path)
    reference = update_trainer(False)  # meanwhile: 1 process, all B samples, the same minibatches
    batch = fixed_batch(reference)
    p0, p1 = rank_plans()
    stats = reference.update(batch, [torch.cat([a, b + B // 2]) for a, b in zip(p0, p1, strict=True)])
    reference.normalizer.update(batch.obs)
    expect = module_arrays(reference)
    assert wait_all(procs, tmp_path) == [0, 0], logs(tmp_path, 0) + logs(tmp_path, 1)
    ranks = [dict(np.load(tmp_path / f"update{r}.npz")) for r in range(2)]
    for key, value in expect.items():
        np.testing.assert_array_equal(ranks[0][key], ranks[1][key], err_msg=key)  # identical replicas
        np.testing.assert_allclose(ranks[0][key], value, rtol=0, atol=1e-6, err_msg=key)
    assert not np.allclose(expect["actor.net.0.weight"], update_trainer(False).actor.net[0].weight.detach())
    # the adaptive learning rate followed the all-reduced KL, as the 1-process one did
    assert float(ranks[0]["learning_rate"]) == reference.learning_rate != 3e-3
    assert abs(float(ranks[0]["kl"]) - stats["kl"]) < 1e-6
    for rank in range(2):
        assert "parameters differ at iteration 1" in (tmp_path / f"mismatch{rank}.txt").read_text()
    r, a = batch.returns.double(), batch.advantages.double()  # all-reduced = the whole batch's
    for i, whole in enumerate((r.mean(0), (r * r).mean(0), (a * a).mean(0))):
        np.testing.assert_allclose(ranks[0][f"moments.{i}"], whole.numpy(), rtol=1e-12, err_msg=str(i))


def test_two_rank_run_is_replicated_and_resumes_to_the_same_metrics(tmp_path: Path) -> None:
    procs = launch("train", tmp_path)
    assert wait_all(procs, tmp_path) == [0, 0], logs(tmp_path, 0) + logs(tmp_path, 1)
    assert not logs(tmp_path, 1).strip()  # rank 1 is quiet
    for rank in range(2):  # identical after every iteration, at every checkpoint (and the resume)
        checked = json.loads((tmp_path / f"checks{rank}.json").read_text())
        full_run, part_run, resumed_run = [1, 2, 2, 3, 4, 4, 5, 6, 6], [1, 2, 2, 3, 3], [0, 4, 4, 5, 6, 6]
        assert checked == [*full_run, *part_run, *resumed_run], checked
    full, part = tmp_path / "full", tmp_path / "part"
    assert [i for i, _ in list_checkpoints(full / "checkpoints")] == [2, 4, 6]
    assert [i for i, _ in list_checkpoints(part / "checkpoints")] == [2, 3, 4, 6]
    a, b = rows(full), rows(part)
    assert [r["iteration"] for r in a] == [r["iteration"] for r in b] == [f"{i}.0" for i in range(1, 7)]
    assert float(a[-1]["env_steps"]) == 6 * 32 * 8  # both ranks' steps
    for ra, rb in zip(a, b, strict=True):
        for key in ra:
            if not key.startswith("time/") and key not in ("env_steps_per_s", "wall_time_s"):
                assert ra[key] == rb[key], (ra["iteration"], key)
    ca = load_checkpoint(full / "checkpoints/iter_000006.json")
    cb = load_checkpoint(part / "checkpoints/iter_000006.json")
    assert ca.trainer.meta[distributed.WORLD_KEY] == 2
    for x, y in ((ca.trainer, cb.trainer), (ca.env, cb.env)):
        assert x is not None and y is not None and x.arrays.keys() == y.arrays.keys()
        for key in x.arrays:
            np.testing.assert_array_equal(x.arrays[key], y.arrays[key], err_msg=key)
    # networks and optimizer are stored once (identical on both ranks); observations, RNG, env per rank
    keys = ca.trainer.arrays.keys()
    assert "actor.net.0.weight" in keys and not any(k.startswith("rank") and "actor" in k for k in keys)
    assert {"rank0/obs", "rank1/obs", "rank0/rng.torch", "rank1/rng.torch"} <= keys
    assert ca.env is not None and {"rank0/s", "rank1/s"} <= ca.env.arrays.keys()
    assert ca.trainer.arrays["rank0/obs"].shape == (16, 5)

    # one process continues the 2-process run: networks carry on, envs restart, and it says so
    from amorctl.train.loop import train_run

    notes: list[str] = []
    torch.set_num_threads(1)
    more = train_run(tiny_config(run={"iterations": 7}), part, resume=True, on_note=notes.append)
    assert more.end_iteration == 7 and len(notes) == 1
    assert "saved by 2 process(es), this run has 1" in notes[0] and "envs restart" in notes[0]
    single = load_checkpoint(part / "checkpoints/iter_000007.json")
    assert distributed.WORLD_KEY not in single.trainer.meta and single.trainer.arrays["obs"].shape == (32, 5)


def json_docs(text: str) -> list[dict]:
    """The JSON documents printed one after another (``--json`` of several commands)."""
    decoder, docs, text = json.JSONDecoder(), [], text.strip()
    while text:
        doc, end = decoder.raw_decode(text)
        docs.append(doc)
        text = text[end:].strip()
    return docs


def test_two_rank_sweeps_equal_the_one_process_sweeps(
    tmp_path: Path, toy_run: Path, capsys: pytest.CaptureFixture
) -> None:
    """``amorctl pareto`` and ``evaluate --sweep`` on 2 ranks (uneven blocks: 8 + 7 weight
    vectors, 3 + 2 episodes per level) give the 1-process command's front and returns bit for
    bit: every episode is seeded by (seed, its sample / episode index), never by its batch
    position, and the policy runs on fixed-shape blocks (docs/distributed.md)."""
    from amorctl.cli.main import main

    torch.set_num_threads(1)
    (tmp_path / "run").symlink_to(toy_run)  # trained: its actions follow w
    procs = launch("pareto", tmp_path)
    one = tmp_path / "one"
    one.mkdir()
    (one / "run").symlink_to(toy_run)
    capsys.readouterr()
    assert main([*sweep_commands(one)[0], "--seed", "3", "--json"]) == 0  # meanwhile: 1 process
    assert main([*sweep_commands(one)[1], "--seed", "3", "--json"]) == 0
    pareto_one, evaluate_one = json_docs(capsys.readouterr().out)
    assert wait_all(procs, tmp_path) == [0, 0], logs(tmp_path, 0) + logs(tmp_path, 1)
    assert not (tmp_path / "rank1.out").read_text()  # rank 1 printed and wrote nothing
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_dir()) == ["e", "one", "p", "run"]
    pareto_doc, evaluate_doc = json_docs((tmp_path / "rank0.out").read_text())
    assert json.loads((tmp_path / "p/pareto.json").read_text())["motions"] == pareto_doc["motions"]
    assert pareto_doc["weights"] == pareto_one["weights"] and len(pareto_doc["weights"]) == SWEEP_K
    # the same front, bit for bit: every row's returns, spreads, survival, the equal-weights
    # point, the non-dominated flags, hypervolume, expected utility and sparsity
    assert pareto_doc["motions"] == pareto_one["motions"]
    (front,) = pareto_doc["motions"]
    assert any(front["non_dominated"]) and not all(front["non_dominated"])  # a real front
    assert pareto_doc["timing"]["num_envs"] == pareto_one["timing"]["num_envs"] + SWEEP_E  # + rank 1's 1/m
    two_csv = list(csv.DictReader((tmp_path / "p/pareto.csv").open()))
    one_csv = list(csv.DictReader((one / "p/pareto.csv").open()))
    assert [r["sample"] for r in two_csv] == [str(k) for k in range(SWEEP_K)] + ["equal"]
    assert two_csv == one_csv  # every row, every column
    assert (tmp_path / "p/pareto.png").stat().st_size > 0
    # the weight sweep: each level's episodes 0-2 from rank 0, 3-4 from rank 1, as one process ran them
    sweep, sweep_one = evaluate_doc["sweep"], evaluate_one["sweep"]
    assert evaluate_doc["settings"] and Path(sweep["figure"]).is_file()
    assert np.array(sweep["returns"]).shape == (5, SWEEP_LEVEL_E)
    assert {k: v for k, v in sweep.items() if k != "figure"} == {
        k: v for k, v in sweep_one.items() if k != "figure"
    }


def test_two_rank_sweeps_on_the_tracking_env_equal_the_one_process_sweeps(
    tmp_path: Path, tracking_run: Path, capsys: pytest.CaptureFixture
) -> None:
    """The biped20 tracking env (MuJoCo physics, RSI at a random clip and frame, clip switches):
    ``amorctl pareto`` over random clips (7 weight vectors × 2 episodes split 4 + 3) and
    ``evaluate --sweep up`` on two named motions (3 episodes per level split 2 + 1) on 2 ranks give
    the 1-process front and returns bit for bit."""
    from amorctl.cli.main import main

    torch.set_num_threads(1)
    (tmp_path / "run").symlink_to(tracking_run)
    procs = launch("pareto-tracking", tmp_path)
    one = tmp_path / "one"
    one.mkdir()
    (one / "run").symlink_to(tracking_run)
    capsys.readouterr()
    for command in tracking_sweep_commands(one):  # meanwhile: 1 process
        assert main([*command, "--seed", "3", "--json"]) == 0
    pareto_one, evaluate_one = json_docs(capsys.readouterr().out)
    assert wait_all(procs, tmp_path) == [0, 0], logs(tmp_path, 0) + logs(tmp_path, 1)
    assert not (tmp_path / "rank1.out").read_text()
    pareto_doc, evaluate_doc = json_docs((tmp_path / "rank0.out").read_text())
    assert json.loads((tmp_path / "p/pareto.json").read_text())["motions"] == pareto_doc["motions"]
    assert pareto_doc["weights"] == pareto_one["weights"] and len(pareto_doc["weights"]) == TRACK_K
    (front,) = pareto_doc["motions"]
    points = np.array(front["points"], dtype=float)
    assert points.shape == (TRACK_K, 7) and np.isfinite(points).all()
    assert len({tuple(p) for p in points.round(9).tolist()}) == TRACK_K  # every sample its own row
    assert front["hypervolume"]["value"] > 0
    assert pareto_doc["motions"] == pareto_one["motions"]  # every value of the front, bit for bit
    two_csv = (tmp_path / "p/pareto.csv").read_text()
    assert two_csv == (one / "p/pareto.csv").read_text()
    sweep, sweep_one = evaluate_doc["sweep"], evaluate_one["sweep"]
    returns = np.array(sweep["returns"], dtype=float)
    assert returns.shape == (5, TRACK_LEVEL_E) and np.isfinite(returns).all() and np.ptp(returns) > 0
    assert {k: v for k, v in sweep.items() if k != "figure"} == {
        k: v for k, v in sweep_one.items() if k != "figure"
    }


def _long_run(tmp_path: Path) -> None:
    config = tmp_path / "long.toml"
    config.write_text(
        "[run]\niterations = 100000\ncheckpoint_every = 100000\ntensorboard = false\nthreads = 1\n"
        '[env]\nkind = "toy"\nnum_envs = 32\nepisode_seconds = 0.3\n'
        "[network]\nactor_hidden = [16]\ncritic_hidden = [16]\n"
        '[ppo]\nprecision = "fp32"\nnum_steps = 8\nnum_epochs = 1\nnum_minibatches = 1\n'
    )


def _wait_rows(run: Path, count: int, procs: list[subprocess.Popen], timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and len(rows(run)) < count:
        assert all(p.poll() is None for p in procs), "a rank ended early"
        time.sleep(0.1)
    assert len(rows(run)) >= count


def test_a_signal_on_one_rank_stops_both_and_a_dead_rank_fails_the_other(tmp_path: Path) -> None:
    _long_run(tmp_path)
    run = tmp_path / "run"
    procs = launch("cli", tmp_path)
    _wait_rows(run, 3, procs)
    procs[1].send_signal(signal.SIGTERM)  # only rank 1 is told
    codes = wait_all(procs, tmp_path, timeout=60)
    assert codes == [130, 143], logs(tmp_path, 0) + logs(tmp_path, 1)
    (iteration, path), *more = list_checkpoints(run / "checkpoints")
    assert not more and len(rows(run)) == iteration >= 3  # both stopped at the iteration rank 0 saved
    summary = json.loads((tmp_path / "rank0.out").read_text())
    assert summary["interrupted"] and summary["end_iteration"] == iteration
    assert load_checkpoint(path).trainer.meta[distributed.WORLD_KEY] == 2

    procs = launch("cli", tmp_path)  # resume with 2 ranks; Ctrl-C to rank 0 alone
    _wait_rows(run, iteration + 2, procs)
    procs[0].send_signal(signal.SIGINT)
    assert wait_all(procs, tmp_path, timeout=60) == [130, 130], logs(tmp_path, 0) + logs(tmp_path, 1)
    iteration, path = list_checkpoints(run / "checkpoints")[-1]
    assert len(rows(run)) == iteration == json.loads((tmp_path / "rank0.out").read_text())["end_iteration"]

    procs = launch("cli", tmp_path)  # resume with 2 ranks, then kill rank 1 outright
    _wait_rows(run, iteration + 2, procs)
    procs[1].kill()
    killed = time.monotonic()
    code = procs[0].wait(timeout=TIMEOUT_S + 30)
    waited = time.monotonic() - killed
    assert code != 0 and waited < TIMEOUT_S, (code, waited)  # within the configured timeout
    err = (tmp_path / "rank0.err").read_text()
    assert "another rank died or stopped answering" in err and "Traceback" not in err


def test_nproc_refuses_an_env_count_it_cannot_split_before_launching(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    from amorctl.cli.main import main

    out = tmp_path / "run"
    code = main(["train", "--env", "toy", "--num-envs", "5", "--nproc", "2", "--out", str(out)])
    assert code == 2 and "num_envs = 5 is not divisible by the 2 processes" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
def test_nproc_launches_torchrun_and_only_rank_0_reports(tmp_path: Path) -> None:
    config = tmp_path / "tiny.toml"
    config.write_text(
        "[run]\niterations = 3\ncheckpoint_every = 3\ntensorboard = false\nthreads = 1\n"
        '[env]\nkind = "toy"\nnum_envs = 16\nepisode_seconds = 0.3\n'
        "[network]\nactor_hidden = [8]\ncritic_hidden = [8]\n"
        '[ppo]\nprecision = "fp32"\nnum_steps = 4\nnum_epochs = 1\nnum_minibatches = 1\n'
    )
    out = tmp_path / "run"
    env = {**os.environ, "GLOO_SOCKET_IFNAME": "lo", "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-m", "amorctl", "train", "--config", str(config), "--out", str(out), "--nproc", "2",
         "--json"],
        capture_output=True, text=True, env=env, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout[done.stdout.index("{") :])  # after the launch line
    assert summary["end_iteration"] == 3 and summary["metrics"]["env_steps"] == 3 * 16 * 4
    assert done.stdout.count('"end_iteration"') == 1  # rank 1 printed nothing
    ckpt = load_checkpoint(out / "checkpoints/iter_000003.json")
    assert ckpt.trainer.meta[distributed.WORLD_KEY] == 2 and len(rows(out)) == 3

    # Ctrl-C (SIGINT to the terminal's process group): the ranks stop together and checkpoint
    proc = subprocess.Popen(
        [sys.executable, "-m", "amorctl", "train", "--out", str(out), "--resume", "--iterations", "100000",
         "--nproc", "2", "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, start_new_session=True,
    )  # fmt: skip
    _wait_rows(out, 6, [proc])
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode != 0, err
    iteration = list_checkpoints(out / "checkpoints")[-1][0]
    assert iteration >= 6 and len(rows(out)) == iteration, err


@pytest.mark.slow
def test_a_hung_rank_makes_the_other_fail_after_the_timeout(tmp_path: Path) -> None:
    _long_run(tmp_path)
    procs = launch("cli", tmp_path, timeout=5.0)
    _wait_rows(tmp_path / "run", 2, procs)
    procs[1].send_signal(signal.SIGSTOP)  # alive, silent
    stopped = time.monotonic()
    try:
        code = procs[0].wait(timeout=60)
    finally:
        procs[1].kill()
    waited = time.monotonic() - stopped
    assert code != 0 and 2.0 < waited < 30.0, (code, waited)
    assert "another rank died or stopped answering" in (tmp_path / "rank0.err").read_text()


# ---------------------------------------------------------------------------- rank entry point
if __name__ == "__main__":
    mode, where = sys.argv[1], Path(sys.argv[2])
    torch.set_num_threads(1)
    if mode == "cli":
        main_cli(where, distributed.World())
    with distributed.session() as world_:
        programs = {"update": main_update, "train": main_train, "pareto": main_pareto,
                    "pareto-tracking": main_pareto_tracking}  # fmt: skip
        programs[mode](where, world_)
    # as amorctl's own commands do after joining a group: skip interpreter finalization, where
    # gloo's native threads sometimes aborted a rank (SIGABRT) after its work was written
    end_process(0)
