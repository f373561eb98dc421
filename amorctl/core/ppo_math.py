"""The PPO pieces every learner here shares, written once in array-API style (``xp``: numpy,
torch or jax.numpy): the diagonal Gaussian's log-probability, entropy and KL, the clipped
surrogate, the approximate KL, and rsl_rl's adaptive learning-rate rule.

MOPPO's two backends (torch-cpu, jax-mjx) and the HLP call these; what differs between them
(autodiff, the optimizer, ``lax.scan``) stays in each. Shapes: B samples, A action dimensions.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

LOG_2PI = math.log(2.0 * math.pi)
#: Bounds of the adaptive learning rate.
LR_MIN, LR_MAX = 1e-6, 1e-2


def gaussian_log_prob(actions: Any, mean: Any, log_std: Any, xp: Any = np) -> Any:
    """log N(actions; mean, exp(log_std)^2) summed over the action dimension: [B, A] -> [B]."""
    var = xp.exp(2.0 * log_std)
    return xp.sum(-((actions - mean) ** 2) / (2.0 * var) - log_std - 0.5 * LOG_2PI, axis=-1)


def gaussian_entropy(log_std: Any, xp: Any = np) -> Any:
    """Entropy of the diagonal Gaussian (independent of the mean): [A] -> scalar."""
    return xp.sum(0.5 + 0.5 * LOG_2PI + log_std)


def gaussian_kl(old_mean: Any, old_log_std: Any, mean: Any, log_std: Any, xp: Any = np) -> Any:
    """KL(old || new) of diagonal Gaussians, per sample: means [B, A], log stds [A] -> [B]."""
    old_std, new_std = xp.exp(old_log_std), xp.exp(log_std)
    return xp.sum(
        log_std - old_log_std + (old_std**2 + (old_mean - mean) ** 2) / (2 * new_std**2) - 0.5, axis=-1
    )


def clipped_surrogate(advantages: Any, ratio: Any, clip: float, xp: Any = np) -> Any:
    """PPO's clipped surrogate loss per sample (to be averaged): [B] -> [B]."""
    return xp.maximum(-advantages * ratio, -advantages * xp.clip(ratio, 1 - clip, 1 + clip))


def approx_kl(ratio: Any, log_ratio: Any) -> Any:
    """The approximate KL ``(r - 1) - log r`` per sample (Schulman's k3 estimator): [B] -> [B]."""
    return (ratio - 1) - log_ratio


def adapt_learning_rate(lr: Any, kl: Any, desired_kl: float, xp: Any = np, lr_min: float = LR_MIN) -> Any:
    """rsl_rl's rule: divide by 1.5 above ``2 desired_kl``, multiply by 1.5 below
    ``desired_kl / 2`` (and above 0), within ``[lr_min, LR_MAX]`` (``[ppo] min_learning_rate``)."""
    down = xp.maximum(lr_min, lr / 1.5)
    up = xp.minimum(LR_MAX, lr * 1.5)
    return xp.where(kl > 2.0 * desired_kl, down, xp.where((kl > 0) & (kl < 0.5 * desired_kl), up, lr))
