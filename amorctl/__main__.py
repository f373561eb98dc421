"""``python -m amorctl``: the command line; ``torchrun -m amorctl train ...`` starts it on every rank."""

from __future__ import annotations

from amorctl.cli.main import run

if __name__ == "__main__":
    run()
