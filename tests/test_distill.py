"""Teacher-student distillation (``[distill] teachers``, docs/distill.md): the student learns each
clip's teacher actions, teachers are checked against the student's dataset before anything is
written, and a student is not resumed with teachers that moved on."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from amorctl.core.config import TrainConfig, merge
from amorctl.core.errors import AmorError
from amorctl.core.levers import check_backend_levers
from amorctl.registry import get_registry
from amorctl.train.checkpoint import load_checkpoint
from amorctl.train.distill import Taught
from amorctl.train.loop import train_run
from amorctl.train.rundir import RunDir

CLIPS = ("sway_a", "sway_b")


class ClipConstantTeacher:
    """A teacher whose mean action is a constant per clip: +0.3 on clip 0, -0.3 on clip 1."""

    def __init__(self, action_dim: int) -> None:
        self.action_dim = action_dim

    def __call__(self, obs: np.ndarray, clips: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sign = np.where(np.asarray(clips) == 0, 1.0, -1.0).astype(np.float32)
        mean = np.repeat(0.3 * sign[:, None], self.action_dim, axis=1)
        return mean, np.full_like(mean, np.log(0.05))

    def fingerprint(self) -> list[str]:
        return ["constant@iter_000000.json"]


def _student_config(root: Path, teachers: list[str], **ppo: object) -> TrainConfig:
    return merge(
        TrainConfig(),
        {
            "run": {"iterations": 1, "checkpoint_every": 1, "tensorboard": False, "threads": 1},
            "env": {"kind": "tracking", "character": "biped20", "dataset": str(root / "ds.mcap"),
                    "num_envs": 8, "episode_seconds": 0.4},
            "network": {"actor_hidden": [32], "critic_hidden": [16], "init_std": 0.5},
            "ppo": {"num_steps": 8, "num_epochs": 4, "num_minibatches": 2, "learning_rate": 3e-3,
                    "lr_schedule": "fixed", "precision": "fp32", **ppo},
            "distill": {"teachers": teachers},
        },
        "test",
    )  # fmt: skip


def test_student_learns_each_clips_teacher_actions(make_tracking_run, tmp_path: Path) -> None:
    """On the states it visits, the student's actions approach the teacher of each state's clip
    (opposite targets on the two clips, so it must tell them apart), and its std the teacher's."""
    from amorctl.envs.factory import make_env
    from amorctl.plugins.backends.torch_cpu.distill import DistillTrainer

    make_tracking_run(tmp_path, "distill test data")  # writes tmp_path/ds.mcap (clips sway_a, sway_b)
    config = _student_config(tmp_path, ["unused: the test hands its own teacher"])
    backend = get_registry().backend("torch-cpu").make()
    env = make_env(config, backend)
    teacher = ClipConstantTeacher(env.action_dim)
    torch.set_num_threads(1)
    trainer = DistillTrainer(Taught(env, teacher), config.network, config.ppo, seed=0, learning_rate=3e-3)

    def action_error() -> float:  # on the envs' current states, each against its clip's teacher
        target, _ = teacher(trainer.obs.numpy(), env.tracking_view().clip_index())
        return float(np.abs(trainer.act(trainer.obs.numpy()) - target).mean())

    before, std_before = action_error(), float(torch.exp(trainer.actor.log_std.detach()).mean())
    for _ in range(60):
        last = trainer.iteration()
    after = action_error()
    env.close()
    assert before > 0.25  # the student starts near 0, the targets are +-0.3
    assert after < 0.05 and last["distill/action_mae"] < 0.05, (after, last["distill/action_mae"])
    assert last["action_std"] < 0.5 * std_before  # pulled from 0.5 towards the teacher's 0.05


@pytest.fixture(scope="module")
def teacher_run(tmp_path_factory: pytest.TempPathFactory, make_tracking_run) -> Path:
    return make_tracking_run(tmp_path_factory.mktemp("teacher"), "teacher fixture")


def test_student_run_records_its_teachers_and_refuses_teachers_that_moved_on(
    teacher_run: Path, tmp_path: Path
) -> None:
    root = teacher_run.parent
    student = tmp_path / "student"
    config = _student_config(root, [str(teacher_run)])
    train_run(config, student)
    run = RunDir.open(student)
    assert run.config.distill.teachers == (str(teacher_run.resolve()),)
    ckpt = load_checkpoint(run.checkpoints()[-1][1])
    assert ckpt.trainer.meta["distill_teachers"] == [f"{teacher_run.resolve()}@iter_000001.json"]
    # a student is an ordinary run afterwards: its policy loads and acts
    policy = run.policy()
    assert policy(np.zeros((2, policy.obs_dim), np.float32)).shape == (2, policy.action_dim)

    moved = tmp_path / "teacher-copy"  # the teacher trained on: a newer checkpoint
    import shutil

    shutil.copytree(teacher_run, moved)
    teacher_config = RunDir.open(moved).config
    train_run(dataclasses.replace(teacher_config, run=dataclasses.replace(teacher_config.run, iterations=2)),
              moved, resume=True)  # fmt: skip
    student2 = tmp_path / "student2"
    train_run(_student_config(root, [str(moved)]), student2)
    shutil.rmtree(moved / "checkpoints")
    shutil.copytree(teacher_run / "checkpoints", moved / "checkpoints")  # back to iteration 1
    resumed = dataclasses.replace(config, run=dataclasses.replace(config.run, iterations=2))
    resumed = dataclasses.replace(resumed, distill=RunDir.open(student2).config.distill)
    with pytest.raises(AmorError, match=r"taught by .*iter_000002.*now .*iter_000001"):
        train_run(resumed, student2, resume=True)


