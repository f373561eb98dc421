"""The clipped PPO loss of the HLP's learner, as a pure function (its GAE is :func:`amorctl.core.gae.gae`)."""

from __future__ import annotations

import torch

from amorctl.core.ppo_math import approx_kl, clipped_surrogate


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
    normalized here. Returns (loss, {"policy", "value", "entropy", "approx_kl", "clip_fraction"})."""
    adv = (advantages - advantages.mean()) / (advantages.std(unbiased=False) + 1e-8)
    log_ratio = new_logp - old_logp
    ratio = log_ratio.exp()
    policy = clipped_surrogate(adv, ratio, clip, xp=torch).mean()
    value = ((values - returns) ** 2).mean()
    ent = entropy.mean()
    loss = policy + value_coef * value - entropy_coef * ent
    with torch.no_grad():
        stats = {
            "policy": float(policy),
            "value": float(value),
            "entropy": float(ent),
            "approx_kl": float(approx_kl(ratio, log_ratio).mean()),
            "clip_fraction": float(((ratio - 1).abs() > clip).float().mean()),
        }
    return loss, stats
