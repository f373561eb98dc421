"""The rollout batch MOPPO collects and updates on."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class Batch:
    """One rollout, flattened to B = T·N samples (``rewards``/``values`` keep [T, N, m] views)."""

    obs: torch.Tensor  # [B, D] raw observations (normalized inside the networks' call)
    actions: torch.Tensor  # [B, A]
    log_probs: torch.Tensor  # [B] log pi_old(a | s)
    means: torch.Tensor  # [B, A] pi_old's action means (for the analytic KL)
    values: torch.Tensor  # [B, C] V_old(s) per critic channel (C = m, or m + 1: survival_channel)
    weights: torch.Tensor  # [B, m] each sample's episode weights
    rewards: torch.Tensor  # [T, N, m]
    next_values: torch.Tensor  # [T, N, C] V(s_{t+1}): next rollout value, or V(final_obs) if truncated
    terminated: torch.Tensor  # [T, N] bool
    truncated: torch.Tensor  # [T, N] bool
    old_log_std: torch.Tensor  # [A]
    advantages: torch.Tensor | None = None  # [B, C] per-channel GAE (set by compute_returns)
    returns: torch.Tensor | None = None  # [B, C] value targets (set by compute_returns)
