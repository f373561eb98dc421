"""What a training episode tracks when its clip ends (``[env] clip_continuation``): a random
clip (the default) or its own clip again, as evaluation loops one; evaluation never uses it."""

from __future__ import annotations

import numpy as np
import pytest

from amorctl.analysis.eval_env import make_eval_env
from amorctl.core.config import TrainConfig, merge, override
from amorctl.core.errors import AmorError
from amorctl.core.levers import check_backend_levers, levers_in_use
from amorctl.envs.synthetic import synthetic_library
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.registry import get_registry
from amorctl.train.rundir import RunDir


def _clip_ends_seen(continuation: str, steps: int = 120) -> tuple[list[tuple[int, int]], TrackingEnv]:
    """(clip before, clip after) of every clip switch in ``steps`` steps of 16 envs tracking 4
    short clips with the reference as the action (so episodes run into their clips' ends)."""
    ch = get_registry().character("biped20")
    lib = synthetic_library(ch, num_clips=4, seconds=0.5, seed=2)
    env = TrackingEnv(
        ch, lib, num_envs=16, nthread=1, seed=3, action_mode="residual", clip_continuation=continuation
    )
    env.reset(seed=3)
    switches = []
    for _ in range(steps):
        before = env.clip_id.copy()
        _, _, terminated, truncated, info = env.step(np.zeros((16, ch.num_joints)))
        moved = info["clip_switched"] & ~(terminated | truncated)
        switches += [(int(a), int(b)) for a, b in zip(before[moved], env.clip_id[moved], strict=True)]
        starts = env.clip_starts[env.clip_id[moved]]
        np.testing.assert_array_equal(env.ref_idx[moved], starts)  # from the clip's first frame
    return switches, env


def test_same_keeps_the_clip_and_random_draws_another() -> None:
    same, env = _clip_ends_seen("same")
    assert len(same) > 20
    assert all(a == b for a, b in same)
    env.close()
    random, env = _clip_ends_seen("random")
    assert len(random) > 20
    assert sum(a != b for a, b in random) > len(random) / 2  # 3 in 4 draws land on another clip
    env.close()
    with pytest.raises(AmorError, match="clip_continuation must be one of random, same"):
        TrackingEnv(
            "biped20",
            synthetic_library(get_registry().character("biped20"), num_clips=1, seconds=0.5),
            num_envs=1,
            nthread=1,
            clip_continuation="loop",
        )


def test_config_asks_the_backend_and_evaluation_never_uses_it(tracking_run) -> None:
    config = override(TrainConfig(), env__clip_continuation="same")
    assert levers_in_use(config)["clip_continuation"] == "[env] clip_continuation = 'same'"
    assert "clip_continuation" not in levers_in_use(TrainConfig())
    check_backend_levers(config, get_registry().backend("torch-cpu").levers)
    with pytest.raises(AmorError, match="clip_continuation = 'same' needs a backend that implements it"):
        check_backend_levers(config, get_registry().backend("jax-mjx").levers)
    with pytest.raises(AmorError, match="clip_continuation needs the tracking env"):
        merge(TrainConfig(), {"env": {"kind": "toy", "clip_continuation": "same"}}, "test")
    with pytest.raises(AmorError, match="clip_continuation"):
        merge(TrainConfig(), {"env": {"clip_continuation": "loop"}}, "test")

    run = RunDir.open(tracking_run)
    trained = override(run.config, env__clip_continuation="same")
    env, _ = make_eval_env(trained, 4)
    try:
        assert env.clip_continuation == "random"
    finally:
        env.close()
    assert run.env_config(num_envs=2).env.clip_continuation == "random"
