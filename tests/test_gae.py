"""GAE per objective: hand-computed values, episode boundaries, and linearity in the weights."""

from __future__ import annotations

import pytest
import torch

from amorctl.core.gae import gae as _gae


def gae(*args):
    return _gae(*args, xp=torch)


torch.set_num_threads(1)

GAMMA, LAM = 0.9, 0.8


def _one(rewards, values, next_values, terminated=(False,) * 3, truncated=(False,) * 3):
    as_t = lambda x: torch.tensor(x, dtype=torch.float64).reshape(3, 1)  # noqa: E731
    adv, ret = gae(
        as_t(rewards),
        as_t(values),
        as_t(next_values),
        torch.tensor(terminated).reshape(3, 1),
        torch.tensor(truncated).reshape(3, 1),
        GAMMA,
        LAM,
    )
    return adv.reshape(3).tolist(), ret.reshape(3).tolist()


def test_gae_matches_hand_computed_values() -> None:
    # deltas: 1 + .9*.5 - .5 = .95, 2 + .45 - .5 = 1.95, 3 + .9*1 - .5 = 3.4; gamma*lam = .72
    adv, ret = _one([1, 2, 3], [0.5, 0.5, 0.5], [0.5, 0.5, 1.0])
    assert adv == pytest.approx([0.95 + 0.72 * (1.95 + 0.72 * 3.4), 1.95 + 0.72 * 3.4, 3.4])
    assert adv == pytest.approx([4.11656, 4.398, 3.4])
    assert ret == pytest.approx([4.61656, 4.898, 3.9])


def test_gae_terminal_step_neither_bootstraps_nor_carries() -> None:
    adv, _ = _one([1, 2, 3], [0.5, 0.5, 0.5], [0.5, 99.0, 1.0], terminated=(False, True, False))
    assert adv == pytest.approx([0.95 + 0.72 * 1.5, 1.5, 3.4])  # delta1 = 2 - .5, V(next) ignored


def test_gae_truncated_step_bootstraps_from_final_value_but_does_not_carry() -> None:
    adv, _ = _one([1, 2, 3], [0.5, 0.5, 0.5], [0.5, 2.0, 1.0], truncated=(False, True, False))
    assert adv == pytest.approx([0.95 + 0.72 * 3.3, 3.3, 3.4])  # delta1 = 2 + .9*2 - .5


def test_gae_is_per_objective_and_linear_in_the_weights() -> None:
    gen = torch.Generator().manual_seed(0)
    T, N, m = 7, 5, 3
    rewards = torch.randn(T, N, m, generator=gen, dtype=torch.float64)
    values = torch.randn(T, N, m, generator=gen, dtype=torch.float64)
    next_values = torch.randn(T, N, m, generator=gen, dtype=torch.float64)
    terminated = torch.rand(T, N, generator=gen) < 0.2
    truncated = (torch.rand(T, N, generator=gen) < 0.2) & ~terminated
    w = torch.distributions.Dirichlet(torch.ones(m)).sample((N,)).double()  # one w per env

    adv, ret = gae(rewards, values, next_values, terminated, truncated, GAMMA, LAM)
    adv_w, ret_w = gae(
        (rewards * w).sum(-1),
        (values * w).sum(-1),
        (next_values * w).sum(-1),
        terminated,
        truncated,
        GAMMA,
        LAM,
    )
    torch.testing.assert_close(adv_w, (adv * w).sum(-1))
    torch.testing.assert_close(ret_w, (ret * w).sum(-1))
    for i in range(m):  # each column is the scalar GAE of that objective
        col, _ = gae(rewards[..., i], values[..., i], next_values[..., i], terminated, truncated, GAMMA, LAM)
        torch.testing.assert_close(col, adv[..., i])
