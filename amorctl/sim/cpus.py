"""How many CPU cores this process may use (the default thread count of the simulators), and
which CPU they are (what throughput figures are quoted with)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

#: The instruction sets that decide network precision and speed on x86 (bf16 needs the last two).
CPU_FLAGS = ("avx2", "avx512f", "avx512_bf16", "amx_bf16")


def cpu_description(info: Path = Path("/proc/cpuinfo")) -> str:
    """``"<model>; <which of CPU_FLAGS it has>"`` from Linux ``/proc/cpuinfo`` (the model alone,
    from :func:`platform.processor`, where there is no such file)."""
    model, flags = platform.processor() or "unknown CPU", set()
    try:
        text = info.read_text() if info.is_file() else ""
    except OSError:
        text = ""
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "model name":
            model = value.strip()
        elif key.strip() == "flags":
            flags = set(value.split())
    if not text:
        return model
    have = [f for f in CPU_FLAGS if f in flags]
    return f"{model}; {', '.join(have) or 'none of ' + ', '.join(CPU_FLAGS)}"


def available_cpus() -> int:
    """Cores in this process's CPU affinity mask (``taskset``, cgroups cpusets), at least one.

    ``os.cpu_count()`` counts the machine's cores, which over-subscribes a process pinned to fewer
    (``taskset -c 1 amorctl train`` must run one simulation thread, not two on one core).
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity API (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def idle_cpus(sample_s: float = 0.3) -> int:
    """Cores of this process's affinity that are idle now, at least one.

    Samples ``/proc/stat`` twice ``sample_s`` apart and sums the idle fraction of each core in the
    affinity mask (a core half taken by another process counts half; rounded). Falls back to
    :func:`available_cpus` where ``/proc/stat`` is missing (not Linux).
    """
    import time

    try:
        cores = sorted(os.sched_getaffinity(0))
        before = _cpu_times()
        time.sleep(sample_s)
        after = _cpu_times()
    except (AttributeError, OSError):
        return available_cpus()
    idle = 0.0
    for core in cores:
        if core in before and core in after:
            total = sum(after[core]) - sum(before[core])
            idle += (after[core][3] + after[core][4] - before[core][3] - before[core][4]) / max(total, 1)
    return max(1, min(len(cores), round(idle)))


def _cpu_times() -> dict[int, list[int]]:
    """Per-core jiffies from ``/proc/stat``: user, nice, system, idle, iowait, ..."""
    times = {}
    with open("/proc/stat") as f:
        for line in f:
            name, *fields = line.split()
            if name.startswith("cpu") and name != "cpu":
                times[int(name[3:])] = [int(x) for x in fields[:8]]
    return times
