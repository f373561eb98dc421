"""``amorctl plugins new``: each kind's package installs with pip, is listed by
``amorctl plugins``, and its own generated test (amorctl's testing kit) passes.

pip installs into a temporary ``--target`` directory put on the subprocesses' ``PYTHONPATH``, not
into the shared environment, so other test processes never see the packages come and go.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from amorctl.cli.main import main
from amorctl.testing.scaffold import KINDS, package_names


def _sub(args: list[str], env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(args, env=env, cwd=cwd, capture_output=True, text=True, timeout=300)


def test_new_plugins_install_list_and_pass_their_own_tests(tmp_path: Path, capsys) -> None:
    names = {"character": "kitbot", "objectives": "kit-obj", "backend": "kitbe"}
    for kind in KINDS:
        assert (
            main(["plugins", "new", names[kind], "--kind", kind, "--out", str(tmp_path / kind), "--json"])
            == 0
        )
        listed = json.loads(capsys.readouterr().out)
        assert any(f.endswith("pyproject.toml") for f in listed["files"])
    target = tmp_path / "site"
    pip = _sub(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
         "--target", str(target), *(str(tmp_path / k) for k in KINDS)],
        dict(os.environ), tmp_path,
    )  # fmt: skip
    assert pip.returncode == 0, pip.stderr
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")])}
    plugins = _sub([sys.executable, "-m", "amorctl", "plugins", "--json"], env, tmp_path)
    assert plugins.returncode == 0, plugins.stderr
    rows = {(p["name"], p["kind"]): p for p in json.loads(plugins.stdout)["plugins"]}
    assert rows[("kitbot", "character")]["package"] == package_names("kitbot")[0]
    assert rows[("kit-obj", "objective-set")]["package"] == "amorctl-kit-obj"
    assert rows[("kitbe", "backend")]["version"] == "0.1.0"
    tests = [str(tmp_path / k / "tests") for k in KINDS]
    result = _sub([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *tests], env, tmp_path)
    assert result.returncode == 0, result.stdout[-3000:]
    assert "7 passed" in result.stdout


def test_new_refuses_bad_input_before_writing(tmp_path: Path, capsys) -> None:
    assert main(["plugins", "new", "biped20", "--out", str(tmp_path / "a")]) == 2
    assert "already installed" in capsys.readouterr().err and not (tmp_path / "a").exists()
    assert main(["plugins", "new", "ok-name", "--kind", "robot", "--out", str(tmp_path / "b")]) == 2
    assert "--kind 'robot'" in capsys.readouterr().err and not (tmp_path / "b").exists()
    (tmp_path / "c").mkdir()
    assert main(["plugins", "new", "ok-name", "--out", str(tmp_path / "c")]) == 2
    assert "already exists" in capsys.readouterr().err


@pytest.mark.parametrize("kind", KINDS)
def test_generated_module_is_valid_python(tmp_path: Path, kind: str) -> None:
    assert main(["plugins", "new", "gen-check", "--kind", kind, "--out", str(tmp_path / "p")]) == 0
    source = (tmp_path / "p" / "amorctl_gen_check" / "__init__.py").read_text()
    compile(source, "__init__.py", "exec")
    assert "@hookimpl" in source and "gen-check" in source
