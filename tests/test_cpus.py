"""Default thread counts follow the process's CPU affinity (``taskset``), not the machine's cores."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from amorctl.sim.cpus import available_cpus


def test_available_cpus_counts_the_affinity_mask(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {1}, raising=False)
    assert available_cpus() == 1
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 2, 5}, raising=False)
    assert available_cpus() == 3


def test_backend_threads_split_the_affinity_among_local_ranks(monkeypatch: pytest.MonkeyPatch) -> None:
    from amorctl.plugins.backends.torch_cpu import _threads_per_local_rank

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    monkeypatch.delenv("LOCAL_WORLD_SIZE", raising=False)
    assert _threads_per_local_rank() == 4
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "2")
    assert _threads_per_local_rank() == 2
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "8")
    assert _threads_per_local_rank() == 1  # never zero


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity API")
def test_a_process_pinned_to_one_core_defaults_to_one_thread() -> None:
    core = min(os.sched_getaffinity(0))
    code = "from amorctl.plugins.backends.torch_cpu import _threads_per_local_rank as t; print(t())"
    env = {k: v for k, v in os.environ.items() if k != "LOCAL_WORLD_SIZE"}
    out = subprocess.run(
        [sys.executable, "-c", f"import os; os.sched_setaffinity(0, {{{core}}}); {code}"],
        capture_output=True, text=True, check=True, env=env,
    )  # fmt: skip
    assert out.stdout.strip() == "1"
