"""The progress view of a training command (``train``, ``hlp train``): a rich live panel on a
terminal, else one progress line at most every 10 s (and on the first and last iteration)."""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from collections.abc import Sequence

from rich.console import RenderableType
from rich.live import Live

from amorctl.cli.output import console

#: Seconds between two plain progress lines when there is no live panel.
PRINT_EVERY_S = 10.0


def fmt(value: float, spec: str = ".3g") -> str:
    """``value`` formatted with ``spec``; an en dash for NaN or inf (a metric not measured yet)."""
    return "–" if not math.isfinite(value) else format(value, spec)


def fmt_time(seconds: float) -> str:
    """``H:MM:SS``, or ``?`` for a time that is not known."""
    if not math.isfinite(seconds):
        return "?"
    seconds = int(seconds)
    return f"{seconds // 3600:d}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


class TrainingView(ABC):
    """What the training loops' ``on_start`` / ``on_iteration`` hooks drive.

    A command's view names its objectives and prints its header through :meth:`begin` (from its
    own ``on_start``), draws the live panel in :meth:`render` and the plain line in :meth:`line`;
    the metrics ``m`` are the loop's flat ``name -> value`` dict of one iteration.
    """

    def __init__(self, live: bool) -> None:
        self.live_enabled = live
        self.names: tuple[str, ...] = ()
        self.start = 0
        self.live: Live | None = None
        self.last_print = 0.0

    def begin(self, names: Sequence[str], start: int, header: str) -> None:
        """Remember the objectives and the first iteration, print ``header``, start the panel."""
        self.names, self.start = tuple(names), start
        console.print(header, highlight=False)
        if self.live_enabled:
            self.live = Live(console=console, refresh_per_second=4, transient=False)
            self.live.start()

    def seconds_left(self, iteration: int, total: int, elapsed: float) -> float:
        """Time to ``total`` at the pace of the iterations run since :meth:`begin`."""
        return elapsed / max(iteration - self.start, 1) * (total - iteration)

    def per_objective(self, m: dict[str, float], prefix: str, spec: str = ".3g") -> str:
        """``name=value`` for each objective's metric ``<prefix>/<name>``, space-separated."""
        return " ".join(f"{n}={fmt(m[f'{prefix}/{n}'], spec)}" for n in self.names)

    @abstractmethod
    def render(self, m: dict[str, float], total: int, elapsed: float) -> RenderableType:
        """The live panel after an iteration."""

    @abstractmethod
    def line(self, m: dict[str, float]) -> str:
        """The progress line printed (after ``it <iteration>/<total>``) when there is no live panel."""

    def on_iteration(self, m: dict[str, float], total: int, elapsed: float) -> None:
        if self.live is not None:
            self.live.update(self.render(m, total, elapsed))
            return
        now = time.monotonic()
        it = int(m["iteration"])
        if now - self.last_print >= PRINT_EVERY_S or it == total or it - self.start <= 1:
            self.last_print = now
            console.print(f"it {it}/{total}  {self.line(m)}", highlight=False, soft_wrap=True)

    def stop(self) -> None:
        if self.live is not None:
            self.live.stop()
            self.live = None
