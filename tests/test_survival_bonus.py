"""A survival bonus of another size (``[env] survival_bonus_scale``): every objective's bonus is
scaled on the steps that do not terminate, the tracking terms are not; the reward space follows;
the config asks the backend; evaluation, sweeps and tuning never use it."""

from __future__ import annotations

import numpy as np
import pytest

from amorctl.analysis.eval_env import make_eval_env
from amorctl.core.config import TrainConfig, merge, override
from amorctl.core.errors import AmorError
from amorctl.core.levers import check_backend_levers, levers_in_use
from amorctl.envs.survival_bonus import ScaledSurvivalBonus, scale_survival_bonus
from amorctl.envs.synthetic import synthetic_library
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.registry import get_registry
from amorctl.train.rundir import RunDir


def _env(scale: float) -> TrackingEnv:
    ch = get_registry().character("biped20")
    lib = synthetic_library(ch, num_clips=2, seconds=2.0, seed=1)
    return TrackingEnv(ch, lib, num_envs=32, nthread=1, seed=5, survival_bonus_scale=scale)


@pytest.mark.parametrize("scale", [0.0, 0.25, 3.0])
def test_only_the_bonus_changes_and_only_where_the_step_goes_on(scale: float) -> None:
    actions = np.random.default_rng(0).uniform(-1.5, 1.5, size=(32, 20))  # hard enough to fall
    plain, scaled = _env(1.0), _env(scale)
    c = plain.reward_space.survival_bonus
    assert c == 1.0 and scaled.reward_space.survival_bonus == pytest.approx(scale * c)
    np.testing.assert_allclose(scaled.reward_space.high, plain.reward_space.high + (scale - 1) * c)
    np.testing.assert_array_equal(scaled.reward_space.low, plain.reward_space.low)
    plain.reset(seed=5)
    scaled.reset(seed=5)
    ended = np.zeros(32, dtype=bool)
    for _ in range(30):  # the same starts and actions: the same physics, step by step
        _, r0, term0, _, _ = plain.step(actions)
        _, r1, term1, _, _ = scaled.step(actions)
        np.testing.assert_array_equal(term0, term1)
        expected = r0 + np.where(term0, 0.0, (scale - 1) * c)[:, None]
        np.testing.assert_allclose(r1, expected, atol=1e-5)
        ended |= term0
    assert 0 < ended.sum() < 32  # both kinds of step were compared
    plain.close()
    scaled.close()


def test_scale_one_is_the_set_itself_and_bad_scales_are_refused() -> None:
    objectives = get_registry().objective_set("tracking7").make(get_registry().character("biped20"))
    assert scale_survival_bonus(objectives, 1.0) is objectives
    assert isinstance(scale_survival_bonus(objectives, 0.5), ScaledSurvivalBonus)
    for bad in (-0.5, float("nan"), float("inf")):
        with pytest.raises(AmorError, match="survival_bonus_scale"):
            scale_survival_bonus(objectives, bad)
    objectives.alive_bonus = 0.0  # a set without a bonus has nothing to scale
    with pytest.raises(AmorError, match="needs an objective set with a survival bonus"):
        scale_survival_bonus(objectives, 0.5)


def test_config_asks_the_backend_and_evaluation_never_uses_it(tracking_run) -> None:
    config = override(TrainConfig(), env__survival_bonus_scale=0.25)
    assert levers_in_use(config)["survival_bonus_scale"] == "[env] survival_bonus_scale = 0.25"
    check_backend_levers(config, get_registry().backend("torch-cpu").levers)
    with pytest.raises(AmorError, match=r"survival_bonus_scale = 0\.25 needs a backend"):
        check_backend_levers(config, get_registry().backend("jax-mjx").levers)
    with pytest.raises(AmorError, match="survival_bonus_scale needs the tracking env"):
        merge(TrainConfig(), {"env": {"kind": "toy", "survival_bonus_scale": 0.5}}, "test")
    with pytest.raises(AmorError, match="survival_bonus_scale"):
        merge(TrainConfig(), {"env": {"survival_bonus_scale": -0.1}}, "test")
    with pytest.raises(AmorError, match="survival_channel = true needs a survival bonus"):
        no_bonus_with_channel = {"env": {"survival_bonus_scale": 0.0}, "ppo": {"survival_channel": True}}
        merge(TrainConfig(), no_bonus_with_channel, "test")

    run = RunDir.open(tracking_run)
    env, _ = make_eval_env(override(run.config, env__survival_bonus_scale=0.25), 4)
    try:
        assert env.reward_space.survival_bonus == 1.0
    finally:
        env.close()
    assert run.env_config(num_envs=2).env.survival_bonus_scale == 1.0
