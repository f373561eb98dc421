"""A run directory works from anywhere: ``train --data REL`` stores the dataset absolute
with its SHA-256; a moved dataset is refused naming the run's config key, and ``--data NEWPATH``
(the same file) is enough for evaluate, pareto, tune and deploy export."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from pathlib import Path

import pytest

from amorctl.cli.main import main
from amorctl.core.config import load_config
from amorctl.core.errors import AmorError
from amorctl.core.files import file_sha256

TINY = """
[run]
iterations = 1
checkpoint_every = 1
tensorboard = false
threads = 1
[env]
kind = "tracking"
character = "biped20"
num_envs = 4
episode_seconds = 0.4
[network]
actor_hidden = [16]
critic_hidden = [16]
[ppo]
num_steps = 4
num_epochs = 1
num_minibatches = 1
"""


def _dataset(path: Path) -> Path:
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.motion.dataset import write_dataset
    from amorctl.registry import get_registry

    lib = synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=1.0, seed=3)
    clips = tuple(
        dataclasses.replace(c, name=n) for c, n in zip(lib.clips, ("sway_a", "sway_b"), strict=True)
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    write_dataset(path, dataclasses.replace(lib, clips=clips))
    return path


@pytest.fixture(scope="module")
def relative_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``cd project && amorctl train --data data/ds.mcap --out runs/r``: the project directory."""
    import torch

    project = tmp_path_factory.mktemp("project")
    _dataset(project / "data" / "ds.mcap")
    (project / "tiny.toml").write_text(TINY)
    here, threads = Path.cwd(), torch.get_num_threads()
    os.chdir(project)
    try:
        code = main(["train", "--config", "tiny.toml", "--data", "data/ds.mcap", "--out", "runs/r", "--json"])
    finally:
        os.chdir(here)
        torch.set_num_threads(threads)
    assert code == 0
    return project


