"""Commands that plugins add (hook ``amorctl_register_commands``, docs/plugins.md "Commands"): the
stickman test plugin's command runs and is listed; a broken one is reported and isolated."""

from __future__ import annotations

import json
import math
import types

import pytest
import typer

from amorctl import registry as reg
from amorctl.api import AmorError, CommandSpec, hookimpl
from amorctl.cli.main import main


def _plugin(register_commands) -> types.ModuleType:
    module = types.ModuleType("fake_command_plugin")
    module.amorctl_register_commands = hookimpl(register_commands)  # type: ignore[attr-defined]
    return module


@pytest.fixture
def with_plugins(monkeypatch: pytest.MonkeyPatch):
    """Make ``get_registry()`` return the installed plugins plus fake (name, hook, package) ones."""

    def install(*plugins: tuple[str, object, str]) -> None:
        extra = [(name, _plugin(hook), package, "1.0") for name, hook, package in plugins]
        monkeypatch.setattr(reg, "_CACHED", reg.load_registry(extra_plugins=extra))

    return install


def _flat(text: str) -> str:
    """Help text without rich's box characters and line breaks."""
    return " ".join(text.translate({ord(c): " " for c in "│╭╮╰╯─"}).split())


def test_the_stickman_plugin_adds_a_command_that_runs_and_is_listed(capsys: pytest.CaptureFixture) -> None:
    assert main(["stickman", "calibrate", "--offset", "2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["character"] == "stickman12" and len(out["offsets"]) == 12
    assert out["offsets"]["left_knee"] == pytest.approx(math.radians(2))

    assert main(["stickman", "joints"]) == 0
    assert capsys.readouterr().out.splitlines()[:2] == ["left_shoulder upper", "left_elbow upper"]

    assert main(["plugins", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["plugins"]
    assert {
        "name": "stickman",
        "kind": "command",
        "package": "amorctl-stickman",
        "plugin": "stickman12",
    }.items() <= next(r for r in rows if r["kind"] == "command").items()

    assert main(["--help"]) == 0
    help_text = _flat(capsys.readouterr().out)
    assert help_text.index("Commands") < help_text.index("Plugin commands")
    listed = "stickman Stickman12 robot tools: servo calibration and joints. (from amorctl-stickman)"
    assert f"Plugin commands {listed}" in help_text
    assert main(["stickman", "--help"]) == 0
    assert "Usage: amorctl stickman" in capsys.readouterr().out


def test_a_broken_command_plugin_is_reported_and_the_rest_works(
    with_plugins, capsys: pytest.CaptureFixture
) -> None:
    hello = typer.Typer()

    @hello.command()
    def greet() -> None:
        """Say hello."""
        print("hello")

    def explode(register) -> None:
        raise RuntimeError("no calibration board")

    with_plugins(
        ("badcmd", explode, "amorctl-bad"),
        ("wrongtype", lambda register: register(CommandSpec("gadget", object())), "amorctl-wrong"),
        ("shadow", lambda register: register(CommandSpec("train", hello)), "amorctl-shadow"),
        ("badname", lambda register: register(CommandSpec("Bad Name", hello)), "amorctl-badname"),
        ("okcmd", lambda register: register(CommandSpec("hello", hello)), "amorctl-ok"),
    )
    assert main(["plugins", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    problems = {p["plugin"]: p for p in listed["problems"]}
    assert {p["status"] for p in problems.values()} == {"broken"}
    assert problems["badcmd"]["package"] == "amorctl-bad"
    assert problems["badcmd"]["error"] == "RuntimeError: no calibration board"
    assert problems["wrongtype"]["error"] == (
        "command 'gadget': TypeError: expected a typer.Typer app or a click command, got object"
    )
    assert (
        problems["shadow"]["error"] == "command 'train': ValueError: a built-in amorctl command has this name"
    )
    assert "lower-case letters, digits and hyphens" in problems["badname"]["error"]
    assert {(r["name"], r["package"]) for r in listed["plugins"] if r["kind"] == "command"} >= {
        ("hello", "amorctl-ok"),
        ("stickman", "amorctl-stickman"),
    }

    assert main(["plugins"]) == 0
    assert "broken plugin 'badcmd' from package 'amorctl-bad'" in capsys.readouterr().out
    assert main(["hello"]) == 0  # a one-command typer app runs as the command itself
    assert capsys.readouterr().out == "hello\n"
    assert main(["stickman", "calibrate", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["offsets"]["left_knee"] == 0.0
    assert main(["characters", "list", "--json"]) == 0
    assert "stickman12" in {c["name"] for c in json.loads(capsys.readouterr().out)["characters"]}
    assert main(["train", "--help"]) == 0  # the built-in, not the plugin's `train`
    assert "MOPPO" in capsys.readouterr().out
    assert main(["gadget"]) == 2
    assert "No such command 'gadget'" in _flat(capsys.readouterr().err)
    assert main(["--help"]) == 0
    help_text = _flat(capsys.readouterr().out)
    assert "hello Say hello. (from amorctl-ok)" in help_text and "gadget" not in help_text


def test_a_click_group_gets_its_arguments_and_gives_its_exit_status(
    with_plugins, capsys: pytest.CaptureFixture
) -> None:
    click = pytest.importorskip("click")

    @click.group(help="Vendor hardware bridge.")
    def bridge() -> None:
        pass

    @bridge.command()
    @click.option("--port", type=int, required=True)
    def connect(port: int) -> None:
        click.echo(f"connected on port {port}")

    @bridge.command()
    def unplugged() -> None:
        raise AmorError("bridge: no device on /dev/ttyUSB0 (plug the robot in)")

    with_plugins(("bridge", lambda register: register(CommandSpec("bridge", bridge)), "amorctl-bridge"))
    assert main(["bridge", "connect", "--port", "7"]) == 0
    assert capsys.readouterr().out == "connected on port 7\n"
    assert main(["bridge", "connect"]) == 2
    assert "Missing option '--port'" in capsys.readouterr().err
    assert main(["bridge", "unplugged"]) == 2
    assert capsys.readouterr().err == "error: bridge: no device on /dev/ttyUSB0 (plug the robot in)\n"
    assert main(["bridge", "--help"]) == 0
    out = capsys.readouterr().out
    assert "Usage: amorctl bridge" in out and "connect" in out and "unplugged" in out
    assert main(["--help"]) == 0
    assert "bridge Vendor hardware bridge. (from amorctl-bridge)" in _flat(capsys.readouterr().out)
