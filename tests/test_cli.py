"""CLI outputs and exit codes, in-process and through the installed console script."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from amorctl import __version__
from amorctl.cli.main import main
from amorctl.core.config import load_preset
from amorctl.core.errors import AmorError


def run(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_version(capsys: pytest.CaptureFixture) -> None:
    code, out, _ = run(capsys, "--version")
    assert code == 0
    assert out.strip() == f"amorctl {__version__}"


def test_plugins_json_lists_builtins_and_the_third_party_package(capsys: pytest.CaptureFixture) -> None:
    code, out, _ = run(capsys, "plugins", "--json")
    assert code == 0
    rows = {(p["name"], p["kind"]): p for p in json.loads(out)["plugins"]}
    assert rows[("humanoid36", "character")]["package"] == "amorctl"
    assert rows[("biped20", "character")]["package"] == "amorctl"
    assert {rows[(f, "motion-format")]["package"] for f in ("deepmimic", "bvh", "npz")} == {"amorctl"}
    third = rows[("stickman12", "character")]
    assert (third["package"], third["version"]) == ("amorctl-stickman", "0.2.0")


def test_plugins_table(capsys: pytest.CaptureFixture) -> None:
    code, out, _ = run(capsys, "plugins")
    assert code == 0
    assert "stickman12" in out and "amorctl-stickman" in out


def test_characters_list_json(capsys: pytest.CaptureFixture) -> None:
    code, out, _ = run(capsys, "characters", "list", "--json")
    assert code == 0
    joints = {c["name"]: c["num_joints"] for c in json.loads(out)["characters"]}
    assert joints["humanoid36"] == 30
    assert joints["biped20"] == 20
    assert joints["stickman12"] == 12


def test_characters_show_third_party_character(capsys: pytest.CaptureFixture) -> None:
    code, out, _ = run(capsys, "characters", "show", "stickman12", "--json")
    assert code == 0
    info = json.loads(out)
    assert (info["nq"], info["nv"], info["nu"]) == (19, 18, 12)
    assert info["root_body"] == "root"
    assert {j["group"] for j in info["joints"]} == {"upper", "lower", "feet"}
    assert info["end_effectors"] == ["left_hand", "right_hand", "left_foot", "right_foot"]
    assert info["physics_hz"] == 250 and info["control_hz"] == 50


@pytest.mark.parametrize("name", ["humanoid36", "biped20"])
def test_characters_show_table(capsys: pytest.CaptureFixture, name: str) -> None:
    code, out, _ = run(capsys, "characters", "show", name)
    assert code == 0
    assert "nv=" in out and "upper" in out and "feet" in out


def test_unknown_character_is_one_line_and_exit_2(capsys: pytest.CaptureFixture) -> None:
    code, out, err = run(capsys, "characters", "show", "nope")
    assert code == 2
    assert out == ""
    assert err.startswith("error: unknown character 'nope' (installed: biped20, humanoid36")
    assert err.count("\n") == 1


def _console(*args: str, debug: bool = False) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "AMORCTL_DEBUG"}
    if debug:
        env["AMORCTL_DEBUG"] = "1"
    exe = os.path.join(os.path.dirname(sys.executable), "amorctl")
    return subprocess.run([exe, *args], capture_output=True, text=True, env=env, timeout=120)


def test_console_script_error_has_no_traceback() -> None:
    proc = _console("characters", "show", "nope")
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().startswith("error: unknown character 'nope'")


def test_debug_env_shows_the_traceback() -> None:
    proc = _console("characters", "show", "nope", debug=True)
    assert proc.returncode != 0
    assert "Traceback" in proc.stderr and "AmorError" in proc.stderr


def test_usage_error_exits_non_zero() -> None:
    proc = _console("characters", "frobnicate")
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr


def _train_context(args: list[str]):
    import typer
    import typer.main

    from amorctl.cli import train as cli_train

    app = typer.Typer()
    app.command()(cli_train.train)
    return typer.main.get_command(app).make_context("train", args)


def test_train_options_map_to_config_fields_by_parameter_name(tmp_path: Path) -> None:
    """A train option named SECTION__KEY sets that config field; errors name its flag; torchrun's
    ranks get the same options (without --nproc, with --out fixed)."""
    from amorctl.cli import train as cli_train

    ctx = _train_context(["-c", "humanoid36", "--num-envs", "8", "--seed", "3", "--json", "--nproc", "2"])
    overrides, flags = cli_train._command_line(ctx)
    assert overrides == {"env": {"character": "humanoid36", "num_envs": 8}, "run": {"seed": 3}}
    assert flags[("env", "num_envs")] == "--num-envs" and flags[("env", "dataset")] == "--data"
    assert cli_train._relaunch_args(ctx, tmp_path / "r") == [
        "--character", "humanoid36", "--out", str(tmp_path / "r"), "--seed", "3", "--num-envs", "8", "--json"
    ]  # fmt: skip
    with pytest.raises(AmorError, match=r"^--num-envs: "):
        cli_train._apply_flags(load_preset("quick"), {"env": {"num_envs": 0}}, flags)