def _run(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_train_stores_the_dataset_absolute_with_its_hash(relative_run: Path) -> None:
    config = load_config(relative_run / "runs" / "r" / "config.toml")
    data = relative_run / "data" / "ds.mcap"
    assert config.env.dataset == str(data.resolve())
    assert config.env.dataset_sha256 == file_sha256(data) and len(config.env.dataset_sha256) == 64


def test_the_run_works_from_another_directory_and_finds_its_moved_dataset(
    relative_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.setenv("AMORCTL_CACHE_DIR", str(tmp_path / "cache"))
    project = tmp_path / "project"
    shutil.copytree(relative_run, project)  # this test moves the dataset: keep the fixture intact
    run = project / "runs" / "r"
    config_path = run / "config.toml"
    text = config_path.read_text().replace(str(relative_run.resolve()), str(project.resolve()))
    config_path.write_text(text)  # the copy's config points at the copy's dataset
    monkeypatch.chdir(tmp_path)  # not the directory train ran in
    code, out, err = _run(capsys, "evaluate", str(run), "--episodes", "1", "--motion", "sway_b", "--json")
    assert code == 0, err
    assert json.loads(out)["motions"] == ["sway_b"]  # a clip of the run's dataset

    moved = tmp_path / "elsewhere" / "renamed.mcap"
    moved.parent.mkdir()
    (project / "data" / "ds.mcap").rename(moved)
    sha = file_sha256(moved)
    old = project.resolve() / "data" / "ds.mcap"
    expected = (
        f"error: {config_path}: env.dataset = '{old}': the run's motion dataset is not there (moved or "
        f"deleted): pass --data NEWPATH (the same file with SHA-256 {sha[:12]}…), or set env.dataset in "
        f"{config_path} to where it is now\n"
    )
    for argv in (
        ["evaluate", str(run), "--episodes", "1"],
        ["deploy", "export", str(run), "--out", str(tmp_path / "b0")],
        ["tune", str(run), "--weights", "up=1", "--seconds", "0.2"],
        ["train", "--resume", "--out", str(run), "--iterations", "2"],
    ):
        code, out, err = _run(capsys, *argv)
        assert (code, err) == (2, expected), argv
    assert not (tmp_path / "b0").exists()
    from amorctl.hlp.run import run_dataset
    from amorctl.train.rundir import RunDir

    with pytest.raises(AmorError, match=r"env\.dataset = .*pass --data NEWPATH"):
        run_dataset(RunDir.open(run))  # hlp reads the dataset the same way

    # --data with the same file: the run's own dataset, no re-encoding (nothing in the cache)
    code, out, err = _run(
        capsys, "evaluate", str(run), "--data", str(moved), "--episodes", "1", "--motion", "sway_a", "--json"
    )
    assert code == 0, err
    assert json.loads(out)["motions"] == ["sway_a"]
    code, out, err = _run(
        capsys, "tune", str(run), "--data", str(moved), "--weights", "up=1", "--seconds", "0.2", "--json"
    )
    assert code == 0, err
    assert not (tmp_path / "cache" / "heldout").exists()
    code, out, err = _run(
        capsys, "deploy", "export", str(run), "--data", str(moved), "--out", str(tmp_path / "b"), "--json"
    )
    assert code == 0, err
    with_motions = json.loads((tmp_path / "b" / "deploy.json").read_text())["motions"]
    assert with_motions["clips"] == ["sway_a", "sway_b"]

    code, out, err = _run(
        capsys, "train", "--resume", "--out", str(run), "--iterations", "2", "--data", str(moved), "--json"
    )
    assert code == 0, err
    assert json.loads(out)["end_iteration"] == 2

    other = _dataset(tmp_path / "other.mcap")  # same clips, another file: not the run's dataset
    other.write_bytes(other.read_bytes() + b"\0")
    code, out, err = _run(
        capsys, "deploy", "export", str(run), "--data", str(other), "--out", str(tmp_path / "c")
    )
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"error: --data {other}: not the run's dataset (its SHA-256 is not the {sha[:12]}…")
    assert not (tmp_path / "c").exists()


def test_resume_with_the_same_relative_data_as_train(
    relative_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """The command line that started the run continues it (its --data now stored absolute)."""
    project = tmp_path / "project"
    shutil.copytree(relative_run, project)
    config_path = project / "runs" / "r" / "config.toml"
    config_path.write_text(
        config_path.read_text().replace(str(relative_run.resolve()), str(project.resolve()))
    )
    monkeypatch.chdir(project)
    code, out, err = _run(
        capsys,
        "train",
        "--resume",
        "--out",
        "runs/r",
        "--data",
        "data/ds.mcap",
        "--iterations",
        "2",
        "--json",
    )
    assert code == 0, err
    assert json.loads(out)["end_iteration"] == 2


def test_hlp_commands_take_the_runs_moved_dataset_with_data(
    relative_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """``hlp train`` / ``hlp trace`` find a moved dataset with ``--data`` (the message says so);
    another file is refused: an HLP runs on the clips its run was trained on."""
    monkeypatch.setenv("AMORCTL_CACHE_DIR", str(tmp_path / "cache"))
    run = tmp_path / "r"
    shutil.copytree(relative_run / "runs" / "r", run)  # its config points at the fixture's dataset
    moved = tmp_path / "moved.mcap"
    shutil.copy(relative_run / "data" / "ds.mcap", moved)
    config_path = run / "config.toml"
    config_path.write_text(
        config_path.read_text().replace(str(relative_run.resolve()), str(tmp_path / "gone"))
    )
    hlp = ["hlp", "train", str(run), "--out", str(tmp_path / "h"), "--window", "4"]
    hlp += ["--iterations", "1", "--num-envs", "4", "--json"]
    code, out, err = _run(capsys, *hlp)
    assert code == 2 and "pass --data NEWPATH" in err and err.count("\n") == 1, err
    assert not (tmp_path / "h").exists()

    other = tmp_path / "other.mcap"
    other.write_bytes(moved.read_bytes() + b"\0")
    code, out, err = _run(capsys, *hlp, "--data", str(other))
    assert code == 2 and err.startswith(f"error: --data {other}: not the run's dataset"), err
    assert "an HLP runs on its AMOR run's own dataset" in err and not (tmp_path / "h").exists()

    code, out, err = _run(capsys, *hlp, "--data", str(moved))
    assert code == 0, err
    assert json.loads(out)["end_iteration"] == 1
    code, out, err = _run(
        capsys, "hlp", "trace", str(tmp_path / "h"), "--motion", "sway_a", "--data", str(moved), "--json"
    )
    assert code == 0, err
    (trace,) = json.loads(out)["traces"]
    assert trace["segments"][0]["motion"] == "sway_a" and trace["steps"] > 10


def test_a_library_for_another_joint_order_names_the_first_difference() -> None:
    from amorctl.envs.synthetic import synthetic_library
    from amorctl.envs.tracking_checks import check_library
    from amorctl.registry import get_registry

    ch = get_registry().character("biped20")
    lib = synthetic_library(ch, num_clips=1, seconds=0.5, seed=0)
    names = list(lib.joint_names)
    names[1], names[2] = names[2], names[1]
    with pytest.raises(AmorError) as err:
        check_library(ch, dataclasses.replace(lib, joint_names=tuple(names)))
    assert str(err.value) == (
        f"motion library joints do not match the joints of character biped20: "
        f"#1 is {names[1]!r}, the character's is {names[2]!r}"
    )