def test_teachers_are_checked_before_anything_is_written(
    teacher_run: Path, make_tracking_run, tmp_path: Path
) -> None:
    root = teacher_run.parent
    out = tmp_path / "student"
    with pytest.raises(AmorError, match=r"\[distill\] teachers: .*nowhere.*not a run directory"):
        train_run(_student_config(root, [str(tmp_path / "nowhere")]), out)
    assert not out.exists()
    # a teacher of sway_a only (its other clip is another motion): sway_b has no teacher
    partial = make_tracking_run(tmp_path / "partial", "partial teacher", clip_names=("sway_a", "other"))
    with pytest.raises(AmorError, match=r"no teacher holds the clips sway_b"):
        train_run(_student_config(root, [str(partial)]), out)
    assert not out.exists()
    # listed after the full teacher, the partial one teaches nothing and is accepted
    train_run(_student_config(root, [str(teacher_run), str(partial)]), out)
    assert RunDir.open(out).checkpoints()
    # a clip of the same name with other frames is refused
    other = make_tracking_run(tmp_path / "other", "other data", clip_names=("sway_b", "sway_a"))
    with pytest.raises(AmorError, match=r"clip 'sway_(a|b)' has other frames or motion latents"):
        train_run(_student_config(root, [str(other)]), tmp_path / "student3")
    assert not (tmp_path / "student3").exists()
    # another action mode means other actions
    with pytest.raises(AmorError, match=r"action_mode = 'residual', the student has 'absolute'"):
        train_run(
            merge(_student_config(root, [str(teacher_run)]), {"env": {"action_mode": "absolute"}}, "test"),
            tmp_path / "student4",
        )


def test_distill_needs_the_tracking_env_and_a_backend_that_implements_it() -> None:
    with pytest.raises(AmorError, match=r"\[distill\] teachers need the tracking env"):
        merge(TrainConfig(), {"env": {"kind": "toy"}, "distill": {"teachers": ["x"]}}, "test")
    config = merge(TrainConfig(), {"distill": {"teachers": ["x"]}, "run": {"backend": "jax-mjx"}}, "test")
    with pytest.raises(AmorError, match=r"\[distill\] teachers = \['x'\] needs a backend"):
        check_backend_levers(config, get_registry().backend("jax-mjx").levers)


