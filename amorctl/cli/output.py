"""Shared console output: rich tables for people, JSON for machines.

Under ``--json`` stdout is the JSON and nothing else: :func:`json_stdout` (entered by
``run_app`` for the whole command) sends everything else printed on ``sys.stdout`` meanwhile
(libraries' import chatter such as mujoco.mjx's ``Failed to import warp``, progress, notes) to
stderr, and :func:`print_json` writes to the stdout the command started with. Child processes
(``train --nproc``'s ranks) keep the real stdout and do the same in themselves.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stdout
from typing import Any, TextIO

from rich.console import Console

console = Console()
err_console = Console(stderr=True)

_json_out: TextIO | None = None  # the real stdout while json_stdout is active


@contextmanager
def json_stdout(active: bool) -> Iterator[None]:
    """While active, stdout is reserved for :func:`print_json`: anything else written on
    ``sys.stdout`` goes to stderr."""
    global _json_out
    if not active:
        yield
        return
    previous, _json_out = _json_out, sys.stdout
    try:
        with redirect_stdout(sys.stderr):
            yield
    finally:
        _json_out = previous


@contextmanager
def plugin_stdout() -> Iterator[None]:
    """The real stdout again, for a command a plugin added: it prints its own output (its JSON
    under ``--json``)."""
    if _json_out is None:
        yield
        return
    with redirect_stdout(_json_out):
        yield


def print_json(data: Any) -> None:
    """Write ``data`` as indented JSON on stdout (no rich markup, safe to pipe)."""
    out = _json_out or sys.stdout
    out.write(json.dumps(data, indent=2, default=_default) + "\n")
    out.flush()


def _default(obj: Any) -> Any:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if hasattr(obj, "__fspath__"):
        return str(obj)
    raise TypeError(f"cannot serialise {type(obj).__name__}")
