"""A run's metrics: ``metrics.csv`` (one row per iteration) plus optional TensorBoard scalars.

Columns (docs/train.md, "Metrics"): the trainer's (``loss/...``, ``return/<objective>``,
``episode/survival``, ...), ``wall_time_s``, and from :mod:`amorctl.train.episode_stats`
``survival/<clip family>`` and ``wcount/<simplex region>``. A resumed run keeps the columns its
file started with.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
from pathlib import Path
from typing import Any

from amorctl.core.files import atomic_write_text

METRICS_FILE = "metrics.csv"
TB_DIR = "tb"


def total_wall_time(times: list[float]) -> float:
    """Training wall time in seconds from a run's ``wall_time_s`` column, oldest row first: the
    column restarts at each resume, so the total is the sum of each segment's last value (NaN for
    no rows)."""
    if not times:
        return math.nan
    return times[-1] + sum(a for a, b in itertools.pairwise(times) if b < a)


class MetricsLog:
    """metrics.csv (one row per iteration) plus optional TensorBoard scalars."""

    def __init__(self, out: Path, tensorboard: bool, resume_from: int | None) -> None:
        self.path = out / METRICS_FILE
        self.columns: list[str] | None = None
        if resume_from is not None and self.path.is_file():  # forget iterations after the checkpoint
            rows = list(csv.DictReader(self.path.open(newline="", encoding="utf-8")))
            if rows:
                self.columns = list(rows[0])
                # a row cut short (a write the disk refused mid-line) has missing (None) fields
                whole = [r for r in rows if None not in r and None not in r.values()]
                kept = [r for r in whole if float(r["iteration"]) <= resume_from]
                buf = io.StringIO()
                writer = csv.DictWriter(buf, self.columns)
                writer.writeheader()
                writer.writerows(kept)
                atomic_write_text(self.path, buf.getvalue())
        elif self.path.exists():
            self.path.unlink()
        self.tb: Any = None
        if tensorboard:
            from tensorboardX import SummaryWriter

            purge = None if resume_from is None else resume_from + 1
            self.tb = SummaryWriter(str(out / TB_DIR), purge_step=purge)

    def write(self, metrics: dict[str, float]) -> None:
        step = int(metrics["iteration"])
        if self.columns is None:
            self.columns = list(metrics)
        new = not self.path.exists()
        with self.path.open("a", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, self.columns, extrasaction="ignore")
            if new:
                writer.writeheader()
            writer.writerow({k: repr(float(metrics.get(k, math.nan))) for k in self.columns})
        if self.tb is not None:
            for key, value in metrics.items():
                # the per-iteration weight histogram stays in the CSV (28 curves would bury the rest)
                if key != "iteration" and math.isfinite(value) and not key.startswith("wcount/"):
                    self.tb.add_scalar(key, value, step)

    def close(self) -> None:
        if self.tb is not None:
            self.tb.close()


def family_survival(metrics: dict[str, float], spec: str = ".0%") -> str:
    """``walk 98%  walker 90%  backflip 0%`` from an iteration's ``survival/<family>`` metrics
    (:mod:`amorctl.train.episode_stats`), in the order logged; ``""`` when there are none."""
    parts = [
        f"{key.split('/', 1)[1]} {'–' if not math.isfinite(v) else format(v, spec)}"
        for key, v in metrics.items()
        if key.startswith("survival/")
    ]
    return "  ".join(parts)
