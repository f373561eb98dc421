"""benchmarks/stage.py: a run trained in stages through a resumable pretrained entry continues
exactly where the last stage stopped, and its card records every stage."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import eval_curve
import lever_rows
import stage as stage_script

from amorctl.core.config import TrainConfig, load_config, merge, to_toml
from amorctl.envs.synthetic import synthetic_library
from amorctl.motion.dataset import load_dataset, write_dataset
from amorctl.registry import get_registry
from amorctl.train.checkpoint import load_checkpoint
from amorctl.train.episode_stats import clip_family
from amorctl.train.loop import train_run
from amorctl.train.rundir import RunDir


def tiny_config(tmp_path: Path) -> TrainConfig:
    lib = synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=1.0, seed=3)
    lib = dataclasses.replace(lib, clips=tuple(lib.clips))
    write_dataset(tmp_path / "ds.mcap", lib)
    return merge(
        TrainConfig(),
        {
            "run": {"iterations": 4, "checkpoint_every": 1, "tensorboard": False},
            "env": {"kind": "tracking", "character": "biped20", "dataset": str(tmp_path / "ds.mcap"),
                    "num_envs": 4, "episode_seconds": 0.2},
            "network": {"actor_hidden": [16], "critic_hidden": [16]},
            "ppo": {"num_steps": 4, "num_epochs": 1, "num_minibatches": 2, "precision": "fp32"},
        },
        "test",
    )  # fmt: skip


def run_stage(tmp_path: Path, *extra: str) -> None:
    stage_script.main(
        ["--run", "tiny", "--minutes", "5", "--shelf", str(tmp_path / "shelf"),
         "--work", str(tmp_path / "work"), "--max-iterations", "2", "--eval-episodes", "1", *extra]
    )  # fmt: skip


def test_two_stages_continue_exactly_and_the_card_records_both(tmp_path: Path, capsys) -> None:
    config = tiny_config(tmp_path)
    (tmp_path / "tiny.toml").write_text(to_toml(config))
    run_stage(tmp_path, "--config", str(tmp_path / "tiny.toml"))
    run_stage(tmp_path)
    out = capsys.readouterr().out
    assert "stage 1: 2 iterations" in out and "stage 2: 2 iterations" in out
    assert "stage 1 of tiny: new run, 5 min" in out
    assert "stage 2 of tiny: resuming at iteration 2 (32 env steps), 5 min" in out
    progress = [line for line in out.splitlines() if " of 0:05:00  it " in line]
    assert [line.split("  it ")[1].split()[0] for line in progress] == ["1", "3"], out  # each stage's first
    assert all("env steps" in line and "survival" in line for line in progress), progress

    entry = tmp_path / "shelf" / "tiny"
    card = json.loads((entry / "card.json").read_text())
    assert card["resumable"] and [s["stage"] for s in card["stages"]] == [1, 2]
    first, second = card["stages"]
    assert (first["iterations"], second["iterations"], second["cumulative"]["iterations"]) == (2, 2, 4)
    assert second["cumulative"]["env_steps"] == first["env_steps"] + second["env_steps"] == 4 * 4 * 4
    assert second["cumulative"]["wall_clock_s"] == pytest.approx(
        first["wall_clock_s"] + second["wall_clock_s"]
    )
    for st in card["stages"]:
        assert st["commit"] is not None and "cores" in st["machine"]
        assert st["precision"] == "fp32"  # the config's precision, as the backend resolved it
        assert st["evaluation"]  # one entry per motion family of the clips
        for ev in st["evaluation"].values():
            assert 0.0 <= ev["survival"] <= 1.0 and ev["joint_mae_deg"] > 0
        clips = st["evaluation_clips"]  # and per clip: the family figure is their mean
        for family, ev in st["evaluation"].items():
            rows = [v for c, v in clips.items() if clip_family(c) == family]
            assert rows and ev["survival"] == pytest.approx(np.mean([r["survival"] for r in rows]))
    assert "Training stages" in (entry / "README.md").read_text()
    assert (entry / "figures" / "stages.png").is_file()
    assert load_config(entry / "config.toml").env.dataset == "dataset.mcap"  # the entry is self-contained
    assert RunDir.open(entry).dataset_path() == entry / "dataset.mcap"  # found there, opened by path

    # the same 4 iterations in one go: the staged run's networks and optimizer are identical
    train_run(config, tmp_path / "straight")
    straight = load_checkpoint(tmp_path / "straight/checkpoints/iter_000004.json").trainer.arrays
    staged = load_checkpoint(entry / "checkpoints/iter_000004.json").trainer.arrays
    for key in ("actor.net.0.weight", "critic.net.0.weight", "actor.log_std"):
        np.testing.assert_array_equal(staged[key], straight[key], err_msg=key)
    assert any(k.startswith("optimizer.") for k in staged)  # resumable: the training state is kept


def test_a_later_stage_refuses_new_settings_and_a_plain_entry(tmp_path: Path, capsys, monkeypatch) -> None:
    config = tiny_config(tmp_path)
    (tmp_path / "tiny.toml").write_text(to_toml(config))
    with pytest.raises(SystemExit):
        run_stage(tmp_path)  # no entry and nothing to start from
    assert "the first stage needs --preset or --config" in capsys.readouterr().err
    run_stage(tmp_path, "--config", str(tmp_path / "tiny.toml"), "--description", "a tiny run")
    with pytest.raises(SystemExit):
        run_stage(tmp_path, "--set", "ppo.entropy_coef=0.01")
    assert "continues with the run's own config" in capsys.readouterr().err
    run_stage(tmp_path, "--budget-steps", "16")  # an env-step budget: 4 envs x 4 steps = one iteration
    assert "stage 2: 1 iterations, 16 env steps" in capsys.readouterr().out
    stage_script.main(  # the documented command has no --max-iterations: the loop is open-ended
        ["--run", "tiny", "--minutes", "5", "--shelf", str(tmp_path / "shelf"),
         "--work", str(tmp_path / "work"), "--budget-steps", "16", "--eval-episodes", "1"]
    )  # fmt: skip
    assert "stage 3: 1 iterations, 16 env steps" in capsys.readouterr().out
    card_path = tmp_path / "shelf" / "tiny" / "card.json"
    card = json.loads(card_path.read_text())
    assert [s["interrupted"] for s in card["stages"]] == [False] * 3  # budgets end a stage normally

    head = {"commit": "abc1234"}  # what git says; a commit made while the stage trains moves it

    def stopped_by_ctrl_c(*args, **kwargs):
        result = train_run(*args, **kwargs)
        head["commit"] = "def5678"
        return dataclasses.replace(result, interrupted=True, signal="SIGINT")

    monkeypatch.setattr(stage_script, "train_run", stopped_by_ctrl_c)
    monkeypatch.setattr(stage_script, "git_commit", lambda _: head["commit"])
    run_stage(tmp_path)
    card = json.loads(card_path.read_text())
    assert [s["interrupted"] for s in card["stages"]] == [False] * 3 + [True]
    assert card["stages"][-1]["commit"] == "abc1234"  # the code that trained, not HEAD at the end
    assert card["commit"] == "abc1234"  # the entry's code version: its last stage's
    assert card["description"] == "a tiny run"  # kept from the first stage
    readme = (tmp_path / "shelf" / "tiny" / "README.md").read_text()
    assert "| fp32 |" in readme and "(stopped by hand)" in readme and "code version: abc1234" in readme
    assert card["stages"][0]["command"].startswith("python benchmarks/stage.py --run tiny --minutes 5 ")
    assert "--config" in card["stages"][0]["command"] and card["command"] == card["stages"][0]["command"]
    card_path.write_text(json.dumps({**card, "resumable": False}))
    with pytest.raises(SystemExit):
        run_stage(tmp_path)
    err = capsys.readouterr().err
    assert "not a resumable entry" in err and "run.init_from=" in err and "shelf/tiny" in err


def test_a_stage_refuses_to_move_a_teacher_of_another_entry(tmp_path: Path, capsys, monkeypatch) -> None:
    """An entry that another entry of its shelf was kickstarted by stays the checkpoint that taught:
    a stage of it is refused before anything is written (by path, or by pretrained:NAME in the
    package's own shelf), and a copy in another shelf trains on."""
    config = tiny_config(tmp_path)
    (tmp_path / "tiny.toml").write_text(to_toml(config))
    run_stage(tmp_path, "--config", str(tmp_path / "tiny.toml"))
    shelf, work = tmp_path / "shelf", tmp_path / "work"
    student = shelf / "student"
    student.mkdir()
    for teacher in (str((shelf / "tiny").resolve()), "pretrained:tiny"):
        (student / "config.toml").write_text(f'[distill]\nteachers = ["{teacher}"]\n')
        monkeypatch.setattr(stage_script.pretrained, "package_folder", lambda: shelf)
        before = (shelf / "tiny" / "card.json").read_text()
        stamp = sorted(p.name for p in (work / "tiny" / "checkpoints").iterdir())
        with pytest.raises(SystemExit):
            run_stage(tmp_path)
        err = capsys.readouterr().err
        assert "student in the same shelf learned from this run" in err and "Traceback" not in err, err
        assert (shelf / "tiny" / "card.json").read_text() == before
        assert sorted(p.name for p in (work / "tiny" / "checkpoints").iterdir()) == stamp
    (student / "config.toml").write_text('[distill]\nteachers = ["pretrained:other"]\n')
    run_stage(tmp_path)
    assert "stage 2: 2 iterations" in capsys.readouterr().out


def test_lever_rows_tabulates_runs_and_clips() -> None:
    def fake(label: str, walk: float, jump: float) -> dict:
        clips = {
            "walk": {"survival": walk, "joint_mae_deg": 8.0},
            "jump": {"survival": jump, "joint_mae_deg": 12.0},
        }
        return {
            "label": label,
            "env_steps": 2_500_000,
            "wall_s": 600.0,
            "episode_length": 80.0,
            "clips": clips,
        }

    text = lever_rows.markdown([fake("plain", 1.0, 0.0), fake("adaptive", 0.875, 0.5)])
    assert "| plain | 2.50 M | 10 min | 80 | 1 of 2 | 50% | 10.0° |" in text
    assert "| adaptive | 2.50 M | 10 min | 80 | 0 of 2 | 69% | 10.0° |" in text
    assert "| jump | 0% / 12.0° | 50% / 12.0° |" in text


def test_lever_rows_puts_runs_on_different_clips_in_one_table() -> None:
    def fake(label: str, clips: dict[str, float]) -> dict:
        return {
            "label": label,
            "env_steps": 4_147_200,
            "wall_s": 960.0,
            "episode_length": 400.0,
            "clips": {c: {"survival": s, "joint_mae_deg": 13.0} for c, s in clips.items()},
        }

    rows = [fake("jump alone", {"jump": 0.875}), fake("dance_b alone", {"dance_b": 0.625})]
    text = lever_rows.markdown(rows)
    assert "| jump alone | 4.15 M | 16 min | 400 | 0 of 1 | 88% | 13.0° |" in text
    assert "| jump | 88% / 13.0° | — |" in text
    assert "| dance_b | — | 62% / 13.0° |" in text


def test_lever_rows_takes_a_run_at_one_of_its_checkpoints(tmp_path: Path, capsys) -> None:
    config = merge(tiny_config(tmp_path), {"run": {"keep_checkpoints": 0}}, "test")
    train_run(config, tmp_path / "run")
    steps_per_iteration = config.env.num_envs * config.ppo.num_steps
    early = lever_rows.row("early", tmp_path / "run", episodes=1, seed=1, iteration=2)
    late = lever_rows.row("late", tmp_path / "run", episodes=1, seed=1)
    assert early["env_steps"] == 2 * steps_per_iteration and late["env_steps"] == 4 * steps_per_iteration
    assert list(early["metrics"]["iteration"]) == [1, 2] and len(late["metrics"]["iteration"]) == 4
    assert 0 < early["wall_s"] < late["wall_s"]
    assert early["clips"].keys() == late["clips"].keys() and len(early["clips"]) == 2
    with pytest.raises(SystemExit):
        lever_rows.main(["--run", f"early={tmp_path / 'run'}@two"])
    assert "write LABEL=DIR or LABEL=DIR@ITERATION" in capsys.readouterr().err


def test_eval_curve_measures_checkpoints_once_and_tabulates_them(tmp_path: Path, capsys) -> None:
    config = merge(tiny_config(tmp_path), {"run": {"keep_checkpoints": 0}}, "test")
    train_run(config, tmp_path / "run")
    cache = tmp_path / "curve.json"
    args = ["--run", str(tmp_path / "run"), "--every", "2", "--episodes", "1", "--cache", str(cache)]
    eval_curve.main(args)
    first = capsys.readouterr().out
    saved = json.loads(cache.read_text())
    assert sorted(saved) == ["2", "4"]
    assert saved["4"]["env_steps"] == 4 * 4 * 4  # 4 iterations x 4 envs x 4 steps
    expected = eval_curve.summary(saved["2"]["clips"], "walk")
    assert f"| 2 | 0.0 M | {expected['clips_90']:.0f} | {expected['mean_survival']:.0%} |" in first
    # a cached entry is not measured again
    saved["2"]["clips"] = {"walk": {"survival": 1.0, "joint_mae_deg": 5.0}}
    cache.write_text(json.dumps(saved))
    eval_curve.main(args)
    assert "| 2 | 0.0 M | 1 | 100% | 5.00° |" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        eval_curve.main(["--run", str(tmp_path / "run"), "--iterations", "3", "5"])
    assert "no checkpoint at iteration(s) [5]" in capsys.readouterr().err


def test_first_stage_trains_on_the_clips_named(tmp_path: Path, capsys) -> None:
    config = tiny_config(tmp_path)
    lib = load_dataset(tmp_path / "ds.mcap")
    names = ("walk", "backflip")
    lib = dataclasses.replace(
        lib, clips=tuple(dataclasses.replace(c, name=n) for c, n in zip(lib.clips, names, strict=True))
    )
    write_dataset(tmp_path / "ds.mcap", lib)
    (tmp_path / "tiny.toml").write_text(to_toml(config))
    with pytest.raises(SystemExit):
        run_stage(tmp_path, "--config", str(tmp_path / "tiny.toml"), "--clips", "walker/")
    assert "--clips walker/: no such clip" in capsys.readouterr().err
    run_stage(tmp_path, "--config", str(tmp_path / "tiny.toml"), "--clips", "walk")
    entry = tmp_path / "shelf" / "tiny"
    assert json.loads((entry / "card.json").read_text())["motions"] == ["walk"]
    shipped = load_dataset(entry / "dataset.mcap")
    assert [c.name for c in shipped.clips] == ["walk"]
    np.testing.assert_array_equal(shipped.joint_pos, lib.joint_pos[: lib.clips[0].num_frames])
    with pytest.raises(SystemExit):
        run_stage(tmp_path, "--clips", "walk")  # a later stage keeps the run's clips
    assert "continues with the run's own config" in capsys.readouterr().err


def test_stage_precision_reads_what_the_backend_chose_in_the_stage(tmp_path: Path) -> None:
    """``precision = "auto"`` resolves per machine: a stage records what its own iterations ran."""
    rows = ["iteration,bf16", "1,0", "2,0", "3,1", "4,1", "5,1"]
    (tmp_path / "metrics.csv").write_text("\n".join(rows) + "\n")
    assert stage_script.stage_precision(tmp_path, 2) == "bf16"
    assert stage_script.stage_precision(tmp_path, 0) == "bf16 in 3 of 5 iterations"
    assert stage_script.stage_precision(tmp_path, 1) == "bf16 in 3 of 4 iterations"
    (tmp_path / "metrics.csv").write_text("\n".join(rows[:3]) + "\n")
    assert stage_script.stage_precision(tmp_path, 0) == "fp32"
    assert stage_script.stage_precision(tmp_path / "nowhere", 0) == "unknown"


def test_training_survival_is_the_same_from_a_working_copy_and_its_thinned_entry(tmp_path: Path) -> None:
    from amorctl.train.pretrained_export import thin_metrics

    full, entry = tmp_path / "work", tmp_path / "entry"
    full.mkdir(), entry.mkdir()
    rows = ["iteration,env_steps,wall_time_s,survival/walk"]
    rows += [f"{i},{i * 100},{i * 0.5},{(i % 7) / 7}" for i in range(1, 301)]
    (full / "metrics.csv").write_text("\n".join(rows) + "\n")
    thin_metrics(full / "metrics.csv", entry / "metrics.csv")
    steps, survival = stage_script.training_survival(full, ["walk"], window=5)["walk"]
    steps_e, survival_e = stage_script.training_survival(entry, ["walk"], window=5)["walk"]
    np.testing.assert_array_equal(steps, steps_e)
    np.testing.assert_array_equal(survival, survival_e)
    assert len(steps) == 30 - 5 + 1 and steps[0] == 5000  # rows 10, 20, ..., 300; window of 5 rows
    assert survival[0] == pytest.approx(np.mean([(i % 7) / 7 for i in (10, 20, 30, 40, 50)]))
