"""A trained policy for inference, loaded from a checkpoint without an environment.

Evaluation, Pareto sweeps, tuning and export need only the actor, the critic and the observation
normalizer; :class:`TorchPolicy` rebuilds them from a checkpoint's arrays and metadata (no pickle).
"""

from __future__ import annotations

import numpy as np
import torch

from amorctl.core.config import NetworkConfig
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.plugins.backends.torch_cpu.networks import Actor, Critic, RunningNormalizer, load_modules


class TorchPolicy:
    """``policy(obs [N, D]) -> actions [N, A]`` (the Gaussian mean); ``values(obs) -> [N, m]``.

    Always fp32 (a bf16-trained policy's actions differ from its training-time ones by bf16
    rounding only).
    """

    def __init__(self, state: Snapshot, network: NetworkConfig) -> None:
        meta = state.meta
        try:
            obs_dim, action_dim, m = int(meta["obs_dim"]), int(meta["action_dim"]), len(meta["objectives"])
        except KeyError as exc:
            raise AmorError(f"checkpoint metadata lacks {exc}") from None
        self.objectives: tuple[str, ...] = tuple(meta["objectives"])
        self.obs_dim, self.action_dim = obs_dim, action_dim
        self.actor = Actor(obs_dim, action_dim, network.actor_hidden, network.init_std)
        self.critic = Critic(obs_dim, m, network.critic_hidden)
        self.normalizer = RunningNormalizer(obs_dim, clip=network.obs_clip)
        try:
            load_modules(
                {"actor": self.actor, "critic": self.critic, "normalizer": self.normalizer}, state.arrays
            )
        except RuntimeError as exc:
            raise AmorError(f"checkpoint does not fit the run's network configuration: {exc}") from None
        for module in (self.actor, self.critic, self.normalizer):
            module.eval()

    @torch.no_grad()
    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions [N, A] float32 for raw observations [N, D]."""
        return self.actor(self.normalizer(torch.as_tensor(obs, dtype=torch.float32))).numpy()

    @torch.no_grad()
    def values(self, obs: np.ndarray) -> np.ndarray:
        """Critic values [N, m] float32 for raw observations [N, D]."""
        return self.critic(self.normalizer(torch.as_tensor(obs, dtype=torch.float32))).numpy()
