"""The action rate and joint-velocity RMS a weight sweep reports per level (analysis.smoothness)."""

import numpy as np
import pytest

from amorctl.analysis.smoothness import MotionSums, smoothness_per_env, step_pairs


def test_step_pairs_skip_episode_ends_and_clip_switches() -> None:
    valid = np.array([[1, 1], [1, 1], [1, 1], [1, 0]], dtype=bool)
    episode = np.array([[0, 1], [0, 1], [0, 1], [0, -1]])
    frames = np.array([[5, 9], [6, 10], [20, 11], [21, 12]])  # env 0 switches clip at t = 2
    pairs = step_pairs(valid, episode, frames)
    assert pairs.tolist() == [[False, False], [True, True], [False, True], [True, False]]


def test_smoothness_uses_pd_targets_and_finite_differences() -> None:
    t, n, j = 3, 2, 2
    actions = np.zeros((t, n, j))
    actions[1, 0] = [0.1, 0.0]  # env 0: action jumps by 0.1 on one joint at t = 1
    ref = np.zeros((t, n, j))
    ref[:, 1, 0] = [0.0, 0.2, 0.4]  # env 1: the reference moves: residual targets move with it
    q = np.zeros((t, n, j))
    q[:, 0, 1] = [0.0, 0.02, 0.04]  # env 0: 0.02 rad per 0.02 s = 1 rad/s on one joint
    pairs = np.array([[False, False], [True, True], [True, True]])
    rate, vel2 = smoothness_per_env(actions, q, ref, pairs, 0.02, residual=True)
    assert rate == pytest.approx([0.01 + 0.01, 0.04 + 0.04])
    assert vel2 == pytest.approx([2.0, 0.0])
    absolute, _ = smoothness_per_env(actions, q, ref, pairs, 0.02, residual=False)
    assert absolute == pytest.approx([0.02, 0.0])
    by = MotionSums(rate, vel2, pairs.sum(0), joints=j).to_dict()  # one env per level
    assert by["action_rate"] == pytest.approx([0.01, 0.04])
    assert by["joint_vel_rms"] == pytest.approx([np.sqrt(2.0 / 4), 0.0])
    assert by["action_rate_falls"] is False and by["joint_vel_rms_falls"] is True


def test_motion_sums_add_up_over_disjoint_episodes_and_skip_joints_for_gym_envs() -> None:
    a = MotionSums(np.array([2.0, 1.0]), np.array([8.0, 2.0]), np.array([2, 2]), joints=2)
    b = MotionSums(np.array([2.0, 0.0]), np.array([0.0, 0.0]), np.array([2, 2]), joints=2)
    d = (a + b).to_dict()
    assert d["action_rate"] == pytest.approx([1.0, 0.25])
    assert d["joint_vel_rms"] == pytest.approx([np.sqrt(8.0 / 8), np.sqrt(2.0 / 8)])
    assert d["step_pairs"] == [4, 4] and d["action_rate_falls"] is True
    no_joints = MotionSums(np.array([1.0, 2.0]), np.zeros(2), np.array([1, 1]), joints=None).to_dict()
    assert no_joints["joint_vel_rms"] is None and no_joints["action_rate_falls"] is False
