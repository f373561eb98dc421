"""Adaptive episode starts (``[env] adaptive_starts``): falls counted per clip and phase bin,
spread backward, drawn in proportion; the tracking env's starts follow them and resume exactly."""

from __future__ import annotations

import numpy as np
import pytest

from amorctl.core.config import TrainConfig, merge, override
from amorctl.core.env_random import BatchRandom
from amorctl.core.errors import AmorError
from amorctl.core.levers import check_backend_levers, levers_in_use
from amorctl.envs import start_sampling
from amorctl.envs.start_sampling import StartSampler
from amorctl.envs.synthetic import synthetic_library
from amorctl.envs.tracking_env import TrackingEnv
from amorctl.registry import get_registry

RATE = start_sampling.FALL_RATE


def _two_clips() -> StartSampler:
    # clip 0: frames 0-9 (starts 0-8), clip 1: frames 10-15 (starts 10-14); bins of 4 frames
    return StartSampler(np.array([0, 10]), np.array([10, 16]), bin_frames=4, fraction=1.0)


def test_bins_cover_every_start_frame_of_every_clip() -> None:
    s = _two_clips()
    assert s.bin_lo.tolist() == [0, 4, 8, 10, 14]
    assert s.bin_hi.tolist() == [4, 8, 9, 14, 15]
    assert s.bin_clip.tolist() == [0, 0, 0, 1, 1]
    assert s.frame_bin.tolist() == [0] * 4 + [1] * 4 + [2, -1] + [3] * 4 + [4, -1]


def test_bins_as_long_as_the_clips_weight_whole_clips_by_their_falls() -> None:
    """Clip weighting is adaptive starts with one bin per clip: a clip is drawn in proportion to
    its falls, its start frame uniform over the clip (RSI within it)."""
    s = StartSampler(np.array([0, 10]), np.array([10, 16]), bin_frames=3000, fraction=1.0)
    assert s.bin_lo.tolist() == [0, 10] and s.bin_hi.tolist() == [9, 15]
    s.record(np.array([2, 7, 12]))  # two falls in clip 0, one in clip 1
    np.testing.assert_allclose(s.probabilities(np.array([0, 1])), [2 / 3, 1 / 3])
    ids = np.arange(6000)
    _, clips, frames = s.draw(BatchRandom(np.random.default_rng(0)), ids, np.array([0, 1]))
    assert abs(np.mean(clips == 0) - 2 / 3) < 0.03
    assert set(frames[clips == 0].tolist()) == set(range(0, 9))  # every start frame of the clip
    assert set(frames[clips == 1].tolist()) == set(range(10, 15))


def test_falls_spread_backward_within_their_clip_only() -> None:
    s = _two_clips()
    assert s.probabilities(np.array([0, 1])) is None  # no fall yet: plain RSI
    s.record(np.array([5, 9]))  # frame 9 is clip 0's last frame: no bin
    assert s.falls.tolist() == [0.0, RATE, 0.0, 0.0, 0.0]
    np.testing.assert_allclose(s.probabilities(np.array([0, 1])), [1 / 3, 2 / 3, 0, 0, 0])
    s.record(np.array([10]))  # clip 1's first bin: nothing spills into clip 0's last bin
    f1, f3 = (1 - RATE) * RATE, RATE
    expected = np.array([0.5 * f1, f1, 0.0, f3, 0.0])
    np.testing.assert_allclose(s.probabilities(np.array([0, 1])), expected / expected.sum())
    np.testing.assert_allclose(s.probabilities(np.array([1])), [0, 0, 0, 1, 0])  # selected clips only


def test_draws_follow_the_probabilities_and_stay_inside_their_bins() -> None:
    s = _two_clips()
    s.record(np.array([5]))
    rand = BatchRandom(np.random.default_rng(0))
    chosen, clips, frames = s.draw(rand, np.arange(6000), np.array([0, 1]))
    assert len(chosen) == 6000 and (clips == 0).all()  # fraction 1: every start
    assert ((frames >= 0) & (frames < 8)).all()
    assert np.mean(frames >= 4) == pytest.approx(2 / 3, abs=0.03)
    half = StartSampler(np.array([0, 10]), np.array([10, 16]), 4, fraction=0.25)
    half.record(np.array([5]))
    chosen, _, _ = half.draw(rand, np.arange(8000), np.array([0, 1]))
    assert len(chosen) / 8000 == pytest.approx(0.25, abs=0.02)
    none, _, _ = half.draw(rand, np.arange(100), np.array([1]))  # no fall on the selected clip
    assert len(none) == 0


