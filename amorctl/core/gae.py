"""Generalized advantage estimation, written once for numpy and torch arrays (array-API style).

MOPPO runs it on the vector reward, one objective at a time, and only then scalarizes the
advantage with the episode's weights. Because GAE is linear in rewards and values,
``gae(r·w, V·w) == gae(r, V)·w`` for a fixed ``w`` per env and episode (tested). The HLP runs it
on its scalar reward. The jax-mjx backend keeps a ``lax.scan`` twin (its parity tests pin it to
this one).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def gae(
    rewards: Any,
    values: Any,
    next_values: Any,
    terminated: Any,
    truncated: Any,
    gamma: float,
    lam: float,
    xp: Any = np,
) -> tuple[Any, Any]:
    """Advantages and value targets over a rollout, for any trailing objective shape.

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
        xp: the array namespace (``numpy`` or ``torch``).

    Returns:
        advantages [T, N, ...] and returns (value targets: advantages + values) [T, N, ...], in
        the rewards' dtype.
    """
    shape = (*terminated.shape, *(1,) * (rewards.ndim - 2))
    not_terminal = _ones_except(terminated, rewards, shape, xp)
    goes_on = _ones_except(terminated | truncated, rewards, shape, xp)
    deltas = rewards + gamma * not_terminal * next_values - values
    advantages = xp.zeros_like(rewards)
    running = xp.zeros_like(rewards[0])
    for t in reversed(range(rewards.shape[0])):
        running = deltas[t] + gamma * lam * goes_on[t] * running
        advantages[t] = running
    return advantages, advantages + values


def _ones_except(flags: Any, like: Any, shape: tuple[int, ...], xp: Any) -> Any:
    """1 where ``flags`` is false, 0 where true, in ``like``'s dtype, reshaped to ``shape``."""
    out = xp.ones_like(flags, dtype=like.dtype)
    out[flags] = 0
    return xp.reshape(out, shape)
