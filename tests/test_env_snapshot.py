"""Tracking-env snapshots (``get_state`` / ``set_state``) and bit-exact resume of tracking runs."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import torch

from amorctl.core.config import TrainConfig, merge
from amorctl.core.contracts import Snapshot, SnapshotEnv
from amorctl.core.errors import AmorError
from amorctl.envs.synthetic import synthetic_library
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.motion.dataset import write_dataset
from amorctl.registry import get_registry
from amorctl.train.checkpoint import list_checkpoints, load_checkpoint, save_checkpoint
from amorctl.train.loop import train_run

NUM_ENVS = 3
WARMUP, K = 7, 12  # 7 control steps of a 2-step-latency, 5-substep servo leave the delay head at 2


def _character(name: str):
    registry = get_registry()
    if name not in registry.names("character"):
        pytest.skip(f"character {name} not installed")
    return registry.character(name)


def _env(ch, lib, seed: int) -> TrackingEnv:
    # short episodes and clips so resets (RSI, weight draws) and clip switches happen in the window
    return TrackingEnv(ch, lib, num_envs=NUM_ENVS, max_episode_steps=5, nthread=2, seed=seed)


def _roll(env: TrackingEnv, actions: np.ndarray) -> list[dict[str, np.ndarray]]:
    out = []
    for a in actions:
        obs, rewards, terminated, truncated, info = env.step(a)
        out.append(
            {
                "obs": obs,
                "rewards": rewards,
                "terminated": terminated,
                "truncated": truncated,
                "final_obs": info["final_obs"],
                "diverged_total": np.array(info["diverged_total"]),
                "clip_switched": info["clip_switched"],
                "weights": env.weights,
                "qpos": env.sim.qpos.copy(),
            }
        )
    return out


def _through_files(state: Snapshot, directory: Path) -> Snapshot:
    """The state as a checkpoint stores and reloads it (safetensors + JSON)."""
    meta = {  # what a tracking run's checkpoint carries (train.rundir.run_meta)
        "amorctl_version": "test", "backend": "torch-cpu", "env_kind": "tracking", "character": "biped20",
        "gym_id": None, "objective_set": "tracking7", "objectives": ["up"], "obs_dim": 1, "action_dim": 1,
        "fixed_weights": "",
    }  # fmt: skip
    path = save_checkpoint(directory, 1, meta, Snapshot(), state)
    loaded = load_checkpoint(path).env
    assert loaded is not None
    return loaded


@pytest.mark.parametrize("name", ["biped20", "humanoid36"])
def test_snapshot_restores_the_next_steps_exactly(name: str, tmp_path: Path) -> None:
    ch = _character(name)
    lib = synthetic_library(ch, num_clips=2, seconds=0.3, seed=2)
    env = _env(ch, lib, seed=5)
    assert isinstance(env, SnapshotEnv)
    rng = np.random.default_rng(0)
    actions = rng.uniform(env.joint_low, env.joint_high, size=(WARMUP + K, NUM_ENVS, env.action_dim))
    env.reset(seed=5)
    _roll(env, actions[:WARMUP])
    state = env.get_state()
    if env.sim.servo:  # the native servo's pending commands are part of MuJoCo's state (history)
        assert env.sim.history_cols.shape == (ch.num_joints, ch.actuator.latency_steps)
        assert "sim/delay/buffer" not in state.arrays
    assert state.arrays["sim/state"].shape == (NUM_ENVS, env.sim.nstate)
    assert np.any(state.arrays["sim/warmstart"] != 0.0)
    expected = _roll(env, actions[WARMUP:])
    assert any(s["truncated"].any() or s["terminated"].any() for s in expected)  # resets happened
    assert any(s["clip_switched"].any() for s in expected)

    # the same env, restored in memory; and a fresh env (other seed, other episodes) from files
    env.set_state(state)
    again = _roll(env, actions[WARMUP:])
    fresh = _env(ch, lib, seed=99)
    fresh.reset(seed=99)
    _roll(fresh, actions[:3])
    fresh.set_state(_through_files(state, tmp_path))
    resumed = _roll(fresh, actions[WARMUP:])
    for run in (again, resumed):
        for t, (a, b) in enumerate(zip(expected, run, strict=True)):
            for key in a:
                np.testing.assert_array_equal(a[key], b[key], err_msg=f"{name} step {t}: {key}")
    env.close()
    fresh.close()


def test_snapshot_of_another_shape_is_refused() -> None:
    ch = _character("humanoid36")
    lib = synthetic_library(ch, num_clips=2, seconds=0.3, seed=2)
    big = TrackingEnv(ch, lib, num_envs=NUM_ENVS + 1, nthread=1)
    small = TrackingEnv(ch, lib, num_envs=NUM_ENVS, nthread=1)
    big.reset(seed=0)
    with pytest.raises(AmorError, match="shape"):
        small.set_state(big.get_state())
    state = big.get_state()
    del state.arrays["sim/state"]
    with pytest.raises(AmorError, match="sim"):
        big.set_state(state)
    big.close()
    small.close()


# --- end to end: an interrupted tracking run resumes bit-exactly ---------------------------------
LOSSES = ("loss/total", "loss/policy", "loss/value", "loss/entropy", "kl", "clip_fraction")


def _rows(out: Path) -> list[dict[str, str]]:
    with (out / "metrics.csv").open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("name", ["biped20", "humanoid36"])
def test_interrupted_tracking_run_resumes_bit_exactly(name: str, tmp_path: Path) -> None:
    ch = _character(name)
    lib = synthetic_library(ch, num_clips=2, seconds=0.3, seed=3)
    write_dataset(tmp_path / "ds.mcap", lib)
    config = merge(
        TrainConfig(),
        {
            "run": {"iterations": 2, "checkpoint_every": 10, "tensorboard": False, "threads": 1},
            "env": {"kind": "tracking", "character": name, "dataset": str(tmp_path / "ds.mcap"),
                    "num_envs": NUM_ENVS, "episode_seconds": 0.06},
            "network": {"actor_hidden": [16], "critic_hidden": [16]},
            "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 1},
        },
        "snapshot test",
    )  # fmt: skip
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        full = train_run(config, tmp_path / "full")
        part = train_run(config, tmp_path / "part", stop_after=1)
        assert part.interrupted and part.end_iteration == 1
        ckpt = load_checkpoint(list_checkpoints(tmp_path / "part" / "checkpoints")[-1][1])
        assert ckpt.iteration == 1 and ckpt.env is not None  # the env state went through the files
        assert "sim/state" in ckpt.env.arrays and "rng" in ckpt.env.meta
        assert "sim/delay/buffer" not in ckpt.env.arrays  # servo delays live in sim/state's history
        resumed = train_run(config, tmp_path / "part", resume=True)
    finally:
        torch.set_num_threads(threads)
    assert (full.end_iteration, resumed.start_iteration, resumed.end_iteration) == (2, 1, 2)
    a, b = _rows(tmp_path / "full"), _rows(tmp_path / "part")
    assert [r["iteration"] for r in a] == [r["iteration"] for r in b] == ["1.0", "2.0"]
    keys = [k for k in a[1] if k.startswith(("loss/", "return/", "explained_variance/")) or k in LOSSES]
    assert set(LOSSES) <= set(keys)
    for key in keys:
        assert a[1][key] == b[1][key], key