def test_state_round_trips_and_bad_state_is_refused() -> None:
    s, t = _two_clips(), _two_clips()
    s.record(np.array([1, 12]))
    t.load_state(s.state())
    np.testing.assert_array_equal(s.falls, t.falls)
    for bad in ({"falls": [0.0] * 4}, {"falls": [float("nan")] * 5}, {"falls": [-1.0] * 5}):
        with pytest.raises(AmorError, match="adaptive-start"):
            t.load_state(bad)
    with pytest.raises(AmorError, match="fraction"):
        StartSampler(np.array([0]), np.array([10]), 4, fraction=0.0)


def _env(fraction: float, seed: int = 3) -> TrackingEnv:
    ch = get_registry().character("biped20")
    lib = synthetic_library(ch, num_clips=3, seconds=2.0, seed=1)
    return TrackingEnv(
        ch, lib, num_envs=64, nthread=1, seed=seed, adaptive_starts=fraction, start_bin_seconds=0.4
    )


def test_the_tracking_env_starts_where_its_policy_falls_and_resumes_exactly() -> None:
    env = _env(1.0)
    env.reset(seed=3)
    sampler = env.start_sampler
    assert sampler is not None
    hard = np.flatnonzero(sampler.bin_clip == 1)[2]  # the third bin of the second clip (full length)
    sampler.record(np.full(10, sampler.bin_lo[hard]))
    env._reset_envs(np.arange(env.num_envs))
    lo, hi = sampler.bin_lo[hard], sampler.bin_hi[hard]
    back = sampler.bin_lo[hard - 2]  # the kernel reaches two bins back
    assert (env.clip_id == sampler.bin_clip[hard]).all()
    assert ((env.ref_idx >= back) & (env.ref_idx < hi)).all()
    assert np.mean(env.ref_idx >= lo) == pytest.approx(1 / 1.75, abs=0.15)

    # falls are recorded by step(): big actions topple the robot; the state resumes exactly
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1.5, 1.5, size=(40, env.num_envs, env.action_dim))
    for a in actions[:20]:
        env.step(a)
    assert sampler.falls.sum() > 0
    state = env.get_state()
    assert state.meta["start_sampler"] == sampler.state()
    expected = [env.step(a)[0] for a in actions[20:]]
    other = _env(1.0, seed=9)
    other.reset(seed=9)
    other.set_state(state)
    for t, a in enumerate(actions[20:]):
        np.testing.assert_array_equal(other.step(a)[0], expected[t], err_msg=f"step {t}")
    np.testing.assert_array_equal(other.start_sampler.falls, sampler.falls)
    plain = _env(0.0)
    plain.reset(seed=3)
    assert plain.start_sampler is None and "start_sampler" not in plain.get_state().meta
    with pytest.raises(AmorError, match="adaptive-start"):
        other.set_state(plain.get_state())
    for e in (env, other, plain):
        e.close()


def test_plain_rsi_is_unchanged_by_the_option_at_zero() -> None:
    a, b = _env(0.0, seed=4), _env(0.0, seed=4)
    a.reset(seed=4)
    b.reset(seed=4)
    np.testing.assert_array_equal(a.ref_idx, b.ref_idx)
    a.close()
    b.close()


def test_config_asks_the_backend_for_the_lever_and_the_tracking_env() -> None:
    config = override(TrainConfig(), env__adaptive_starts=0.5)
    assert levers_in_use(config)["adaptive_starts"] == "[env] adaptive_starts = 0.5"
    check_backend_levers(config, get_registry().backend("torch-cpu").levers)
    jax_levers = get_registry().backend("jax-mjx").levers  # declared without importing jax
    assert "adaptive_starts" not in jax_levers
    with pytest.raises(AmorError, match=r"adaptive_starts = 0\.5 needs a backend"):
        check_backend_levers(override(config, run__backend="jax-mjx"), jax_levers)
    with pytest.raises(AmorError, match="adaptive_starts needs the tracking env"):
        merge(TrainConfig(), {"env": {"kind": "toy", "adaptive_starts": 0.5}}, "test")
    with pytest.raises(AmorError, match="adaptive_starts"):
        merge(TrainConfig(), {"env": {"adaptive_starts": 1.5}}, "test")


def test_a_training_run_carries_the_falls_in_its_checkpoint(make_tracking_run, tmp_path) -> None:
    from amorctl.train.checkpoint import list_checkpoints, load_checkpoint

    run = make_tracking_run(tmp_path, "adaptive starts", adaptive_starts=0.5, start_bin_seconds=0.2)
    env_state = load_checkpoint(list_checkpoints(run / "checkpoints")[-1][1]).env
    assert env_state is not None
    falls = env_state.meta["start_sampler"]["falls"]
    assert len(falls) == 10  # two 1 s clips of 5 bins of 0.2 s each
    assert "adaptive_starts = 0.5" in (run / "config.toml").read_text()
