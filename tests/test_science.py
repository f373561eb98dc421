"""The pure helpers of benchmarks/science.py (weight-response statistics, report): fast, no training."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import science_report as sr


def test_level_stats_monotonic_effect_size_and_survival() -> None:
    returns = np.array([[1.0, 3.0], [3.0, 5.0], [6.0, 8.0]])  # means 2, 4, 7; std at low level 1
    s = sr.level_stats([0.0, 0.5, 1.0], returns, [1.0, 0.95, 0.9])
    assert s["mean"] == [2.0, 4.0, 7.0]
    assert s["monotonic"] is True
    assert s["effect_size"] == pytest.approx(5.0)
    assert s["min_survival"] == 0.9
    s["spearman_rho"] = 0.92
    assert sr.sweep_passes(s)
    s["spearman_rho"] = 0.85
    assert not sr.sweep_passes(s)


def test_level_stats_not_monotonic_and_no_spread() -> None:
    s = sr.level_stats([0, 0.5, 1], np.array([[2.0, 2.0], [5.0, 5.0], [4.0, np.nan]]), [1, 1, 0.5])
    assert s["monotonic"] is False
    assert s["effect_size"] is None  # the low level has no spread
    s["spearman_rho"] = 0.99
    assert not sr.sweep_passes(s)  # not monotonic, and survival 0.5


def test_survivors_rho_leaves_fallen_episodes_out() -> None:
    import science_measure as sm

    levels = np.array([0.0, 0.5, 1.0])
    returns = np.array([[10.0, 11.0], [12.0, 13.0], [14.0, 2.0]])  # the last episode fell early
    survived = np.array([[True, True], [True, True], [True, False]])
    assert sm.survivors_rho(levels, returns, survived) == pytest.approx(0.9487, abs=1e-3)
    everyone = np.ones_like(survived)
    assert sm.survivors_rho(levels, returns, everyone) < 0.6  # the fall drags the all-episode ρ
    assert sm.survivors_rho(levels, returns, None) is None
    assert sm.survivors_rho(levels, returns, np.zeros_like(survived)) is None


def test_set_options_reach_the_config_and_the_protocol(tmp_path) -> None:
    import argparse

    import science

    argv = ["--out", str(tmp_path), "--doc", str(tmp_path / "s.md"), "--budget-minutes", "1"]
    args = science.parse_args(
        [*argv, "--preset", "science_sc", "--set", "ppo.survival_weight=2", "--set", "env.num_envs=64"]
    )
    assert args.set == {"ppo__survival_weight": 2, "env__num_envs": 64}
    assert args.set_text == ["ppo.survival_weight=2", "env.num_envs=64"]
    config = science.Science(args).base_config()
    assert (config.ppo.survival_weight, config.env.num_envs, config.ppo.survival_channel) == (2.0, 64, True)
    assert (
        "`science_sc` preset with `ppo.survival_weight=2`, `env.num_envs=64`"
        in science.Science(args).protocol()
    )
    for bad in ("ppo.survival_weight=", "survival_weight=2", "ppo.x=[1,"):
        with pytest.raises(argparse.ArgumentTypeError):
            science.config_setting(bad)


def test_weights_reference_and_iterations() -> None:
    w = sr.corner_heavy_weights(7, 0.7)
    assert np.allclose(w.sum(1), 1) and np.allclose(np.diag(w), 0.7) and np.isclose(w[0, 1], 0.05)
    assert sr.hv_reference(3, 500, 2).tolist() == [500.0, 500.0, 0.0]
    assert sr.common_iterations([25, 50, 75, 100], [25, 50, 60], 8) == [25, 50]
    picked = sr.common_iterations(list(range(25, 1001, 25)), list(range(25, 1001, 25)), 5)
    assert len(picked) == 5 and picked[0] == 25 and picked[-1] == 1000


def test_report_renders_partial_results_with_verdicts_and_rerun_commands() -> None:
    results = {
        "meta": {"command": "python benchmarks/science.py", "rerun": {"front": "python x --only front"}},
        "skipped": {"front": "the run's deadline came first"},
        "bar": {
            "episodes": 4,
            "seed": 1,
            "uniform": {"weights": "u", "survival_rate": 0.95, "joint_mae_deg": 9.0, "mpjpe_mm": 1.0,
                        "episode_length_s": 10.0},
            "tracking_heavy": {"weights": "t", "survival_rate": 0.9, "joint_mae_deg": 8.0, "mpjpe_mm": 1.0,
                               "episode_length_s": 10.0},
        },
    }  # fmt: skip
    md = sr.render_markdown(results, "## Protocol\n\ntext")
    assert "| learning bar: survival over 10 s ≥ 90 % (uniform w) | 0.95 | **pass** |" in md
    assert "8° vs 9° | **pass** |" in md
    assert "_Not measured (the run's deadline came first)._ To measure it: `python x --only front`" in md
    assert "| claim (i) | not measured | – |" in md


def test_report_explains_fallen_fixed_policies_and_names_the_training_command() -> None:
    kfixed = {"heavy": 0.7, "iterations_each": 10, "env_steps_total": 7000, "moppo_env_steps": 7000,
              "episodes": 8, "motion": "walk", "hv_fixed_7": 0.0, "hv_amor_7": 0.5, "hv_amor_front": 0.6,
              "survival_fixed": [0, 0, 0, 0, 0, 0.125, 0], "survival_amor": [1.0] * 7}  # fmt: skip
    curve = [(500, 0.1), (2000, 0.84), (3000, 1.0)]
    reading = " ".join(
        sr._kfixed_reading(
            kfixed, {"rows": [{"env_steps": n, "ppo_uniform": {"survival": s}} for n, s in curve]}
        )
    )
    assert "each trained on 1,000 env steps; the uniform-w PPO run" in reading
    assert "first survived ≥ 80 % at 2,000 env steps" in reading
    made_by = {"command": "python science.py --only train", "commit": "abc", "date_utc": "d"}
    train = {
        "run": "r",
        "weights": "MOPPO",
        "iterations": 7,
        "env_steps": 7000,
        "wall_s": 60.0,
        "made_by": made_by,
    }
    results = {
        "meta": {"command": "python science.py --only kfixed", "other_report": "[h36](science-h36.md)"},
        "train": train,
        "kfixed": kfixed,
    }
    md = sr.render_markdown(results, "")
    assert "Most fixed-weight policies fell: with the env steps split 7 ways, each trained on 1,000" in md
    assert "The MOPPO run was trained by `python science.py --only train` (commit `abc`, d)." in md
    assert "Measured in a run of its own: [h36](science-h36.md)" in md
    kfixed["survival_fixed"] = [1.0] * 7  # the fixed-weight policies walk: no such reading
    results["meta"]["command"] = made_by["command"]  # trained by the command of this report
    md = sr.render_markdown(results, "")
    assert "Most fixed-weight policies fell" not in md and "was trained by" not in md


def test_env_step_budgets_end_training_at_the_same_steps_on_any_machine(tmp_path) -> None:
    """``--budget-steps``: training stops at the first iteration reaching the budget (the run's
    total over resumed segments), however fast the machine is."""
    import science_runs

    from amorctl.core.config import TrainConfig, merge
    from amorctl.train.rundir import RunDir

    config = merge(
        TrainConfig(),
        {
            "run": {"iterations": 1000, "checkpoint_every": 1, "tensorboard": False, "threads": 1},
            "env": {"kind": "toy", "num_envs": 8, "episode_seconds": 0.2},
            "network": {"actor_hidden": [8], "critic_hidden": [8]},
            "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 1},
        },
        "test",
    )  # 32 env steps per iteration
    out = tmp_path / "run"
    science_runs.train(config, out, budget_s=None, stop_at=float("inf"), label="t", budget_steps=100)
    assert RunDir.open(out).checkpoint().trainer.meta["env_steps"] == 128  # 4 iterations: 128 >= 100
    science_runs.train(config, out, budget_s=None, stop_at=float("inf"), label="t", budget_steps=100)
    assert RunDir.open(out).checkpoint().trainer.meta["env_steps"] == 128  # spent: nothing more
    science_runs.train(config, out, budget_s=None, stop_at=float("inf"), label="t", budget_steps=200)
    assert RunDir.open(out).checkpoint().trainer.meta["env_steps"] == 224  # continues to 7 iterations


def test_run_option_measures_a_trained_run_on_its_walking_clips_only(
    tmp_path, capsys, make_tracking_run
) -> None:
    """``--run``: a run trained elsewhere, on more clips than the walking ones, is measured (sweeps
    and bar) with rollouts on its walking clips; parts that train are refused in one line."""
    import json

    import science

    from amorctl.registry import get_registry

    run = make_tracking_run(tmp_path, "science --run", clip_names=("walk", "backflip", "walker/turn_left0"))
    out = tmp_path / "out"
    doc = out / "science-biped20-tiny.md"  # --character is the measured run's, whatever it says
    common = ["--run", str(run), "--out", str(out), "--doc", str(doc), "--character", "humanoid36"]
    with pytest.raises(SystemExit):
        science.main([*common, "--only", "train,sweeps"])
    assert "parts sweeps, front, bar, not train" in capsys.readouterr().err
    science.main([*common, "--only", "sweeps,bar", "--sweep-episodes", "1", "--bar-episodes", "4"])
    results = json.loads((out / "science.json").read_text())
    assert results["meta"]["motions"] == ["walk", "walker/turn_left0"]
    dataset = results["meta"]["dataset"]
    assert "the 2 walking clips" in dataset and "3-clip dataset" in dataset
    assert set(results["sweeps"]["objectives"]) == set(get_registry().objective_set("tracking7").objectives)
    assert results["bar"]["episodes"] == 4  # 2 per walking clip
    assert 0.0 <= results["bar"]["uniform"]["survival_rate"] <= 1.0
    assert not (out / "moppo").exists()  # nothing trained
    assert results["sweeps"]["figure"] == "img/science-biped20-tiny-sweeps.png"  # not another run's
    report = doc.read_text()
    assert f"measured run: `{run}`" in report and "**The run** (`--run`)" in report
    assert "MOPPO budget" not in report and "no training here" in report
