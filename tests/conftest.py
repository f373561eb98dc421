"""Shared fixtures: a fresh plugin registry per test, so environment variables take effect."""

from __future__ import annotations

from pathlib import Path

import pytest

from amorctl.registry import reset_registry


@pytest.fixture(autouse=True)
def _fresh_registry(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.delenv("AMORCTL_BLOCK_PLUGINS", raising=False)
    monkeypatch.delenv("AMORCTL_TRACE_HOOKS", raising=False)
    monkeypatch.delenv("AMORCTL_DEBUG", raising=False)
    monkeypatch.delenv("AMORCTL_TOKEN", raising=False)  # live inputs: tests set their own token
    reset_registry()
    yield
    reset_registry()


# --- trained runs shared by the evaluation tests: trained once per session, in seconds ---
TOY_RUN_TOML = {
    "run": {"iterations": 150, "checkpoint_every": 150, "keep_checkpoints": 1, "tensorboard": False,
            "threads": 1},
    "env": {"kind": "toy", "num_envs": 64, "episode_seconds": 0.3},
    "network": {"actor_hidden": [32, 32], "critic_hidden": [32, 32], "init_std": 0.2},
    # fp32 pinned: "auto" picks bf16 on CPUs with AMX, and the fixture's figures must not depend on the CPU
    "ppo": {"num_steps": 16, "num_epochs": 4, "num_minibatches": 2, "learning_rate": 3e-3,
            "precision": "fp32"},
}  # fmt: skip


@pytest.fixture(scope="session")
def toy_run(tmp_path_factory: pytest.TempPathFactory):
    """A MOPPO policy trained on the two-objective toy env (``right`` / ``left``): its run directory."""
    import torch

    from amorctl.core.config import TrainConfig, merge
    from amorctl.train.loop import train_run

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("toy-run") / "run"
    try:
        train_run(merge(TrainConfig(), TOY_RUN_TOML, "toy_run fixture"), out)
    finally:
        torch.set_num_threads(threads)
    reset_registry()
    return out


@pytest.fixture(scope="session")
def toy_hlp_config():
    """A one-iteration HLP config for the toy run (tiny nets, the ``right`` objective as reward)."""
    from amorctl.hlp.config import HlpConfig, merge

    return merge(
        HlpConfig(),
        {
            "run": {"iterations": 1, "checkpoint_every": 1, "tensorboard": False, "threads": 1},
            "env": {"num_envs": 4, "episode_seconds": 0.3},
            "policy": {"actor_hidden": [8], "critic_hidden": [8]},
            "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 1},
            "discriminator": {"reward": "objective:right"},
        },
        "test",
    )


def train_tiny_tracking_run(
    root: Path, label: str, *, clip_names: tuple[str, ...] = ("sway_a", "sway_b"), **env: object
) -> Path:
    """Train ``root/run``: one iteration of biped20 on 1 s synthetic clips named ``clip_names``
    (``root/ds.mcap``), 4 envs, 16-wide networks, one torch thread; ``env`` overrides the
    ``[env]`` table (``episode_seconds`` 0.4 by default)."""
    import dataclasses

    import torch

    from amorctl.core.config import TrainConfig, merge
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.motion.dataset import write_dataset
    from amorctl.registry import get_registry
    from amorctl.train.loop import train_run

    biped20 = get_registry().character("biped20")
    lib = synthetic_library(biped20, num_clips=len(clip_names), seconds=1.0, seed=3)
    clips = tuple(dataclasses.replace(c, name=n) for c, n in zip(lib.clips, clip_names, strict=True))
    write_dataset(root / "ds.mcap", dataclasses.replace(lib, clips=clips))
    config = merge(
        TrainConfig(),
        {
            "run": {"iterations": 1, "checkpoint_every": 1, "tensorboard": False, "threads": 1},
            "env": {"kind": "tracking", "character": "biped20", "dataset": str(root / "ds.mcap"),
                    "num_envs": 4, "episode_seconds": 0.4, **env},
            "network": {"actor_hidden": [16], "critic_hidden": [16]},
            "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 1},
        },
        label,
    )  # fmt: skip
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        train_run(config, root / "run")
    finally:
        torch.set_num_threads(threads)
    reset_registry()
    return root / "run"


@pytest.fixture(scope="session")
def make_tracking_run():
    """:func:`train_tiny_tracking_run`, for test modules' own variants of :func:`tracking_run`."""
    return train_tiny_tracking_run


@pytest.fixture(scope="session")
def tracking_run(tmp_path_factory: pytest.TempPathFactory):
    """A tiny biped20 tracking run (one iteration) on two synthetic clips ``sway_a`` / ``sway_b``."""
    return train_tiny_tracking_run(tmp_path_factory.mktemp("tracking-run"), "tracking_run fixture")


# --- a trained toy-smooth run (the smooth-schedule test): `track` vs `smooth`, seconds ---
TOY_SMOOTH_RUN_TOML = {
    "run": {"iterations": 40, "checkpoint_every": 40, "keep_checkpoints": 1, "tensorboard": False,
            "threads": 1, "seed": 0},
    "env": {"kind": "toy-smooth", "num_envs": 64, "episode_seconds": 1.0},
    "network": {"actor_hidden": [32, 32], "critic_hidden": [32, 32], "init_std": 1.0},
    # fp32 pinned: "auto" picks bf16 on CPUs with AMX, and the fixture's figures must not depend on the CPU
    "ppo": {"num_steps": 16, "num_epochs": 4, "num_minibatches": 2, "learning_rate": 3e-3,
            "precision": "fp32"},
}  # fmt: skip


@pytest.fixture(scope="session")
def toy_smooth_run(tmp_path_factory: pytest.TempPathFactory):
    """A MOPPO policy on the toy-smooth env (``track`` / ``smooth``): it follows the jumping
    target under w = (1, 0) and holds its action still under w = (0, 1). Its run directory."""
    import torch

    from amorctl.core.config import TrainConfig, merge
    from amorctl.train.loop import train_run

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("toy-smooth-run") / "run"
    try:
        train_run(merge(TrainConfig(), TOY_SMOOTH_RUN_TOML, "toy_smooth_run fixture"), out)
    finally:
        torch.set_num_threads(threads)
    reset_registry()
    return out
