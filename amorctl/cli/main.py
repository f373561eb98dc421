"""The ``amorctl`` entry point: builds the typer app and turns AmorError into one line + exit code."""

from __future__ import annotations

import os
import sys
from typing import Annotated

import typer

from amorctl import __version__
from amorctl.cli import characters, data, deploy, evaluate, hlp, pareto, plugins, preprocess, train, tune
from amorctl.core.errors import AmorError

app = typer.Typer(
    name="amorctl",
    help="Adaptive character control through multi-objective RL (AMOR): train one policy for every "
    "trade-off between tracking objectives, then choose, tune or schedule the trade-off.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
app.add_typer(plugins.app, name="plugins")
app.command("train")(train.train)
app.add_typer(characters.app, name="characters")
app.command("preprocess")(preprocess.preprocess)
app.add_typer(data.app, name="data")
app.command("pareto")(pareto.pareto)
app.command("evaluate")(evaluate.evaluate)
app.command("tune")(tune.tune)
app.add_typer(deploy.app, name="deploy")
app.add_typer(hlp.app, name="hlp")


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
    """Run the CLI; user-fixable failures print ``error: <message>`` and exit non-zero."""
    debug = os.environ.get("AMORCTL_DEBUG", "") not in ("", "0")
    try:
        app(args=argv, prog_name="amorctl")  # standalone mode: usage errors exit 2 via SystemExit
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
        print(
            f"error: unexpected {type(exc).__name__}: {exc} (set AMORCTL_DEBUG=1 for a traceback)",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
