"""A new run started from another run's networks (``[run] init_from``, ``train --init-from``,
docs/train.md "Starting from another run"): it acts as its source from the first iteration, counts
its own iterations, records where it started, resumes without the source, and a source that does
not fit is refused before anything is written."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from amorctl.cli.main import main
from amorctl.core.config import TrainConfig, merge, to_toml
from amorctl.core.errors import AmorError
from amorctl.core.levers import check_backend_levers
from amorctl.registry import get_registry
from amorctl.train.checkpoint import load_checkpoint
from amorctl.train.loop import train_run
from amorctl.train.rundir import RunDir

OBS = np.random.default_rng(3).normal(size=(64, 3)).astype(np.float32)


def _config(source: Path, **sections: dict) -> TrainConfig:
    """The config of the run in ``source`` with one iteration and an almost frozen learning rate
    (so the weights after it are the weights it started from, up to 1e-5)."""
    base = RunDir.open(source).config
    fixed = {
        "run": {"iterations": 1, "checkpoint_every": 1},
        "ppo": {"learning_rate": 1e-7, "lr_schedule": "fixed"},
    }
    return merge(merge(base, fixed, "test"), sections, "test")


def _actions(run: Path) -> np.ndarray:
    policy = RunDir.open(run).policy()
    obs = np.resize(OBS, (64, policy.obs_dim)).astype(np.float32)
    obs[:, -2:] = np.random.default_rng(4).dirichlet(np.ones(2), size=64)  # the weights
    return np.asarray(policy(obs))


def _actor(run: Path) -> dict[str, np.ndarray]:
    ckpt = load_checkpoint(RunDir.open(run).checkpoints()[-1][1])
    return {k: v for k, v in ckpt.trainer.arrays.items() if k.startswith("actor.")}


def test_a_run_started_from_another_acts_as_it_and_counts_its_own_iterations(
    toy_smooth_run: Path, tmp_path: Path
) -> None:
    torch.set_num_threads(1)
    source = tmp_path / "source"
    shutil.copytree(toy_smooth_run, source)
    started, fresh = tmp_path / "started", tmp_path / "fresh"
    train_run(_config(source, run={"init_from": str(source)}), started)
    train_run(_config(source), fresh)

    config = RunDir.open(started).config
    assert config.run.init_from == f"{source.resolve()}@40"  # absolute, with the checkpoint taken
    ckpt = load_checkpoint(RunDir.open(started).checkpoints()[-1][1])
    assert ckpt.iteration == 1 and ckpt.trainer.meta["env_steps"] == 64 * 16  # its own counters
    theirs, mine, new = _actor(source), _actor(started), _actor(fresh)
    assert max(np.abs(mine[k] - theirs[k]).max() for k in theirs) < 1e-4
    assert max(np.abs(new[k] - theirs[k]).max() for k in theirs) > 0.1  # the same run without it
    assert np.abs(_actions(started) - _actions(source)).max() < 0.05
    assert np.abs(_actions(fresh) - _actions(source)).max() > 0.2

    shutil.rmtree(source)  # a resumed run reads its own checkpoint, not the source
    train_run(
        dataclasses.replace(config, run=dataclasses.replace(config.run, iterations=2)), started, resume=True
    )
    assert RunDir.open(started).checkpoints()[-1][0] == 2


def test_init_from_std_starts_the_actions_std_there_and_keeps_the_rest(
    toy_smooth_run: Path, tmp_path: Path
) -> None:
    torch.set_num_threads(1)
    started = tmp_path / "started"
    train_run(_config(toy_smooth_run, run={"init_from": str(toy_smooth_run), "init_from_std": 0.03}), started)
    theirs, mine = _actor(toy_smooth_run), _actor(started)
    assert np.abs(np.exp(mine["actor.log_std"]) - 0.03).max() < 1e-5
    assert np.abs(np.exp(theirs["actor.log_std"]) - 0.03).min() > 0.01  # the source's std was not 0.03
    assert max(np.abs(mine[k] - theirs[k]).max() for k in theirs if k != "actor.log_std") < 1e-4
    with pytest.raises(AmorError, match=r"\[run\] init_from_std = 0.03 needs \[run\] init_from"):
        train_run(_config(toy_smooth_run, run={"init_from_std": 0.03}), tmp_path / "refused")
    assert not (tmp_path / "refused").exists()


def test_a_source_that_does_not_fit_is_refused_before_anything_is_written(
    toy_smooth_run: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    cases = [
        (
            {"run": {"init_from": str(tmp_path / "nowhere")}},
            r"\[run\] init_from: .*nowhere.*not a run directory",
        ),
        ({"run": {"init_from": f"{toy_smooth_run}@7"}}, r"\[run\] init_from: .*7"),
        (
            {"run": {"init_from": str(toy_smooth_run)}, "network": {"actor_hidden": [16]}},
            r"\[run\] init_from: .*networks differ .*actor\.",
        ),
        (
            {"run": {"init_from": str(toy_smooth_run)}, "env": {"kind": "toy"}},
            r"\[run\] init_from: .*env.kind = 'toy-smooth', this run has 'toy'",
        ),
    ]
    for sections, message in cases:
        with pytest.raises(AmorError, match=message):
            train_run(_config(toy_smooth_run, **sections), out)
        assert not out.exists(), sections


def test_init_from_needs_a_backend_that_implements_it() -> None:
    config = merge(TrainConfig(), {"run": {"init_from": "x", "backend": "jax-mjx"}}, "test")
    with pytest.raises(AmorError, match=r"\[run\] init_from = 'x' needs a backend"):
        check_backend_levers(config, get_registry().backend("jax-mjx").levers)
    assert "init_from" in get_registry().backend("torch-cpu").levers


def test_train_command_starts_from_a_run_and_says_so(
    toy_smooth_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    config_file = tmp_path / "c.toml"
    config_file.write_text(to_toml(_config(toy_smooth_run)))
    out = tmp_path / "run"
    code = main(
        ["train", "--config", str(config_file), "--init-from", f"{toy_smooth_run}@40", "--out", str(out)]
    )
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert f"started from {toy_smooth_run}@40" in captured.out.replace("\n", "")  # (wrapped lines)
    assert RunDir.open(out).config.run.init_from == f"{toy_smooth_run.resolve()}@40"
    code = main(["train", "--config", str(config_file), "--init-from", str(tmp_path / "nowhere"),
                 "--out", str(tmp_path / "bad"), "--json"])  # fmt: skip
    captured = capsys.readouterr()
    assert code != 0 and "[run] init_from" in captured.err and "Traceback" not in captured.err
    assert not (tmp_path / "bad").exists()


def test_a_tracking_run_starts_from_one_of_the_same_character_and_action_mode(
    tracking_run: Path, tmp_path: Path
) -> None:
    started = tmp_path / "started"
    train_run(_config(tracking_run, run={"init_from": str(tracking_run)}), started)
    theirs, mine = _actor(tracking_run), _actor(started)
    assert max(np.abs(mine[k] - theirs[k]).max() for k in theirs) < 1e-4
    other = _config(tracking_run, run={"init_from": str(tracking_run)}, env={"action_mode": "absolute"})
    with pytest.raises(AmorError, match=r"init_from: .*action_mode = 'residual', this run has 'absolute'"):
        train_run(other, tmp_path / "other")
    assert not (tmp_path / "other").exists()


def test_an_exported_run_says_where_it_started(toy_smooth_run: Path, tmp_path: Path) -> None:
    """The card, its README and `runs list --pretrained` name the run a pretrained entry started from."""
    from amorctl.cli.runs import _pretrained_block
    from amorctl.train.pretrained_export import export_pretrained

    started = tmp_path / "started"
    train_run(_config(toy_smooth_run, run={"init_from": f"{toy_smooth_run}@40"}), started)
    entry = export_pretrained(started, "started", tmp_path / "shelf", commit="test")
    assert entry.card["init_from"] == f"{toy_smooth_run.resolve()}@40"
    assert (
        f"started from the networks of: `{toy_smooth_run.resolve()}@40`"
        in (entry.path / "README.md").read_text()
    )
    assert f"started from {toy_smooth_run.name}@40" in _pretrained_block("pretrained:started", entry.card)
    plain = export_pretrained(toy_smooth_run, "plain", tmp_path / "shelf", commit="test")
    assert plain.card["init_from"] is None and "started from" not in _pretrained_block("p", plain.card)
