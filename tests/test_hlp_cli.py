"""`amorctl evaluate RUN --hlp HLPDIR --compare` (Table 2) and `amorctl tune RUN --hlp HLPDIR`."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from amorctl.cli.main import main
from amorctl.hlp.config import HlpConfig, merge
from amorctl.hlp.run import train_hlp

TINY = {
    "run": {"iterations": 1, "checkpoint_every": 1, "tensorboard": False, "threads": 1},
    "env": {"num_envs": 4, "episode_seconds": 0.3},
    "policy": {"actor_hidden": [16, 16, 16], "critic_hidden": [16, 16, 16]},
    "ppo": {"num_steps": 6, "num_epochs": 1, "num_minibatches": 2},
    "discriminator": {"window": 4, "hidden": [16], "z_hidden": [8], "batch_size": 32, "replay_size": 64},
}


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def hlp_dir(tracking_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("hlp-cli") / "hlp"
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        train_hlp(tracking_run, out, merge(HlpConfig(), TINY, "TINY"))
    finally:
        torch.set_num_threads(threads)
    return out


def run_cli(capsys: pytest.CaptureFixture, *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_evaluate_hlp_compare_prints_table2_json(tracking_run: Path, hlp_dir: Path, capsys) -> None:
    code, out, err = run_cli(
        capsys, "evaluate", tracking_run, "--hlp", hlp_dir, "--compare", "--weights", "smooth=1",
        "--hlp-envs", "4", "--hlp-seconds", "1", "--disc-steps", "10", "--json",
    )  # fmt: skip
    assert code == 0, err
    data = json.loads(out)
    assert data["schema"] == "amorctl.hlp_table/1"
    assert [r["label"] for r in data["rows"]][:2] == ["uniform", "w = smooth=1"]
    assert data["rows"][2]["label"].startswith("HLP hlp")
    assert data["rows"][1]["mean_w"][6] == pytest.approx(1.0)
    assert data["options"]["num_envs"] == 4 and data["options"]["steps"] == 10


def test_evaluate_hlp_bad_input(tracking_run: Path, toy_run: Path, hlp_dir: Path, capsys) -> None:
    for args, needle in (
        (("evaluate", tracking_run, "--hlp", hlp_dir), "--compare"),
        (("evaluate", tracking_run, "--hlp", hlp_dir, "--compare", "--sweep", "up"), "--sweep"),
        (("evaluate", toy_run, "--hlp", hlp_dir, "--compare"), "HLP was trained for"),
        (("evaluate", tracking_run, "--hlp", tracking_run, "--compare"), "not an HLP directory"),
        (("evaluate", tracking_run, "--hlp", hlp_dir, "--compare", "--motion", "nope"), "'nope'"),
    ):
        code, _, err = run_cli(capsys, *args)
        assert code == 2 and err.count("error:") == 1 and needle in err, (args, err)


def test_tune_hlp_scales_weights_and_reports_them(
    tracking_run: Path, hlp_dir: Path, tmp_path, capsys
) -> None:
    mcap = tmp_path / "r.mcap"
    code, out, err = run_cli(
        capsys, "tune", tracking_run, "--hlp", hlp_dir, "--motion", "sway_a", "--scale", "smooth=4,up=0",
        "--seconds", "0.3", "--out", mcap, "--json", "--no-stop-on-fall",
    )  # fmt: skip
    assert code == 0, err
    data = json.loads(out)
    hlp = data["hlp"]
    assert hlp["scales"]["smooth"] == 4 and hlp["scales"]["up"] == 0
    assert hlp["mean_weights"]["up"] == 0
    assert hlp["mean_weights"]["smooth"] > hlp["mean_hlp_weights"]["smooth"]
    assert sum(hlp["mean_weights"].values()) == pytest.approx(1.0, abs=1e-5)
    assert mcap.is_file() and data["steps"] == 15
    for args, needle in (
        (("tune", tracking_run, "--hlp", hlp_dir, "--weights", "uniform"), "--weights"),
        (("tune", tracking_run, "--hlp", hlp_dir, "--scale", "nope=2"), "'nope'"),
        (("tune", tracking_run, "--scale", "up=2", "--weights", "uniform"), "--scale"),
    ):
        code, _, err = run_cli(capsys, *args)
        assert code == 2 and err.count("error:") == 1 and needle in err, (args, err)
