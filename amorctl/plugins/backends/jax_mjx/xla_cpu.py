"""The XLA CPU flag the jax-mjx backend sets before JAX starts (docs/backends.md, "CPU stall").

With XLA's concurrency-optimized CPU scheduler (the default of jax 0.10), a jitted MJX step
vmapped over 128 or more envs sometimes never returns: every thread sleeps on a futex after the
first call starts. Turning that scheduler off made every size from 4 to 4096 envs run on this
project's machines. XLA reads ``XLA_FLAGS`` once, when the first computation is compiled, so this
module only edits the environment and imports nothing of JAX; a flag the user set wins.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

SCHEDULER_FLAG = "xla_cpu_enable_concurrency_optimized_scheduler"


def disable_concurrency_optimized_scheduler(environ: MutableMapping[str, str] = os.environ) -> bool:
    """Append ``--xla_cpu_enable_concurrency_optimized_scheduler=false`` to ``XLA_FLAGS`` unless
    the flag is already there; True when it was added."""
    flags = environ.get("XLA_FLAGS", "")
    if SCHEDULER_FLAG in flags:
        return False
    environ["XLA_FLAGS"] = f"{flags} --{SCHEDULER_FLAG}=false".strip()
    return True
