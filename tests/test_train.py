"""`amorctl train` and the run directory: checkpoints, interruption, bit-exact resume, bad input."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from amorctl.cli.main import main
from amorctl.core.config import TrainConfig, override
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.envs.factory import make_env
from amorctl.plugins.backends.torch_cpu import TorchCpuBackend
from amorctl.train.checkpoint import Checkpoint, list_checkpoints, load_checkpoint
from amorctl.train.loop import train_run
from amorctl.train.rundir import RunDir, check_compatible

torch.set_num_threads(1)

TINY_TOML = """
[run]
iterations = 6
checkpoint_every = 2
keep_checkpoints = 0
tensorboard = false
threads = 1
[env]
kind = "toy"
num_envs = 32
episode_seconds = 0.3
[network]
actor_hidden = [16, 16]
critic_hidden = [16, 16]
[ppo]
precision = "fp32"
num_steps = 8
num_epochs = 2
num_minibatches = 2
"""

LOSSES = ("loss/total", "loss/policy", "loss/value", "loss/entropy", "kl", "clip_fraction", "learning_rate")


def tiny(**changes: object) -> TrainConfig:
    base = dict(
        run__iterations=6,
        run__checkpoint_every=2,
        run__keep_checkpoints=0,
        run__tensorboard=False,
        env__kind="toy",
        env__num_envs=32,
        env__episode_seconds=0.3,
        network__actor_hidden=[16, 16],
        network__critic_hidden=[16, 16],
        ppo__num_steps=8,
        ppo__num_epochs=2,
        ppo__num_minibatches=2,
        ppo__precision="fp32",
    )
    base.update(changes)
    return override(TrainConfig(), **base)


def rows(out: Path) -> list[dict[str, str]]:
    with (out / "metrics.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def snapshot(directory: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()
    }


def run_cli(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_interrupted_run_resumes_bit_exactly(tmp_path: Path) -> None:
    config = tiny()
    full = train_run(config, tmp_path / "full")
    assert (full.start_iteration, full.end_iteration, full.interrupted) == (0, 6, False)
    assert [i for i, _ in list_checkpoints(tmp_path / "full" / "checkpoints")] == [2, 4, 6]

    part = train_run(config, tmp_path / "part", stop_after=3)  # interrupted after iteration 3
    assert part.interrupted and part.end_iteration == 3
    assert [i for i, _ in list_checkpoints(tmp_path / "part" / "checkpoints")] == [2, 3]
    resumed = train_run(config, tmp_path / "part", resume=True)
    assert (resumed.start_iteration, resumed.end_iteration) == (3, 6)

    a, b = rows(tmp_path / "full"), rows(tmp_path / "part")
    assert [r["iteration"] for r in b] == [r["iteration"] for r in a]
    for ra, rb in zip(a, b, strict=True):
        for key in (*LOSSES, "return/right", "return/left", "explained_variance/left", "env_steps"):
            assert ra[key] == rb[key], (ra["iteration"], key)
    wa = load_checkpoint(tmp_path / "full/checkpoints/iter_000006.json").trainer.arrays
    wb = load_checkpoint(tmp_path / "part/checkpoints/iter_000006.json").trainer.arrays
    assert wa.keys() == wb.keys()
    for key in wa:
        np.testing.assert_array_equal(wa[key], wb[key], err_msg=key)


def test_cli_trains_toy_and_writes_the_run_directory(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_TOML.replace("tensorboard = false", "tensorboard = true"))
    out = tmp_path / "run"
    code, stdout, err = run_cli(
        capsys, "train", "--config", str(cfg), "--out", str(out), "--seed", "3", "--json"
    )
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["end_iteration"] == 6 and not summary["interrupted"]
    assert summary["metrics"]["env_steps"] == 6 * 32 * 8
    resolved = (out / "config.toml").read_text()
    assert "seed = 3" in resolved and 'kind = "toy"' in resolved
    ckpt = load_checkpoint(out / "checkpoints/iter_000006.json")
    assert ckpt.meta["objectives"] == ["right", "left"] and ckpt.env is not None
    assert any((out / "tb").iterdir())
    header = rows(out)[0].keys()
    for key in (
        "return/right",
        "explained_variance/left",
        "loss/value",
        "kl",
        "clip_fraction",
        "env_steps_per_s",
    ):
        assert key in header
    # more iterations on resume; the run continues from 6
    code, stdout, err = run_cli(capsys, "train", "--out", str(out), "--resume", "--iterations", "8", "--json")
    assert code == 0, err
    assert json.loads(stdout)["start_iteration"] == 6 and len(rows(out)) == 8


def test_fixed_weights_trains_plain_ppo(tmp_path: Path) -> None:
    config = tiny(env__fixed_weights="left=3,right=1", run__iterations=2)
    env = make_env(config)
    assert env.weights.tolist() == [[0.25, 0.75]] * 32
    obs, *_, info = env.step(np.zeros((32, 1)))
    assert np.all(obs[:, -2:] == [0.25, 0.75]) and np.all(info["final_obs"][:, -2:] == [0.25, 0.75])
    result = train_run(config, tmp_path / "ppo")
    assert result.end_iteration == 2


def test_sigterm_saves_a_checkpoint_and_resume_continues(tmp_path: Path) -> None:
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(
        TINY_TOML.replace("iterations = 6", "iterations = 100000").replace(
            "checkpoint_every = 2", "checkpoint_every = 100000"
        )
    )
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "amorctl.cli.main", "train", "--config", str(cfg), "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ},
    )
    deadline = time.monotonic() + 300  # generous: CI machines can be slow to import torch
    while time.monotonic() < deadline and not ((out / "metrics.csv").exists() and len(rows(out)) >= 3):
        time.sleep(0.2)
    assert proc.poll() is None and len(rows(out)) >= 3  # training, so the signal handler is installed
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    found = list_checkpoints(out / "checkpoints")
    assert len(found) == 1
    iteration = found[0][0]
    assert iteration >= 3 and load_checkpoint(found[0][1]).iteration == iteration
    assert len(rows(out)) == iteration


def test_bad_input_fails_cleanly(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_TOML)
    code, _, err = run_cli(capsys, "train", "--preset", "fast", "--out", str(tmp_path / "a"))
    assert code != 0 and "unknown preset 'fast'" in err
    code, _, err = run_cli(
        capsys, "train", "--config", str(cfg), "--backend", "jax-tpu", "--out", str(tmp_path / "a")
    )
    assert code != 0 and "unknown backend 'jax-tpu'" in err
    code, _, err = run_cli(capsys, "train", "--character", "nosuch", "--out", str(tmp_path / "a"))
    assert code != 0 and "unknown character 'nosuch'" in err
    bad = tmp_path / "bad.toml"
    bad.write_text(TINY_TOML.replace("num_epochs = 2", "num_epochs = 2\nnum_epoch = 3"))
    code, _, err = run_cli(capsys, "train", "--config", str(bad), "--out", str(tmp_path / "a"))
    assert code != 0 and "unknown key 'num_epoch' in [ppo]" in err
    code, _, err = run_cli(
        capsys, "train", "--config", str(cfg), "--fixed-weights", "up=1", "--out", str(tmp_path / "a")
    )
    assert code != 0 and "unknown objective 'up'" in err
    code, _, err = run_cli(
        capsys, "train", "--config", str(cfg), "--fixed-weights", "right=0", "--out", str(tmp_path / "a")
    )
    assert code != 0 and "all zero" in err
    assert not (tmp_path / "a").exists()  # nothing was written for any of them

    code, _, err = run_cli(capsys, "train", "--resume", "--out", str(tmp_path / "none"))
    assert code != 0 and "no run to resume" in err


def test_damaged_or_foreign_checkpoints_are_refused_and_nothing_is_overwritten(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out = tmp_path / "run"
    train_run(tiny(run__iterations=2), out)
    before = snapshot(out)

    # a second run into the same directory without --resume
    code, _, err = run_cli(capsys, "train", "--env", "toy", "--out", str(out))
    assert code != 0 and "already holds a run" in err
    # changing the character (or anything but --iterations) on resume
    code, _, err = run_cli(capsys, "train", "--resume", "--out", str(out), "--seed", "9")
    assert code != 0 and "cannot change when resuming" in err
    assert snapshot(out) == before

    tensors = out / "checkpoints/iter_000002.safetensors"
    tensors.write_bytes(tensors.read_bytes()[:-100])  # truncated
    before = snapshot(out)
    code, _, err = run_cli(capsys, "train", "--resume", "--out", str(out), "--iterations", "4")
    assert code != 0 and "truncated" in err and "iter_000002.safetensors" in err
    assert snapshot(out) == before

    for path in (out / "checkpoints").iterdir():
        path.unlink()
    code, _, err = run_cli(capsys, "train", "--resume", "--out", str(out), "--iterations", "4")
    assert code != 0 and "no checkpoint to resume from" in err
    with pytest.raises(AmorError, match="checkpoint not found"):
        load_checkpoint(out / "checkpoints/iter_000009.json")


def test_checkpoint_of_another_character_is_refused() -> None:
    config = override(TrainConfig(), env__character="biped20")
    env = make_env(tiny())
    meta = {
        "env_kind": "tracking",
        "character": "humanoid36",
        "gym_id": None,
        "objectives": ["right", "left"],
        "obs_dim": env.obs_dim,
        "action_dim": env.action_dim,
        "backend": "torch-cpu",
    }
    ckpt = Checkpoint(Path("runs/x/checkpoints/iter_000010.json"), 10, meta, Snapshot(), None)
    with pytest.raises(AmorError, match="character 'humanoid36', this run has 'biped20'"):
        check_compatible(ckpt, config, env)


def test_load_policy_reproduces_the_trainers_actions(tmp_path: Path) -> None:

    out = tmp_path / "run"
    train_run(tiny(run__iterations=2), out)
    run = RunDir(out)
    ckpt = run.checkpoint()
    policy, config = run.policy_of(ckpt), run.config
    assert ckpt.iteration == 2 and policy.objectives == ("right", "left")
    backend = TorchCpuBackend()
    trainer = backend.make_trainer(make_env(config), config)
    trainer.load_state_dict(ckpt.trainer)
    obs = np.random.default_rng(0).normal(size=(5, policy.obs_dim)).astype(np.float32)
    np.testing.assert_array_equal(policy(obs), trainer.act(obs))
    assert policy.values(obs).shape == (5, 2)


def test_a_run_that_fails_before_its_first_checkpoint_leaves_nothing_and_can_be_rerun(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_TOML)
    out = tmp_path / "run"
    from amorctl.train import metrics

    def broken_write(self, m):  # fails after config.toml and metrics.csv exist
        self.path.write_text("iteration\n")
        raise AmorError(f"{self.path}: disk full")

    monkeypatch.setattr(metrics.MetricsLog, "write", broken_write)
    code, _, err = run_cli(capsys, "train", "--config", str(cfg), "--out", str(out), "--json")
    assert code == 2 and "disk full" in err and err.count("\n") == 1
    assert not out.exists()
    monkeypatch.undo()
    code, stdout, err = run_cli(capsys, "train", "--config", str(cfg), "--out", str(out), "--json")
    assert code == 0, err
    assert json.loads(stdout)["end_iteration"] == 6


def test_divergence_before_the_first_checkpoint_is_one_line_and_removes_the_run(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from amorctl.plugins.backends.torch_cpu.moppo import MOPPOTrainer

    iteration = MOPPOTrainer.iteration

    def diverging(self):
        metrics = iteration(self)
        return {**metrics, "loss/total": float("nan")}

    monkeypatch.setattr(MOPPOTrainer, "iteration", diverging)
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_TOML)
    existing = tmp_path / "mine"
    existing.mkdir()
    (existing / "notes.txt").write_text("keep me")
    for out in (tmp_path / "run", existing):
        code, _, err = run_cli(capsys, "train", "--config", str(cfg), "--out", str(out), "--json")
        assert code == 2 and err.count("\n") == 1, err
        assert err.startswith("error: training diverged at iteration 1 (non-finite loss)")
        assert "no checkpoint was saved, so the run directory was removed" in err
    assert not (tmp_path / "run").exists()
    assert sorted(p.name for p in existing.iterdir()) == ["notes.txt"]  # only the run's files went


def test_divergence_right_after_a_resume_does_not_call_that_checkpoint_good(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from amorctl.plugins.backends.torch_cpu.moppo import MOPPOTrainer

    iteration = MOPPOTrainer.iteration

    def diverging_after(n: int):
        def step(self):
            metrics = iteration(self)
            return {**metrics, "loss/total": float("nan")} if self.iteration_count > n else metrics

        return step

    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_TOML)
    out = tmp_path / "run"
    monkeypatch.setattr(MOPPOTrainer, "iteration", diverging_after(2))  # a checkpoint at 2, then NaN
    code, _, err = run_cli(capsys, "train", "--config", str(cfg), "--out", str(out), "--json")
    good = out / "checkpoints" / "iter_000002.json"
    assert code == 2 and err == (
        f"error: training diverged at iteration 3 (non-finite loss); the last good checkpoint is {good}\n"
    )
    monkeypatch.setattr(MOPPOTrainer, "iteration", diverging_after(0))  # NaN right after the resume
    code, _, err = run_cli(capsys, "train", "--resume", "--out", str(out), "--json")
    assert code == 2 and err.count("\n") == 1, err
    assert "last good checkpoint" not in err
    assert err.startswith(
        f"error: training diverged at iteration 3 (non-finite loss); it diverged before saving a checkpoint "
        f"after resuming from {good}, which may itself hold the bad state"
    )


def test_captured_simulator_warnings_are_counted_not_printed(capfd: pytest.CaptureFixture) -> None:
    import mujoco

    from amorctl.train.loop import captured_sim_warnings

    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='.1'/></body></worldbody></mujoco>"
    )
    with captured_sim_warnings() as warnings:
        for _ in range(5):  # MuJoCo warns once per MjData and kind of warning
            data = mujoco.MjData(model)
            data.qvel[:] = np.nan
            mujoco.mj_step(model, data)
    assert warnings.total == 5 and "QVEL" in warnings.first
    assert "warned 5 times" in warnings.summary()
    assert "WARNING" not in capfd.readouterr().out
    assert mujoco.get_mju_user_warning() is None


def _edit_checkpoint(out: Path, change) -> Path:
    from amorctl.train.checkpoint import record_sha256

    path = list_checkpoints(out / "checkpoints")[-1][1]
    record = json.loads(path.read_text())
    change(record)
    record["meta_sha256"] = record_sha256(record)  # a deliberate edit: only the checks can tell
    path.write_text(json.dumps(record))
    return path


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda r: r.update(iteration=-1), "'iteration' = -1 must be an integer >= 0"),
        (lambda r: r.update(iteration="x"), "'iteration' = 'x' must be an integer >= 0"),
        (lambda r: r.update(iteration=4), "'iteration' = 4 disagrees with the file name"),
        (lambda r: r["tensors"].update(file="/etc/passwd"), "must be a plain \\*.safetensors name"),
        (lambda r: r["tensors"].update(file="../x.safetensors"), "must be a plain \\*.safetensors name"),
        (lambda r: r["env"]["rng"]["state"].update(state="x"), "not a valid random-generator state"),
        (lambda r: r.pop("obs_dim"), "'obs_dim' = None must be a positive integer"),
        (lambda r: r["trainer"].update(episodes=1.5), "trainer.episodes = 1.5 must be an integer >= 0"),
        (lambda r: r["trainer"]["optimizer_param_groups"][0].pop("eps"), "optimizer_param_groups\\[0\\].eps"),
        (lambda r: r["trainer"].update(learning_rate="fast"), "learning_rate = 'fast' must be a finite"),
        (
            lambda r: r["trainer"]["optimizer_param_groups"][0].update(betas=[1e308, 0.999]),
            "betas = \\[1e\\+308",
        ),
        (lambda r: r["trainer"]["optimizer_param_groups"][0].update(eps=-1.0), "eps = -1.0; expected finite"),
        (lambda r: r["trainer"].update(learning_rate=1e308), "learning_rate = 1e\\+308; expected a finite"),
    ],
)
def test_checkpoint_metadata_is_checked_by_type_and_meaning(
    tmp_path: Path, capsys: pytest.CaptureFixture, change, message: str
) -> None:
    out = tmp_path / "run"
    train_run(tiny(run__iterations=2), out)
    path = _edit_checkpoint(out, change)
    before = snapshot(out)
    code, _, err = run_cli(capsys, "train", "--resume", "--out", str(out), "--iterations", "4")
    assert code == 2 and err.count("\n") == 1, err
    assert str(path) in err and re.search(message, err), err
    assert snapshot(out) == before


def test_altered_checkpoint_metadata_fails_its_hash(tmp_path: Path) -> None:
    out = tmp_path / "run"
    train_run(tiny(run__iterations=2), out)
    path = list_checkpoints(out / "checkpoints")[-1][1]
    record = json.loads(path.read_text())
    record["trainer"]["learning_rate"] = 1e308
    path.write_text(json.dumps(record))
    with pytest.raises(AmorError, match="checkpoint metadata was altered"):
        load_checkpoint(path)


def test_policy_of_refuses_a_checkpoint_of_another_character(tmp_path: Path) -> None:
    out = tmp_path / "run"
    train_run(tiny(run__iterations=2), out)
    _edit_checkpoint(out, lambda r: r.update(env_kind="tracking", character="humanoid36"))
    run = RunDir(out)
    with pytest.raises(AmorError, match=r"env kind 'tracking', the run's config .*config.toml. has 'toy'"):
        run.policy()
