"""How many CPU cores this process may use: the default thread count of the simulators."""

from __future__ import annotations

import os


def available_cpus() -> int:
    """Cores in this process's CPU affinity mask (``taskset``, cgroups cpusets), at least one.

    ``os.cpu_count()`` counts the machine's cores, which over-subscribes a process pinned to fewer
    (``taskset -c 1 amorctl train`` must run one simulation thread, not two on one core).
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity API (macOS, Windows)
        return max(1, os.cpu_count() or 1)
