"""What adaptive weight sampling learns from training (``[weights] adaptive_fraction``).

Per env it records the critic's scalarized prediction ``V(s_0)·w`` at an episode's first step and
accumulates the discounted scalarized return ``Σ_t γ^t r_t·w``; when the episode ends (truncated
ones add ``γ^L V(final_obs)·w``) it hands (w, predicted, achieved) to the env's
:class:`~amorctl.core.weight_sampling.WeightSampler`, whose anchors then favour the simplex
regions where the achieved return lags the prediction. Shapes: N envs, m objectives.
"""

from __future__ import annotations

from typing import Any

import torch

#: The per-env arrays, saved in checkpoints under ``feedback.<name>`` for exact resume.
ARRAYS = ("start_value", "disc_return", "discount", "fresh")


class WeightFeedback:
    """Per-env episode bookkeeping that feeds ``sampler.observe``.

    Args:
        sampler: the env's weight sampler (has ``observe(weights, predicted, achieved)``).
        num_envs: N.
        gamma: the discount of the achieved return (the trainer's).
    """

    def __init__(self, sampler: Any, num_envs: int, gamma: float) -> None:
        self.sampler = sampler
        self.gamma = gamma
        self.reset(num_envs)

    def reset(self, num_envs: int) -> None:
        """Every env starts a fresh episode (after an env reset)."""
        self.start_value = torch.zeros(num_envs, dtype=torch.float64)  # [N] V(s_0)·w
        self.disc_return = torch.zeros(num_envs, dtype=torch.float64)  # [N] Σ γ^t r_t·w so far
        self.discount = torch.ones(num_envs, dtype=torch.float64)  # [N] γ^t of the next reward
        self.fresh = torch.ones(num_envs, dtype=torch.bool)  # [N] the next step is an episode's first

    @torch.no_grad()
    def step(
        self,
        weights: torch.Tensor,
        values: torch.Tensor,
        rewards: torch.Tensor,
        terminated: torch.Tensor,
        truncated: torch.Tensor,
        final_values: torch.Tensor,
    ) -> None:
        """One rollout step of all envs.

        Args:
            weights, values, rewards: [N, m] the step's episode weights, ``V(s_t)`` and rewards.
            terminated, truncated: [N] bool, how the step ended episodes (truncated excludes
                terminated).
            final_values: [N, m] ``V(final_obs)`` where truncated (ignored elsewhere).
        """
        w = weights.double()
        predicted = (values.double() * w).sum(-1)
        self.start_value = torch.where(self.fresh, predicted, self.start_value)
        self.fresh[:] = False
        self.disc_return += self.discount * (rewards.double() * w).sum(-1)
        self.discount *= self.gamma
        ended = terminated | truncated
        if not bool(ended.any()):
            return
        bootstrap = torch.where(truncated, self.discount * (final_values.double() * w).sum(-1), 0.0)
        achieved = self.disc_return + bootstrap
        self.sampler.observe(w[ended].numpy(), self.start_value[ended].numpy(), achieved[ended].numpy())
        self.disc_return[ended] = 0.0
        self.discount[ended] = 1.0
        self.fresh[ended] = True
