"""Generalized advantage estimation per objective, as a pure function.

MOPPO computes GAE on the vector reward, one objective at a time, and only then scalarizes the
advantage with the episode's weights. Because GAE is linear in rewards and values,
``gae(r·w, V·w) == gae(r, V)·w`` for a fixed ``w`` per env and episode (tested).
"""

from __future__ import annotations

import torch


def gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    next_values: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    gamma: float,
    lam: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Advantages and value targets for every objective over a rollout.

    Shapes use T = rollout steps, N = envs, and any trailing objective shape ``...`` (m for
    MOPPO, nothing for scalar PPO).

    Args:
        rewards: [T, N, ...] reward of transition t.
        values: [T, N, ...] V(s_t), the critic's value of the state the action was taken in.
        next_values: [T, N, ...] V(s_{t+1}) of the true next state of transition t: the next
            rollout value where the episode goes on, V(final_obs) where it was truncated, and
            anything (it is ignored) where it terminated. Row T-1 holds the bootstrap values of
            the state after the rollout.
        terminated: [T, N] bool, the episode ended in a terminal state at t (no bootstrap).
        truncated: [T, N] bool, the episode hit its time limit at t (bootstrap from
            ``next_values``, but do not carry the λ-return across into the next episode).
        gamma: discount factor.
        lam: GAE λ.

    Returns:
        advantages [T, N, ...] and returns (value targets: advantages + values) [T, N, ...].
    """
    extra = (1,) * (rewards.dim() - 2)
    not_terminal = (~terminated).to(rewards.dtype).reshape(*terminated.shape, *extra)
    goes_on = (~(terminated | truncated)).to(rewards.dtype).reshape(*terminated.shape, *extra)
    deltas = rewards + gamma * not_terminal * next_values - values
    advantages = torch.zeros_like(rewards)
    running = torch.zeros_like(rewards[0])
    for t in reversed(range(rewards.shape[0])):
        running = deltas[t] + gamma * lam * goes_on[t] * running
        advantages[t] = running
    return advantages, advantages + values
