"""The survival bonus as MOPPO's own channel (``[ppo] survival_channel``, docs/moppo.md, Levers).

``tracking7`` adds the same survival bonus ``c`` to every objective on every transition that does
not terminate (``RewardSpace.survival_bonus``). The bonus is the same in all m objectives, so
``w·r = w·(r - c·alive) + c·alive`` for every ``w`` on the simplex: the bonus never trades
against anything, yet it sits inside every objective's return and advantage, so it dominates
their scales (and the per-objective advantage scaling of ``return_norm = "value+advantage"``).
With the lever on, the trainer runs GAE and the value loss on m + 1 channels: the m objectives
without the bonus, and the bonus alone, scalarized with weight ``[ppo] survival_weight``. At the
default 1 the policy gradient of ``A·w`` is unchanged by the split (GAE is linear); what changes
is the critic's parameterization and, with per-objective advantage scaling, that each objective's
advantage is scaled by its own spread instead of by the spread of falls.

Channel k < m is ``V_k - S`` and channel m is ``S`` (S: the survival critic's value), so the main
critic still predicts each objective's whole value ``V_k`` (what the inference policy, coverage
and export read) and the checkpoint's ``critic.*`` arrays keep their meaning.
"""

from __future__ import annotations

import torch


def split_rewards(rewards: torch.Tensor, terminated: torch.Tensor, bonus: float) -> torch.Tensor:
    """Per-objective rewards [T, N, m] -> channels [T, N, m + 1]: the objectives without the
    bonus, then the bonus (``bonus`` on steps that did not terminate, 0 on the terminating one)."""
    alive = bonus * (~terminated).to(rewards.dtype)[..., None]  # [T, N, 1]
    return torch.cat([rewards - alive, alive], dim=-1)


def channel_values(values: torch.Tensor, survival: torch.Tensor) -> torch.Tensor:
    """Critic values V [..., m] and survival values S [..., 1] -> channels [..., m + 1]."""
    return torch.cat([values - survival, survival], dim=-1)


def objective_values(channels: torch.Tensor) -> torch.Tensor:
    """Channels [..., m + 1] -> per-objective quantities [..., m] (each objective + the bonus)."""
    return channels[..., :-1] + channels[..., -1:]


def channel_weights(weights: torch.Tensor, survival_weight: float = 1.0) -> torch.Tensor:
    """Episode weights [..., m] -> channel weights [..., m + 1]: the bonus's weight is
    ``survival_weight`` (1 = Σ w, which leaves ``A·w`` as it was without the split)."""
    return torch.cat([weights, torch.full_like(weights[..., :1], survival_weight)], dim=-1)
