"""Single-objective GAE and the clipped PPO loss, as pure functions (the HLP's learner)."""

from __future__ import annotations

import numpy as np
import torch


def gae(
    rewards: np.ndarray,
    values: np.ndarray,
    next_values: np.ndarray,
    terminated: np.ndarray,
    ended: np.ndarray,
    gamma: float,
    lam: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Generalized advantage estimation over a rollout of T steps and N envs.

    Args:
        rewards, values: [T, N] reward of step t and V(s_t).
        next_values: [T, N] V(s_{t+1}) of the state each step ended in (for a truncated episode
            the value of its final observation, so truncation bootstraps; ignored where terminated).
        terminated: [T, N] true where s_{t+1} is terminal (no bootstrap).
        ended: [T, N] true where the episode ended at step t (terminated or truncated): the
            advantage recursion does not cross it.
    Returns:
        (advantages [T, N], returns [T, N] = advantages + values), float32.
    """
    t_len = rewards.shape[0]
    adv = np.zeros_like(rewards, dtype=np.float64)
    last = np.zeros(rewards.shape[1], dtype=np.float64)
    for t in range(t_len - 1, -1, -1):
        boot = next_values[t] * (1.0 - terminated[t])
        delta = rewards[t] + gamma * boot - values[t]
        last = delta + gamma * lam * (1.0 - ended[t]) * last
        adv[t] = last
    return adv.astype(np.float32), (adv + values).astype(np.float32)


def ppo_loss(
    new_logp: torch.Tensor,
    old_logp: torch.Tensor,
    advantages: torch.Tensor,
    values: torch.Tensor,
    returns: torch.Tensor,
    entropy: torch.Tensor,
    clip: float,
    value_coef: float,
    entropy_coef: float,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Clipped surrogate + value MSE - entropy bonus over a minibatch [B]; advantages are
    normalized here. Returns (loss, {"policy", "value", "entropy", "kl", "clip_fraction"})."""
    adv = (advantages - advantages.mean()) / (advantages.std(unbiased=False) + 1e-8)
    log_ratio = new_logp - old_logp
    ratio = log_ratio.exp()
    policy = -torch.min(ratio * adv, ratio.clamp(1 - clip, 1 + clip) * adv).mean()
    value = ((values - returns) ** 2).mean()
    ent = entropy.mean()
    loss = policy + value_coef * value - entropy_coef * ent
    with torch.no_grad():
        stats = {
            "policy": float(policy),
            "value": float(value),
            "entropy": float(ent),
            "kl": float(((ratio - 1) - log_ratio).mean()),
            "clip_fraction": float(((ratio - 1).abs() > clip).float().mean()),
        }
    return loss, stats
