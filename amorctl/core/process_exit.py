"""Ending a process whose native threads must not meet interpreter finalization."""

from __future__ import annotations

import os
import sys
from typing import NoReturn


def end_process(code: int) -> NoReturn:
    """Flush stdout/stderr and end the process with ``code``, skipping interpreter finalization
    (module teardown, C++ static destructors). Only for a process whose outputs are all written
    and closed: a native thread still inside C code at teardown (a server stack's, gloo's) can
    otherwise abort or crash the process after its work succeeded."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
