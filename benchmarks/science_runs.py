"""The runs of benchmarks/science.py: training to a wall-clock budget, run summaries, and where and
when a measurement was taken (commit, machine, deadline)."""

from __future__ import annotations

import csv
import datetime as dt
import math
import os
import subprocess
import time
from pathlib import Path
from typing import Any

from amorctl.core.config import TrainConfig, override
from amorctl.sim.cpus import available_cpus, cpu_description
from amorctl.train.loop import train_run
from amorctl.train.metrics import total_wall_time
from amorctl.train.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]


def metrics_rows(run: Path) -> list[dict[str, str]]:
    path = run / "metrics.csv"
    return list(csv.DictReader(path.open())) if path.exists() else []


def trained_wall_s(rows: list[dict[str, str]]) -> float:
    """Training wall time summed over resumed segments (0 for no rows)."""
    return total_wall_time([float(r["wall_time_s"]) for r in rows]) if rows else 0.0


def run_summary(run: Path, weights: str) -> dict[str, Any]:
    rows = metrics_rows(run)
    last = rows[-1] if rows else {}
    return {
        "run": str(run),
        "weights": weights,
        "iterations": int(float(last.get("iteration", 0))),
        "env_steps": int(float(last.get("env_steps", 0))),
        "wall_s": trained_wall_s(rows),
        "train_survival": float(last["episode/survival"]) if last.get("episode/survival") else None,
    }


def git_commit() -> str:
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
        )
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=ROOT, capture_output=True, text=True)
    except OSError:
        return "unknown"
    return head.stdout.strip() + (" + uncommitted changes" if dirty.stdout.strip() else "")


def machine() -> str:
    import torch

    return (
        f"{cpu_description()}, {os.cpu_count()} cores, this process pinned to "
        f"{available_cpus()} (affinity {sorted(os.sched_getaffinity(0))}), torch threads "
        f"{torch.get_num_threads()}, load average at start {os.getloadavg()[0]:.2f}"
    )


class Clock:
    """Wall-clock deadline (absolute, UTC): parts that would start after it are skipped."""

    def __init__(self, deadline: str | None) -> None:
        self.at: float | None = None
        if deadline:
            hh, mm = (int(x) for x in deadline.split(":"))
            now = dt.datetime.now(dt.UTC)
            self.at = now.replace(hour=hh, minute=mm, second=0, microsecond=0).timestamp()

    def left(self) -> float:
        return math.inf if self.at is None else self.at - time.time()


def train(
    config: TrainConfig,
    out: Path,
    *,
    budget_s: float | None,
    stop_at: float,
    label: str,
    budget_steps: int | None = None,
) -> None:
    """Train (or continue) the run in ``out`` until ``config.run.iterations``, the wall-clock budget
    (summed over resumed segments), the env-step budget (the run's total) or the absolute time
    ``stop_at`` (epoch seconds)."""
    run = RunDir(out)
    resume = run.exists() and bool(run.checkpoints())
    spent = trained_wall_s(metrics_rows(out)) if resume else 0.0
    if resume:
        config = override(run.config, run__iterations=config.run.iterations)
        if run.checkpoints()[-1][0] >= config.run.iterations:
            return
    remaining = math.inf if budget_s is None else budget_s - spent
    if remaining <= 0 or time.time() >= stop_at:
        return
    if resume and budget_steps is not None:
        done = run.checkpoint().trainer.meta.get("env_steps", 0)
        if int(done) >= budget_steps:
            return
    began = time.perf_counter()
    shown = [began]

    def progress(m: dict[str, float], total: int, elapsed: float) -> None:
        if time.perf_counter() - shown[0] >= 60:
            shown[0] = time.perf_counter()
            print(
                f"  {label}: iteration {m.get('iteration', 0):.0f}, {m.get('env_steps', 0):,.0f} env steps, "
                f"{m.get('env_steps_per_s', 0):,.0f}/s, "
                f"survival {m.get('episode/survival', float('nan')):.2f}, "
                f"return·w {m.get('return/scalarized', float('nan')):.1f}, {elapsed / 60:.1f} min",
                flush=True,
            )

    result = train_run(
        config,
        out,
        resume=resume,
        on_iteration=progress,
        stop_when=lambda m: (
            time.perf_counter() - began > remaining
            or time.time() > stop_at
            or (budget_steps is not None and m.get("env_steps", 0) >= budget_steps)
        ),
    )
    print(f"  {label}: iterations {result.start_iteration} -> {result.end_iteration}", flush=True)
