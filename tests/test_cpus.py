"""Default thread counts follow the process's CPU affinity (``taskset``), not the machine's cores;
the CPU is named with the instruction sets that decide precision."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from amorctl.sim.cpus import available_cpus, cpu_description


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


def test_cpu_description_names_the_model_and_the_precision_flags(tmp_path: Path) -> None:
    info = tmp_path / "cpuinfo"
    info.write_text(
        "processor\t: 0\nmodel name\t: Example CPU 9000\nflags\t\t: fpu sse avx2 amx_bf16 avx512f\n"
    )
    assert cpu_description(info) == "Example CPU 9000; avx2, avx512f, amx_bf16"
    info.write_text("model name\t: Old CPU\nflags\t\t: fpu sse sse2\n")
    assert cpu_description(info) == "Old CPU; none of avx2, avx512f, avx512_bf16, amx_bf16"
    assert "none of" not in cpu_description(tmp_path / "missing")  # no /proc: the model alone
