"""The episode statistics both backends keep on the host (plugins/backends/episode_window.py)."""

from __future__ import annotations

import math

import numpy as np
import torch

from amorctl.plugins.backends.episode_window import EpisodeWindow, window_metrics
from amorctl.plugins.backends.torch_cpu.trainer_metrics import reduce_named


def test_window_sums_episodes_and_averages_the_last_ones() -> None:
    win = EpisodeWindow(num_envs=2, m=2, window=2)
    assert math.isnan(win.metrics(("a", "b"))["return/a"]) and win.metrics(("a", "b"))["episodes"] == 0
    w = np.array([[1.0, 0.0], [0.5, 0.5]])
    no = np.zeros(2, bool)
    win.record(np.array([[1.0, 2.0], [3.0, 4.0]]), w, no, no)
    win.record(np.array([[1.0, 2.0], [3.0, 4.0]]), w, np.array([True, False]), np.array([False, True]))
    # env 0 fell after 2 steps (returns 2, 4; r·w = 2), env 1 hit the time limit (6, 8; r·w = 7)
    m = win.metrics(("a", "b"))
    assert (m["return/a"], m["return/b"], m["return/scalarized"]) == (4.0, 6.0, 4.5)
    assert (m["episode/length"], m["episode/survival"], m["episodes"]) == (2.0, 0.5, 2.0)
    win.record(np.array([[10.0, 0.0], [0.0, 0.0]]), w, np.array([True, False]), no)  # a third: W = 2
    m = win.metrics(("a", "b"))
    assert m["return/a"] == (6.0 + 10.0) / 2 and m["episode/length"] == 1.5 and m["episodes"] == 3.0
    arrays, meta = win.state()
    again = EpisodeWindow(num_envs=2, m=2, window=2)
    again.load_state(arrays, meta)
    assert again.metrics(("a", "b")) == m and again.recent_ptr == win.recent_ptr == 1


def test_named_sums_of_two_ranks_give_the_metrics_of_their_union() -> None:
    ranks = [EpisodeWindow(1, 1, window=4), EpisodeWindow(1, 1, window=4)]
    for rank, (r, length) in zip(ranks, ((1.0, 3), (5.0, 1)), strict=True):
        for t in range(length):
            rank.record(np.array([[r]]), np.ones((1, 1)), np.array([t == length - 1]), np.zeros(1, bool))
    parts = [{k: torch.from_numpy(v) for k, v in rank.sums().items()} for rank in ranks]
    both = reduce_named(lambda flat: flat + torch.cat([p.reshape(-1) for p in parts[1].values()]), parts[0])
    m = window_metrics({k: v.numpy() for k, v in both.items()}, ("x",))
    assert m["return/x"] == (3.0 + 5.0) / 2 and m["episode/length"] == 2.0 and m["episodes"] == 2.0
