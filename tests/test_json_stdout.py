"""Under ``--json`` stdout is the JSON and nothing else, for every command and backend (docs/cli.md).

The commands are enumerated from the CLI itself (plugins' commands included), so a new ``--json``
command fails :func:`test_every_json_command_has_an_invocation_here` until :func:`invocations`
runs it. All of them run on a tiny torch-cpu run in one fresh process (~12 s on 2 cores); on a
jax-mjx run, XLA compiles each command's rollout (minutes), so that test is ``slow``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import typer
import typer.main

from amorctl.cli.main import app, plugin_commands, run_app
from amorctl.cli.output import print_json

ROOT = Path(__file__).resolve().parents[1]


def json_commands() -> list[str]:
    """Every command of ``amorctl`` (built-in or a plugin's) that takes ``--json``, as 'group sub'."""
    found: list[str] = []

    def walk(command, path: list[str]) -> None:
        if hasattr(command, "list_commands"):
            ctx = command.context_class(command, info_name=path[-1] if path else "amorctl")
            for name in command.list_commands(ctx):
                walk(added.get(name) if not path and name in added else command.get_command(ctx, name),
                     [*path, name])  # fmt: skip
        if any("--json" in getattr(p, "opts", ()) for p in command.params):
            found.append(" ".join(path))

    added = plugin_commands().targets  # the root runs these through forwarding commands
    walk(typer.main.get_command(app), [])
    return sorted(found)


def invocations(tmp: Path, run: Path, ds: Path) -> dict[str, list[str]]:
    """One ``--json`` invocation of every command, on the tiny torch-cpu run ``run`` (trained on the
    dataset ``ds`` with clips ``sway_a``/``sway_b``); they run in this order, later ones use what
    earlier ones wrote under ``tmp``."""
    from amorctl.motion.builtin import pybullet_data_path

    clip = pybullet_data_path() / "data" / "motions" / "humanoid3d_walk.txt"
    hlp_toml = tmp / "hlp.toml"
    hlp_toml.write_text(HLP_TOML)
    (tmp / "runs").mkdir()
    s = str
    return {
        "plugins": ["plugins", "--json"],
        "plugins new": ["plugins", "new", "jsonbot", "--out", s(tmp / "jsonbot"), "--json"],
        "characters list": ["characters", "list", "--json"],
        "characters show": ["characters", "show", "biped20", "--json"],
        "characters check": ["characters", "check", "biped20", "--no-hold", "--json"],
        "preprocess": ["preprocess", s(clip), "--character", "humanoid36", "--out", s(tmp / "walk.mcap"),
                       "--no-vae", "--json"],
        "data show": ["data", "show", s(ds), "--json"],
        "data speeds": ["data", "speeds", s(ds), "--json"],
        "train": ["train", "--env", "toy", "--iterations", "1", "--num-envs", "8",
                  "--out", s(tmp / "runs" / "toy"), "--json"],
        "pareto": ["pareto", s(run), "--samples", "2", "--out", s(tmp / "pareto"), "--json"],
        "evaluate": ["evaluate", s(run), "--motion", "sway_a", "--episodes", "1", "--json"],
        "tune": ["tune", s(run), "--motion", "sway_a", "--weights", "up=1", "--seconds", "0.2", "--json"],
        "deploy export": ["deploy", "export", s(run), "--out", s(tmp / "bundle"), "--json"],
        "deploy run": ["deploy", "run", s(tmp / "bundle"), "--motion", "sway_a", "--seconds", "0.2",
                       "--json"],
        "deploy check": ["deploy", "check", s(tmp / "bundle"), "--episodes", "1", "--seconds", "0.2",
                         "--weights", "smooth=1", "--json"],
        "hlp train": ["hlp", "train", s(run), "--out", s(tmp / "hlp"), "--config", s(hlp_toml), "--json"],
        "hlp trace": ["hlp", "trace", s(tmp / "hlp"), "--motion", "sway_a", "--json"],
        "runs list": ["runs", "list", s(tmp / "runs"), "--json"],
        "runs export-pretrained": ["runs", "export-pretrained", s(run), "--name", "jsonrun",
                                   "--out", s(tmp / "pretrained"), "--commit", "test", "--json"],
        "stickman calibrate": ["stickman", "calibrate", "--offset", "1", "--json"],
    }  # fmt: skip


HLP_TOML = """
[run]
iterations = 1
checkpoint_every = 1
tensorboard = false
threads = 1
[env]
num_envs = 4
episode_seconds = 0.3
[policy]
actor_hidden = [16]
critic_hidden = [16]
[ppo]
num_steps = 4
num_epochs = 1
num_minibatches = 2
[discriminator]
window = 4
hidden = [16]
z_hidden = [8]
batch_size = 16
replay_size = 32
steps_per_iteration = 1
"""

#: a jax-mjx tracking run as small as it gets (its XLA compile still takes ~1 min on 2 cores)
JAX_TOML = """
[run]
iterations = 1
checkpoint_every = 1
tensorboard = false
backend = "jax-mjx"
[env]
kind = "tracking"
character = "biped20"
dataset = "{ds}"
num_envs = 4
episode_seconds = 0.2
[network]
actor_hidden = [16]
critic_hidden = [16]
[ppo]
num_steps = 4
num_epochs = 1
num_minibatches = 1
precision = "fp32"
"""

#: runs amorctl commands one after another in one process, the status of each on stderr
RUNNER = """
import json, sys
from amorctl.cli.main import main
for argv in json.loads(sys.argv[1]):
    print(f"@@status {main(argv)} {' '.join(argv[:2])}", file=sys.stderr, flush=True)
"""


def run_commands(commands: list[list[str]], cwd: Path, timeout: float) -> list[object]:
    """Run ``commands`` in a fresh process (libraries imported for the first time, the real
    stdout); each must exit 0. Returns the JSON documents on stdout, which must be all of it."""
    proc = subprocess.run(
        [sys.executable, "-c", RUNNER, json.dumps(commands)],
        cwd=cwd, capture_output=True, text=True, timeout=timeout, env={**os.environ, "COLUMNS": "100"},
    )  # fmt: skip
    statuses = [line.split()[1:] for line in proc.stderr.splitlines() if line.startswith("@@status")]
    failed = [s for s in statuses if s[0] != "0"]
    assert proc.returncode == 0 and len(statuses) == len(commands) and not failed, proc.stderr[-4000:]
    return json_documents(proc.stdout)


def json_documents(text: str) -> list[object]:
    """The JSON values ``text`` holds one after another; anything else in it fails, showing where."""
    decoder, docs, i = json.JSONDecoder(), [], 0
    while (i := len(text) - len(text[i:].lstrip())) < len(text):
        try:
            doc, i = decoder.raw_decode(text, i)
        except json.JSONDecodeError:
            pytest.fail(f"not JSON on stdout at {i}: {text[max(0, i - 200) : i + 300]!r}")
        docs.append(doc)
    return docs


def test_json_documents_reads_a_sequence_and_fails_on_anything_else() -> None:
    assert json_documents('{"a": 1}\n[2]\n  {"b": {"c": 3}}\n') == [{"a": 1}, [2], {"b": {"c": 3}}]
    with pytest.raises(pytest.fail.Exception, match="Failed to import warp"):
        json_documents("Failed to import warp: No module named 'warp'\n{\"a\": 1}\n")


def test_every_json_command_has_an_invocation_here(tmp_path: Path) -> None:
    commands = json_commands()
    assert {"plugins", "evaluate", "deploy run", "hlp trace", "stickman calibrate"} <= set(commands)
    pytest.importorskip("pybullet_data")
    assert commands == sorted(invocations(tmp_path, tmp_path / "run", tmp_path / "ds.mcap"))


# ---------------------------------------------------------------------------- the mechanism
def _chatty_app(tmp_path: Path) -> typer.Typer:
    """A command that imports a module printing on stdout (as mujoco.mjx does without warp),
    prints itself, writes on sys.stdout and through rich, then its JSON."""
    (tmp_path / "chatty_lib.py").write_text("print(\"Failed to import warp: No module named 'warp'\")\n")
    sys.path.insert(0, str(tmp_path))
    chatty = typer.Typer()

    @chatty.command()
    def show(json_out: bool = typer.Option(False, "--json")) -> None:
        import chatty_lib  # noqa: F401

        from amorctl.cli.output import console

        print("progress 50%")
        sys.stdout.write("a note\n")
        console.print("[bold]a table[/bold]")
        if json_out:
            print_json({"answer": 42})
        else:
            print("answer: 42")

    return chatty


def test_under_json_what_else_is_printed_on_stdout_goes_to_stderr(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    chatty = _chatty_app(tmp_path)
    try:
        assert run_app(chatty, "chatty", ["--json"]) == 0
        out, err = capsys.readouterr()
        assert json.loads(out) == {"answer": 42}
        assert err.splitlines() == [
            "Failed to import warp: No module named 'warp'",
            "progress 50%",
            "a note",
            "a table",
        ]
        sys.modules.pop("chatty_lib")
        assert run_app(chatty, "chatty", []) == 0  # without --json: stdout as before
        out, err = capsys.readouterr()
        assert out.splitlines()[-1] == "answer: 42" and "progress 50%" in out and err == ""
        assert sys.stdout is not sys.stderr  # restored
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("chatty_lib", None)


def test_the_jax_backend_imports_mjx_without_its_chatter() -> None:
    pytest.importorskip("jax")
    pytest.importorskip("mujoco.mjx")
    code = textwrap.dedent("""
        import importlib.util
        from amorctl.plugins.backends.jax_mjx import import_mjx_quietly
        import_mjx_quietly()
        import mujoco.mjx
        from amorctl.plugins.backends.jax_mjx import physics
        print("warp installed" if importlib.util.find_spec("warp") else "warp absent")
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout in ("warp absent\n", "warp installed\n")  # nothing else


# ---------------------------------------------------------------------------- every command
def test_every_json_command_prints_only_json_on_torch_cpu(tmp_path: Path, tracking_run: Path) -> None:
    pytest.importorskip("pybullet_data")
    table = invocations(tmp_path, tracking_run, tracking_run.parent / "ds.mcap")
    assert sorted(table) == json_commands()
    docs = run_commands(list(table.values()), tmp_path, timeout=900)
    assert len(docs) == len(table)
    got = dict(zip(table, docs, strict=True))
    assert got["evaluate"]["run"] == str(tracking_run)
    assert got["characters show"]["name"] == "biped20"
    assert got["stickman calibrate"]["character"] == "stickman12"
    assert got["hlp train"]["end_iteration"] == 1


@pytest.mark.slow
def test_json_commands_print_only_json_on_a_jax_mjx_run(tmp_path: Path) -> None:
    """The issue's case: ``evaluate RUN --json`` on a jax-mjx run, in a process that imports
    mujoco.mjx for the first time (~3 min on 2 cores: XLA compiles each command's rollout)."""
    pytest.importorskip("jax")
    import dataclasses

    from amorctl.envs.synthetic import synthetic_library
    from amorctl.motion.dataset import write_dataset
    from amorctl.registry import get_registry

    lib = synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=1.0, seed=3)
    clips = tuple(
        dataclasses.replace(c, name=n) for c, n in zip(lib.clips, ("sway_a", "sway_b"), strict=True)
    )
    write_dataset(tmp_path / "ds.mcap", dataclasses.replace(lib, clips=clips))
    (tmp_path / "jax.toml").write_text(JAX_TOML.format(ds=tmp_path / "ds.mcap"))
    run = str(tmp_path / "run")
    (trained,) = run_commands([["train", "--config", str(tmp_path / "jax.toml"), "--out", run, "--json"]],
                              tmp_path, timeout=600)  # fmt: skip
    assert trained["end_iteration"] == 1
    evaluated, front, tuned = run_commands(
        [
            ["evaluate", run, "--motion", "sway_a", "--episodes", "1", "--json"],
            ["pareto", run, "--samples", "2", "--out", str(tmp_path / "p"), "--json"],
            ["tune", run, "--motion", "sway_a", "--weights", "up=1", "--seconds", "0.2", "--json"],
        ],
        tmp_path,
        timeout=900,
    )
    assert evaluated["settings"][0]["metrics"]["episodes"] == 1
    assert len(front["weights"]) == 2 and tuned["steps"] == 10
