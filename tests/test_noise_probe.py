"""``benchmarks/noise_probe.py``: a policy evaluated with Gaussian noise on its actions, beside
the deterministic one (docs/repertoire.md, "Kickstarting")."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import noise_probe

from amorctl.train.rundir import RunDir


class _Mean:
    """A policy whose mean action is 0.3 in every dimension."""

    action_dim = 4

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.full((obs.shape[0], self.action_dim), 0.3, dtype=np.float32)


def test_noisy_actions_have_the_policys_mean_and_the_given_std() -> None:
    std = np.array([0.0, 0.05, 0.1, 0.5], dtype=np.float32)
    actions = noise_probe.NoisyPolicy(_Mean(), std, seed=0)(np.zeros((20_000, 3), dtype=np.float32))
    assert np.abs(actions.mean(axis=0) - 0.3).max() < 0.01
    assert np.abs(actions.std(axis=0) - std).max() < 0.01
    assert noise_probe.NoisyPolicy(_Mean(), std, seed=0).action_dim == 4  # the rest is the policy's


def test_probe_reports_each_level_on_the_same_starts(tracking_run: Path, capsys) -> None:
    run = RunDir.open(tracking_run)
    table = noise_probe.probe(run, ["0", "own", "0"], ["sway_a"], episodes=2, seed=1)
    own = float(noise_probe.own_std(run.policy()).mean())
    assert list(table) == ["deterministic", f"std {own:.3g} (own)"]  # a repeated level is one column
    assert table["deterministic"]["sway_a"] != table[f"std {own:.3g} (own)"]["sway_a"]  # the noise acts
    noise_probe.main(["--run", str(tracking_run), "--clips", "sway_b", "--episodes", "2", "--std", "2"])
    out = capsys.readouterr().out
    assert "| clip | std 2 |" in out and "| sway_b | " in out
