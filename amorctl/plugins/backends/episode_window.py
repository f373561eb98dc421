"""Episode statistics of a MOPPO trainer, kept on the host in numpy by both backends.

:class:`EpisodeWindow` sums each env's running episode (per-objective return, scalarized return
``r·w``, length) and moves every finished episode into a ring of the last
:data:`EPISODE_WINDOW` episodes, whose means are the ``return/*``,
``return/scalarized``, ``episode/length`` and ``episode/survival`` metrics. Its arrays go into
checkpoints under ``episodes.<name>`` (with ``recent_ptr`` and ``episodes`` in the metadata), so
a resumed run reports what an uninterrupted one would. Shapes: N envs, m objectives, W window.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

#: Finished episodes the recent-episode statistics average over.
EPISODE_WINDOW = 100
#: Per-env episode accumulators and recent-episode windows, saved in checkpoints for exact resume.
EPISODE_STATS: tuple[str, ...] = (
    "ep_return", "ep_scalar", "ep_length",
    "recent_return", "recent_scalar", "recent_length", "recent_survived",
)  # fmt: skip


class EpisodeWindow:
    """Running episode sums of N envs and the window of the last W finished episodes.

    Args:
        num_envs: N.
        m: objectives.
        window: W, the finished episodes the metrics average over.
    """

    def __init__(self, num_envs: int, m: int, window: int = EPISODE_WINDOW) -> None:
        self.m = m
        self.recent_return = np.full((window, m), np.nan)  # [W, m]
        self.recent_scalar = np.full(window, np.nan)  # [W]
        self.recent_length = np.full(window, np.nan)  # [W]
        self.recent_survived = np.full(window, np.nan)  # [W] 1.0: ended by the time limit
        self.recent_ptr = 0
        self.episodes = 0
        self.restart(num_envs)

    def restart(self, num_envs: int) -> None:
        """Start every env's running episode from zero (a reset; a resume may change N)."""
        self.ep_return = np.zeros((num_envs, self.m))  # [N, m]
        self.ep_scalar = np.zeros(num_envs)  # [N]
        self.ep_length = np.zeros(num_envs, dtype=np.int64)  # [N]

    def record(self, rewards: Any, weights: Any, terminated: Any, truncated: Any) -> None:
        """Add one step: rewards and weights [N, m], terminated and truncated [N] bool."""
        rewards = np.asarray(rewards, np.float64)
        terminated = np.asarray(terminated, bool)
        self.ep_return += rewards
        self.ep_scalar += (rewards * np.asarray(weights, np.float64)).sum(-1)
        self.ep_length += 1
        ended = terminated | np.asarray(truncated, bool)
        k = int(ended.sum())
        if k == 0:
            return
        slots = (self.recent_ptr + np.arange(k)) % len(self.recent_length)
        self.recent_return[slots] = self.ep_return[ended]
        self.recent_scalar[slots] = self.ep_scalar[ended]
        self.recent_length[slots] = self.ep_length[ended]
        self.recent_survived[slots] = (~terminated[ended]).astype(np.float64)
        self.recent_ptr = int((self.recent_ptr + k) % len(self.recent_length))
        self.episodes += k
        self.ep_return[ended] = 0.0
        self.ep_scalar[ended] = 0.0
        self.ep_length[ended] = 0

    def sums(self) -> dict[str, np.ndarray]:
        """The window's sums by name (``count``, ``episodes``, ``return`` [m], ``scalarized``,
        ``length``, ``survived``), float64: what a data-parallel run adds up over ranks before
        :func:`window_metrics`."""
        filled = ~np.isnan(self.recent_length)
        return {
            "count": np.array([filled.sum()], np.float64),
            "episodes": np.array([self.episodes], np.float64),
            "return": self.recent_return[filled].sum(0),
            "scalarized": np.array([self.recent_scalar[filled].sum()]),
            "length": np.array([self.recent_length[filled].sum()]),
            "survived": np.array([self.recent_survived[filled].sum()]),
        }

    def metrics(self, names: Sequence[str]) -> dict[str, float]:
        """This window's metrics (:func:`window_metrics` of its own :meth:`sums`)."""
        return window_metrics(self.sums(), names)

    def state(self) -> tuple[dict[str, np.ndarray], dict[str, int]]:
        """(checkpoint arrays ``episodes.<name>``, metadata ``recent_ptr`` and ``episodes``)."""
        arrays = {f"episodes.{key}": np.asarray(getattr(self, key)).copy() for key in EPISODE_STATS}
        return arrays, {"recent_ptr": self.recent_ptr, "episodes": self.episodes}

    def load_state(self, arrays: Mapping[str, Any], meta: Mapping[str, Any]) -> None:
        """Restore :meth:`state` (KeyError for a missing array)."""
        for key in EPISODE_STATS:
            setattr(self, key, np.asarray(arrays[f"episodes.{key}"]).copy())
        self.recent_ptr, self.episodes = int(meta["recent_ptr"]), int(meta["episodes"])


def window_metrics(sums: Mapping[str, np.ndarray], names: Sequence[str]) -> dict[str, float]:
    """``return/<name>``, ``return/scalarized``, ``episode/length``, ``episode/survival`` (means
    over the windowed episodes; NaN before the first) and ``episodes`` from :meth:`EpisodeWindow.sums`
    (one rank's, or their sum over ranks)."""
    k = float(sums["count"][0])
    mean = (lambda total: float(total) / k) if k else (lambda total: float("nan"))
    out = {f"return/{name}": mean(sums["return"][i]) for i, name in enumerate(names)}
    out["return/scalarized"] = mean(sums["scalarized"][0])
    out["episode/length"] = mean(sums["length"][0])
    out["episode/survival"] = mean(sums["survived"][0])
    out["episodes"] = float(sums["episodes"][0])
    return out
