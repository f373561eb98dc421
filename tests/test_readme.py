"""The README is the front door: its two commands must be the ones CI runs."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _fenced_commands(markdown: str) -> list[str]:
    return [block.strip() for block in re.findall(r"```(?:bash|sh|console)?\n(.*?)```", markdown, re.S)]


def test_readme_test_command_is_what_ci_runs() -> None:
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    blocks = _fenced_commands(readme.split("## Quick start", 1)[1].split("##", 1)[0])
    assert len(blocks) == 2, "the quick start has exactly two commands"
    test_command = blocks[1].splitlines()[-1]
    assert "pytest" in test_command
    install_and_test = test_command.split("&&", 2)[-1].strip()
    assert install_and_test in ci, f"CI must run the README's test command: {install_and_test!r}"


def test_every_subcommand_is_documented() -> None:
    from amorctl.cli.main import SUBCOMMANDS  # loaded lazily: the table names every subcommand

    docs = "\n".join(p.read_text() for p in (ROOT / "docs").glob("*.md"))
    names = list(SUBCOMMANDS)
    for name in names:
        assert f"amorctl {name}" in docs, f"`amorctl {name}` is not documented in docs/"
