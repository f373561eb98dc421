"""The ``amorctl`` entry point: builds the typer app and turns AmorError into one line + exit code.

Subcommands are loaded lazily (:class:`LazyGroup`): ``amorctl X ...`` imports only the module of
``X``, so ``amorctl deploy run`` and ``amorctl deploy check`` never import torch (the deploy
runtime is torch-free, docs/deploy.md) and every command starts without importing the others.
``amorctl --help`` loads them all to list their help, and the commands plugins add
(:mod:`amorctl.cli.plugin_commands`), which are looked up only for a name that is not built in.

Under ``--json`` stdout carries the JSON alone (:func:`amorctl.cli.output.json_stdout`).
"""

from __future__ import annotations

import functools
import importlib
import os
import sys
import warnings
from typing import Annotated, Any, NoReturn

import typer
import typer.main
from typer.core import TyperGroup
from typer.models import CommandInfo

from amorctl import __version__
from amorctl.cli.output import json_stdout
from amorctl.cli.plugin_commands import PluginCommands, build_plugin_commands
from amorctl.core.errors import AmorError, AmorNote, AmorWarning
from amorctl.core.files import WRITE_ERRNOS, storage_error
from amorctl.core.process_exit import end_process

#: subcommand -> (module under amorctl.cli, attribute): a ``typer.Typer`` sub-app or a command
#: function; in the order ``amorctl --help`` lists them.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "plugins": ("plugins", "app"),
    "train": ("train", "train"),
    "characters": ("characters", "app"),
    "preprocess": ("preprocess", "preprocess"),
    "data": ("data", "app"),
    "pareto": ("pareto", "pareto"),
    "evaluate": ("evaluate", "evaluate"),
    "tune": ("tune", "tune"),
    "deploy": ("deploy", "app"),
    "hlp": ("hlp", "app"),
    "runs": ("runs", "app"),
}


def load_subcommand(name: str) -> Any:
    """Import subcommand ``name``'s module and build its click command."""
    module_name, attr = SUBCOMMANDS[name]
    target = getattr(importlib.import_module(f"amorctl.cli.{module_name}"), attr)
    if isinstance(target, typer.Typer):
        command: Any = typer.main.get_group(target)  # a group even with one command
    else:
        command = typer.main.get_command_from_info(
            CommandInfo(name=name, callback=target),
            pretty_exceptions_short=True,
            rich_markup_mode=app.rich_markup_mode,
        )
    command.name = name
    return command


def plugin_commands() -> PluginCommands:
    """The commands installed plugins add (loads the plugin registry)."""
    from amorctl.registry import get_registry

    return build_plugin_commands(get_registry(), SUBCOMMANDS)


class LazyGroup(TyperGroup):
    """The root group: :data:`SUBCOMMANDS` are imported when first asked for; plugins' commands
    when a name is not built in, or for the list."""

    def list_commands(self, ctx: Any) -> list[str]:
        names = [*SUBCOMMANDS, *(n for n in super().list_commands(ctx) if n not in SUBCOMMANDS)]
        try:
            added = self._plugin_commands()
        except AmorError:  # e.g. two plugins register one name: the commands that use plugins say so
            added = {}
        return [*names, *sorted(n for n in added if n not in names)]

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        if cmd_name not in self.commands:
            if cmd_name in SUBCOMMANDS:
                self.commands[cmd_name] = load_subcommand(cmd_name)
            elif cmd_name in (added := self._plugin_commands()):
                self.commands[cmd_name] = added[cmd_name]
        return super().get_command(ctx, cmd_name)

    def _plugin_commands(self) -> dict[str, Any]:
        if not hasattr(self, "_added"):
            self._added = plugin_commands().commands
        return self._added


app = typer.Typer(
    name="amorctl",
    cls=LazyGroup,
    help="Adaptive character control through multi-objective RL (AMOR): train one policy for every "
    "trade-off between tracking objectives, then choose, tune or schedule the trade-off.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"amorctl {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """amorctl: AMOR motion-tracking policies from the command line."""


def main(argv: list[str] | None = None) -> int:
    """Run the CLI and return its exit status; user-fixable failures print ``error: <message>``."""
    return run_app(app, "amorctl", argv)


def run(argv: list[str] | None = None) -> NoReturn:
    """The ``amorctl`` console script and ``python -m amorctl``: :func:`main`, then exit with its
    status. A rank of a distributed command (``torchrun``) ends without interpreter finalization,
    its outputs written (see :func:`amorctl.train.distributed.joined_a_group`)."""
    code = main(argv)
    distributed = sys.modules.get("amorctl.train.distributed")  # not imported: no group joined
    if distributed is not None and distributed.joined_a_group():
        end_process(code)
    sys.exit(code)


def _show_warning(previous: Any, message: Any, category: type[Warning], *args: Any, **kwargs: Any) -> None:
    """Print an :class:`AmorWarning` as one ``warning:`` line on stderr (an :class:`AmorNote` as a
    ``note:`` line); others as before."""
    if issubclass(category, AmorWarning):
        print(f"{'note' if issubclass(category, AmorNote) else 'warning'}: {message}", file=sys.stderr)
    else:
        previous(message, category, *args, **kwargs)


def run_app(typer_app: typer.Typer, prog_name: str, argv: list[str] | None = None) -> int:
    """Run ``typer_app`` with amorctl's error convention and return the exit status: an
    :class:`AmorError` prints one ``error:`` line (its exit code), Ctrl-C prints ``interrupted``
    (130), anything else one line (1); ``AMORCTL_DEBUG=1`` re-raises for the traceback. An
    :class:`AmorWarning` prints one ``warning:`` line on stderr and the command goes on."""
    debug = os.environ.get("AMORCTL_DEBUG", "") not in ("", "0")
    args = sys.argv[1:] if argv is None else list(argv)
    try:
        with warnings.catch_warnings(), json_stdout("--json" in args):
            warnings.simplefilter("default", AmorWarning)  # each message once per command
            warnings.showwarning = functools.partial(_show_warning, warnings.showwarning)
            typer_app(args=args, prog_name=prog_name)  # standalone: usage errors exit 2 via SystemExit
    except SystemExit as exit_:
        code = exit_.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except AmorError as err:
        if debug:
            raise
        print(f"error: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # anything unexpected: one line unless debugging
        if debug:
            raise
        refused = storage_error(exc) if isinstance(exc, OSError) and exc.errno in WRITE_ERRNOS else None
        if refused is not None:  # a write the disk refused outside an atomic write (a log, a CSV)
            print(f"error: {refused}", file=sys.stderr)
            return refused.exit_code
        print(
            f"error: unexpected {type(exc).__name__}: {exc} (set AMORCTL_DEBUG=1 for a traceback)",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    run()