def test_train_command_shows_a_student_and_its_teacher_action_error(
    teacher_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """``amorctl train --config`` with ``[distill] teachers``: the header names the teachers and
    each progress line the student's action error against them, in place of MOPPO's losses."""
    import tomlkit

    from amorctl.cli.main import main

    config = _student_config(teacher_run.parent, [str(teacher_run)])
    toml = tomlkit.dumps({"env": {"dataset": config.env.dataset, "num_envs": 8, "episode_seconds": 0.4},
                          "network": {"actor_hidden": [32], "critic_hidden": [16]},
                          "ppo": {"num_steps": 8, "num_minibatches": 2, "precision": "fp32"},
                          "run": {"tensorboard": False, "threads": 1},
                          "distill": {"teachers": [str(teacher_run)]}})  # fmt: skip
    (tmp_path / "student.toml").write_text(toml)
    code = main(["train", "--config", str(tmp_path / "student.toml"), "--out", str(tmp_path / "s"),
                 "--iterations", "2"])  # fmt: skip
    out, err = capsys.readouterr()
    assert code == 0, err
    text = out + err
    assert "student of 1 teacher run(s)" in text
    mae = [float(line.split("teacher action MAE ")[1].split()[0]) for line in text.splitlines()
           if "teacher action MAE " in line]  # fmt: skip
    assert len(mae) >= 1 and all(np.isfinite(mae)) and mae[0] > 0, text
    assert "entropy" not in text.split("student of")[1]  # MOPPO's loss terms are not shown


def _kickstarted(env, teacher: ClipConstantTeacher, config: TrainConfig, kl_coef: float, fade: int):
    from amorctl.plugins.backends.torch_cpu.distill import DistillTrainer

    torch.set_num_threads(1)
    return DistillTrainer(Taught(env, teacher), config.network, config.ppo, seed=0, learning_rate=3e-3,
                          kickstart=(kl_coef, fade))  # fmt: skip


def test_kickstarting_adds_the_fading_teacher_kl_to_moppos_loss(make_tracking_run, tmp_path: Path) -> None:
    """``[distill] rewards = true``: the loss is MOPPO's plus kl_coef(t) x KL(teacher || student),
    the coefficient falling linearly to 0 over kl_fade_iterations; a strong KL pulls the actions
    to the teachers', the rewards alone (kl_coef 0) leave them far from them."""
    from amorctl.envs.factory import make_env

    make_tracking_run(tmp_path, "kickstart test data")
    config = _student_config(tmp_path, ["unused: the test hands its own teacher"])
    backend = get_registry().backend("torch-cpu").make()
    errors = {}
    for coef in (5.0, 0.0):
        env = make_env(config, backend)
        teacher = ClipConstantTeacher(env.action_dim)
        trainer = _kickstarted(env, teacher, config, coef, fade=0)
        for _ in range(40):
            last = trainer.iteration()
        target, _ = teacher(trainer.obs.numpy(), env.tracking_view().clip_index())
        errors[coef] = float(np.abs(trainer.act(trainer.obs.numpy()) - target).mean())
        env.close()
        assert last["distill/kl_coef"] == pytest.approx(coef)
        # MOPPO's terms are all there, and the KL's weight on top of them
        moppo = last["loss/policy"] + config.ppo.value_coef * last["loss/value"]
        moppo -= config.ppo.entropy_coef * last["loss/entropy"]
        assert last["loss/total"] == pytest.approx(moppo + coef * last["distill/kl"], rel=1e-4, abs=1e-5)
    assert errors[5.0] < 0.06 < 0.2 < errors[0.0], errors

    env = make_env(config, backend)
    trainer = _kickstarted(env, ClipConstantTeacher(env.action_dim), config, 2.0, fade=10)
    coefs = []
    for _ in range(12):
        coefs.append(trainer.kl_coef())
        trainer.iteration()
    env.close()
    assert coefs[:3] == pytest.approx([2.0, 1.8, 1.6]) and coefs[5] == pytest.approx(1.0)
    assert coefs[10:] == [0.0, 0.0]


def test_kickstart_settings_need_teachers_and_rewards() -> None:
    with pytest.raises(AmorError, match=r"\[distill\] rewards = true needs \[distill\] teachers"):
        merge(TrainConfig(), {"distill": {"rewards": True}}, "test")
    with pytest.raises(AmorError, match=r"\[distill\] kl_coef = 2 needs \[distill\] rewards = true"):
        merge(TrainConfig(), {"distill": {"teachers": ["x"], "kl_coef": 2.0}}, "test")
    with pytest.raises(AmorError, match=r"kl_fade_iterations"):
        merge(TrainConfig(), {"distill": {"teachers": ["x"], "kl_fade_iterations": -1}}, "test")
    config = merge(
        TrainConfig(), {"distill": {"teachers": ["x"], "rewards": True, "kl_fade_iterations": 50}}, "test"
    )
    assert config.distill.rewards and config.distill.kl_fade_iterations == 50


def test_train_command_shows_a_kickstarted_run(
    teacher_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Kickstarting: the header says so and each progress line shows MOPPO's losses beside the
    teachers' weighted KL, the coefficient fading on schedule."""
    from amorctl.cli.main import main

    config = _student_config(teacher_run.parent, [str(teacher_run)])
    (tmp_path / "k.toml").write_text(
        f'[env]\ndataset = "{config.env.dataset}"\nnum_envs = 8\nepisode_seconds = 0.4\n'
        "[network]\nactor_hidden = [32]\ncritic_hidden = [16]\n"
        '[ppo]\nnum_steps = 8\nnum_minibatches = 2\nprecision = "fp32"\n'
        "[run]\ntensorboard = false\nthreads = 1\n"
        f'[distill]\nteachers = ["{teacher_run}"]\nrewards = true\nkl_coef = 0.5\nkl_fade_iterations = 2\n'
    )
    code = main(
        ["train", "--config", str(tmp_path / "k.toml"), "--out", str(tmp_path / "k"), "--iterations", "3"]
    )
    out, err = capsys.readouterr()
    assert code == 0, err
    text = out + err
    assert "kickstarted by 1 teacher run(s)" in text
    shown = [
        line.split("teacher KL ")[1].split(" x ")[1] for line in text.splitlines() if "teacher KL " in line
    ]
    coefs = [float(part.split()[0].rstrip(")")) for part in shown]
    assert coefs and coefs[0] == pytest.approx(0.5), text
    metrics = (tmp_path / "k" / "metrics.csv").read_text().splitlines()
    header = metrics[0].split(",")
    column = [float(row.split(",")[header.index("distill/kl_coef")]) for row in metrics[1:]]
    assert column == pytest.approx([0.5, 0.25, 0.0])
    code = main(["train", "--config", str(tmp_path / "k.toml"), "--out", str(tmp_path / "kj"),
                 "--iterations", "1", "--json"])  # fmt: skip
    out, err = capsys.readouterr()
    assert code == 0, err
    last = json.loads(out)["metrics"]  # one JSON document, the last iteration's kickstart figures in it
    assert last["distill/kl_coef"] == pytest.approx(0.5) and last["distill/kl"] >= 0, last
