"""Per-clip-family survival and the training-weight histogram (amorctl.train.episode_stats)."""

from __future__ import annotations

import csv
from types import SimpleNamespace

import numpy as np
import pytest

from amorctl.core.simplex_regions import region_counts, region_index, region_labels
from amorctl.train.episode_stats import EpisodeRecorder, clip_family
from amorctl.train.metrics import family_survival


def test_clip_family() -> None:
    assert clip_family("walker/turn_left0") == "walker"
    assert clip_family("dance_a") == "dance"
    assert clip_family("run2") == "run"
    assert clip_family("backflip") == "backflip"
    assert clip_family("getup_facedown") == "getup_facedown"


def test_region_index_and_labels() -> None:
    names = ("a", "b", "c")
    labels = region_labels(names)
    assert labels[:4] == ["a:0-0.25", "a:0.25-0.5", "a:0.5-0.75", "a:0.75-1"] and len(labels) == 12
    w = np.array([[1.0, 0, 0], [0.2, 0.5, 0.3], [0.34, 0.33, 0.33], [0.1, 0.1, 0.8], [0.0, 0.75, 0.25]])
    np.testing.assert_array_equal(region_index(w), [3, 6, 1, 11, 7])
    counts = region_counts(w, 3)
    assert counts.sum() == 5 and counts[3] == 1 and counts[11] == 1


class _FakeEnv:
    """Two clips (families ``walk`` and ``flip``), 4 envs; a scripted step ends some episodes."""

    def __init__(self) -> None:
        self.reward_space = SimpleNamespace(names=("x", "y"))
        self.num_envs = 4
        self.clips = np.array([0, 0, 1, 1])
        self.w = np.array([[0.9, 0.1], [0.6, 0.4], [0.2, 0.8], [0.5, 0.5]], dtype=np.float32)
        self.script = []  # (terminated, truncated) per step

    @property
    def weights(self) -> np.ndarray:
        return self.w.copy()

    def tracking_view(self):
        return SimpleNamespace(clip_names=("walk", "backflip"), clip_index=lambda: self.clips.copy())

    def step(self, actions):
        term, trunc = self.script.pop(0)
        # ended envs start other clips: the recorder must use the ones before the step
        self.clips = self.clips[::-1].copy()
        self.w = self.w[::-1].copy()
        return None, np.zeros((4, 2)), np.array(term), np.array(trunc), {}


def test_recorder_counts_families_and_regions() -> None:
    env = _FakeEnv()
    rec = EpisodeRecorder(env)
    assert rec.families == ("walk", "backflip") and rec.num_envs == 4  # attributes are the env's
    # step 1: env0 (walk) survives, env2 (flip) falls, env3 (flip) survives; step 2: env0, now on
    # the flip clip (the clips were reversed), falls
    env.script = [
        ([False, False, True, False], [True, False, False, True]),
        ([True, False, False, False], [False, False, False, False]),
    ]
    rec.step(np.zeros((4, 1)))
    m1 = rec.metrics()
    assert m1["survival/walk"] == 1.0 and m1["survival/backflip"] == 0.5
    # ended with w = rows 0 (x:0.75-1), 2 (y:0.75-1), 3 (x:0.5-0.75 by the first-max rule)
    assert m1["wcount/x:0.75-1"] == 1 and m1["wcount/y:0.75-1"] == 1 and m1["wcount/x:0.5-0.75"] == 1
    assert sum(v for k, v in m1.items() if k.startswith("wcount/")) == 3
    rec.step(np.zeros((4, 1)))
    m2 = rec.metrics()
    assert m2["survival/backflip"] == pytest.approx(1 / 3)  # window: fell, survived, fell
    assert sum(v for k, v in m2.items() if k.startswith("wcount/")) == 1  # counts restart per iteration
    assert m2["wcount/x:0.5-0.75"] == 1  # env0's weights were row 3 (0.5, 0.5) after the reversal
    assert family_survival(m2) == "walk 100%  backflip 33%"


def test_training_run_logs_family_and_region_columns(tracking_run) -> None:
    with (tracking_run / "metrics.csv").open(newline="") as f:
        header = next(csv.reader(f))
    assert "survival/sway" in header  # clips sway_a and sway_b: one family
    assert sum(1 for h in header if h.startswith("wcount/")) == 28  # 7 objectives x 4 bins


def test_toy_run_region_counts_add_up_to_the_episodes(toy_run) -> None:
    with (toy_run / "metrics.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    total = sum(float(v) for r in rows for k, v in r.items() if k.startswith("wcount/"))
    assert total == float(rows[-1]["episodes"]) > 0  # every ended episode counted once
    assert not any(k.startswith("survival/") for k in rows[0])  # no clips in the toy env
