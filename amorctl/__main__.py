"""``python -m amorctl``: the command line; ``torchrun -m amorctl train ...`` starts it on every rank."""

from __future__ import annotations

import sys

from amorctl.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
