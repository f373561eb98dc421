"""What a caller hooks into a training run (MOPPO's or the HLP's): progress reports and early stops.

One small object instead of five keyword arguments threaded through every layer of a runner.
Every field is optional; :meth:`Callbacks.quiet` keeps the stopping rules and drops the output
(ranks other than 0 under torchrun).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

Metrics = dict[str, float]


@dataclass(frozen=True)
class Callbacks:
    """Progress callbacks and early-stop rules of one training call.

    Attributes:
        on_start: (env, start iteration, total iterations), before the first iteration.
        on_iteration: (metrics, total iterations, seconds elapsed), after every iteration.
        on_note: a one-line notice (e.g. a resume with another number of processes).
        stop_after: stop (with a checkpoint, as on SIGINT) after this many iterations of this call.
        stop_when: stop the same way once it returns True for an iteration's metrics.
    """

    on_start: Callable[[Any, int, int], None] | None = None
    on_iteration: Callable[[Metrics, int, float], None] | None = None
    on_note: Callable[[str], None] | None = None
    stop_after: int | None = None
    stop_when: Callable[[Metrics], bool] | None = None

    def quiet(self) -> Callbacks:
        """The same stopping rules without output."""
        return replace(self, on_start=None, on_iteration=None, on_note=None)

    def start(self, env: Any, start: int, total: int) -> None:
        if self.on_start is not None:
            self.on_start(env, start, total)

    def iteration(self, metrics: Metrics, total: int, elapsed: float) -> None:
        if self.on_iteration is not None:
            self.on_iteration(metrics, total, elapsed)

    def note(self, text: str) -> None:
        if self.on_note is not None:
            self.on_note(text)

    def wants_stop(self, metrics: Metrics, done_here: int) -> bool:
        """Whether ``stop_after`` (``done_here`` iterations in this call) or ``stop_when`` says stop."""
        return (self.stop_after is not None and done_here >= self.stop_after) or (
            self.stop_when is not None and bool(self.stop_when(metrics))
        )
