"""The running return statistics both backends share (amorctl/core/return_scale.py): a case by
hand, and the invariance the advantage scaling exists for."""

from __future__ import annotations

import numpy as np
import pytest

from amorctl.core import return_scale as rs


def test_fold_and_stds_by_hand() -> None:
    returns = np.array([[1.0, 10.0], [3.0, 10.0]])  # objective 1 is constant over the batch
    advantages = np.array([[2.0, 0.0], [-2.0, 0.0]])
    first = rs.batch_moments(returns, advantages, xp=np)
    np.testing.assert_allclose(first.ret_mean, [2.0, 10.0])
    np.testing.assert_allclose(first.ret_sq, [5.0, 100.0])
    np.testing.assert_allclose(first.adv_sq, [4.0, 0.0])
    np.testing.assert_allclose(rs.return_std(first, xp=np), [1.0, rs.MIN_STD])  # floored, not 0
    np.testing.assert_allclose(rs.advantage_std(first, xp=np), [2.0, rs.MIN_STD])
    # a second batch moves each statistic by RATE toward its own
    second = rs.Moments(np.array([4.0, 10.0]), np.array([17.0, 100.0]), np.array([16.0, 0.0]))
    folded = rs.fold(first, second, rs.RATE)
    np.testing.assert_allclose(folded.ret_mean, [2.0 + rs.RATE * 2.0, 10.0])
    np.testing.assert_allclose(folded.adv_sq, [4.0 + rs.RATE * 12.0, 0.0])
    for got, want in zip(rs.fold(first, second, 1.0), second, strict=True):  # rate 1 replaces
        np.testing.assert_allclose(got, want)


@pytest.mark.parametrize("scale", [1e-3, 7.0, 400.0])
def test_scaled_advantages_do_not_depend_on_an_objectives_units(scale: float) -> None:
    """Rewards of objective 0 in other units (× scale): A_0 / s_0, what enters A·w, is unchanged."""
    rng = np.random.default_rng(0)
    returns, advantages = rng.normal(size=(512, 3)), rng.normal(size=(512, 3)) * [1.0, 0.1, 30.0]
    units = np.array([scale, 1.0, 1.0])
    base = rs.batch_moments(returns, advantages, xp=np)
    other = rs.batch_moments(returns * units, advantages * units, xp=np)
    np.testing.assert_allclose(
        advantages * units / rs.advantage_std(other, xp=np),
        advantages / rs.advantage_std(base, xp=np),
        rtol=1e-9,
    )
    np.testing.assert_allclose(rs.return_std(other, xp=np), rs.return_std(base, xp=np) * units, rtol=1e-9)
