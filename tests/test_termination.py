"""Termination on tracking error (``[env] termination_distance``): the error is the largest
root-relative end-effector or root-height error; training episodes end beyond the distance;
evaluation, sweeps and tuning never use it."""

from __future__ import annotations

import numpy as np
import pytest

from amorctl.analysis.eval_env import make_eval_env
from amorctl.core.config import TrainConfig, merge, override
from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import frame_dim, split_frame
from amorctl.core.levers import check_backend_levers, levers_in_use
from amorctl.core.termination import far_from_reference, tracking_error
from amorctl.envs.synthetic import synthetic_library
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.registry import get_registry
from amorctl.train.rundir import RunDir


def test_the_error_is_the_worst_end_effector_or_the_root_height() -> None:
    j, e = 2, 2
    sim, ref = np.zeros((3, frame_dim(j, e))), np.zeros((3, frame_dim(j, e)))
    ee = 13 + 2 * j  # first end effector's position; the second's is 9 entries later
    sim[0, ee : ee + 3] = [0.3, 0.4, 0.0]  # 0.5 m off
    sim[0, ee + 9 + 2] = 0.2  # the other end effector 0.2 m
    sim[1, 0], ref[1, 0] = 0.9, 0.5  # root height 0.4 m off
    sim[2, 13:17] = 9.0  # joints and their velocities do not count
    parts = split_frame(sim, j, e), split_frame(ref, j, e)
    np.testing.assert_allclose(tracking_error(*parts), [0.5, 0.4, 0.0])
    assert far_from_reference(*parts, 0.45).tolist() == [True, False, False]
    assert not far_from_reference(*parts, 0.0).any()  # 0: off


def _env(distance: float) -> TrackingEnv:
    ch = get_registry().character("biped20")
    lib = synthetic_library(ch, num_clips=2, seconds=2.0, seed=1)
    return TrackingEnv(ch, lib, num_envs=32, nthread=1, seed=5, termination_distance=distance)


def test_the_env_ends_exactly_the_episodes_that_drift_past_the_distance() -> None:
    actions = np.random.default_rng(0).uniform(-0.6, 0.6, size=(32, 20))
    plain = _env(0.0)
    plain.reset(seed=5)
    _, rewards0, term0, _, info0 = plain.step(actions)
    sim = split_frame(plain._sim_frames(), plain.num_joints, plain.num_ee)
    ref = split_frame(plain.ref_frames[plain.ref_idx], plain.num_joints, plain.num_ee)
    error = tracking_error(sim, ref)
    distance = float(np.median(error))  # half the batch drifts farther: both outcomes occur
    strict = _env(distance)
    strict.reset(seed=5)  # the same starts: the same physics on the first step
    _, rewards, term, _, info = strict.step(actions)
    expected = (error > distance) & ~info0["fell"]
    assert 0 < expected.sum() < 32
    np.testing.assert_array_equal(info["far"], expected)
    np.testing.assert_array_equal(term, term0 | expected)
    bonus = plain.reward_space.survival_bonus  # an ended episode forgoes its survival bonus
    assert bonus > 0
    np.testing.assert_allclose(rewards0[expected] - rewards[expected], bonus, atol=1e-6)
    np.testing.assert_array_equal(rewards0[~expected], rewards[~expected])
    with pytest.raises(AmorError, match="termination_distance"):
        _env(-1.0)
    plain.close()
    strict.close()


def test_config_asks_the_backend_and_evaluation_never_uses_it(tracking_run) -> None:
    config = override(TrainConfig(), env__termination_distance=0.3)
    assert levers_in_use(config)["termination_distance"] == "[env] termination_distance = 0.3"
    check_backend_levers(config, get_registry().backend("torch-cpu").levers)
    assert "termination_distance" in get_registry().backend("jax-mjx").levers  # both backends
    with pytest.raises(AmorError, match="termination_distance needs the tracking env"):
        merge(TrainConfig(), {"env": {"kind": "toy", "termination_distance": 0.3}}, "test")
    with pytest.raises(AmorError, match="termination_distance"):
        merge(TrainConfig(), {"env": {"termination_distance": -0.1}}, "test")

    run = RunDir.open(tracking_run)
    trained = override(run.config, env__termination_distance=0.3, env__adaptive_starts=0.5)
    env, _ = make_eval_env(trained, 4)
    try:
        assert env.termination_distance == 0.0 and env.start_sampler is None
    finally:
        env.close()
    rebuilt = run.env_config(num_envs=2)
    assert rebuilt.env.termination_distance == 0.0 and rebuilt.env.adaptive_starts == 0.0
