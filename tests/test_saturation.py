"""amorctl.analysis.saturation: joint-steps at a servo's current or speed limit, counted by hand."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import saturation as saturation_script
import stage as stage_script
from test_stage import tiny_config

from amorctl.analysis.saturation import before_falls, saturation
from amorctl.registry import get_registry
from amorctl.train.loop import train_run
from amorctl.train.rundir import RunDir


def test_saturation_counts_current_and_speed_limits_per_joint() -> None:
    limit, no_load = np.array([4.0, 2.0]), 5.0
    # T=2 steps, N=2 envs, S=2 substeps, J=2 joints
    torque = np.zeros((2, 2, 2, 2))
    torque[0, 0, 1, 0] = -3.9  # 97.5 % of joint 0's stall torque in one substep: current limit
    torque[1, 0, 0, 1] = 1.8  # 90 % of joint 1's: below the 95 % threshold
    joint_vel = np.zeros((2, 2, 2))
    joint_vel[1, 1, 1] = -4.6  # 92 % of no-load speed: speed limit
    joint_vel[0, 1, 0] = 4.4  # 88 %: below
    counted = np.ones((2, 2), dtype=bool)
    s = saturation(torque, joint_vel, counted, limit, no_load)
    np.testing.assert_allclose(s.current, [0.25, 0.0])
    np.testing.assert_allclose(s.speed, [0.0, 0.25])
    np.testing.assert_allclose(s.either, [0.25, 0.25])
    assert s.any_joint == 0.5 and s.steps == 4

    counted[0, 0] = False  # the step at the current limit no longer counts
    s = saturation(torque, joint_vel, counted, limit, no_load)
    np.testing.assert_allclose(s.either, [0.0, 1 / 3])
    assert s.steps == 3

    pd = saturation(torque, joint_vel, np.ones((2, 2), dtype=bool), limit, None)  # PD: no speed limit
    np.testing.assert_allclose(pd.speed, [0.0, 0.0])
    assert pd.any_joint == 0.25
    empty = saturation(torque, joint_vel, np.zeros((2, 2), dtype=bool), limit, no_load)
    assert empty.steps == 0 and np.isnan(empty.any_joint)


def test_before_falls_takes_the_last_steps_of_the_falling_episode_only() -> None:
    # env 0: episode 0 for steps 0-1, then episode 2 falls at step 4; env 1: episode 1 never falls
    episode_id = np.array([[0, 1], [0, 1], [2, 1], [2, 1], [2, 1], [-1, 1]])
    terminated = np.zeros((6, 2), dtype=bool)
    terminated[1, 0] = False
    terminated[4, 0] = True
    terminated[5, 0] = True  # not counted (episode -1): ignored
    got = before_falls(terminated, episode_id, window=4)
    expected = np.zeros((6, 2), dtype=bool)
    expected[2:5, 0] = True  # steps 1-4 are the window, but step 1 belongs to episode 0
    np.testing.assert_array_equal(got, expected)


def test_the_benchmark_measures_on_the_same_starts_as_the_stage_evaluation(tmp_path: Path) -> None:
    train_run(tiny_config(tmp_path), tmp_path / "run")
    run = RunDir.open(tmp_path / "run")
    expected = stage_script.evaluate_clips(run, episodes=2, seed=1)
    rows = saturation_script.measure(run, list(expected), episodes=2, seed=1, window_s=0.1)
    assert list(rows) == list(expected)
    for clip, row in rows.items():
        assert row["survival"] == expected[clip]["survival"]
        assert row["joint_mae_deg"] == expected[clip]["joint_mae_deg"]
        assert 0.0 <= row["any_joint"] <= 1.0
        assert row["worst_joint"] in get_registry().character("biped20").joint_names()
