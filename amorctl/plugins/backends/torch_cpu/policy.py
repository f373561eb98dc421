"""A trained policy for inference, loaded from a checkpoint without an environment.

Evaluation, Pareto sweeps, tuning and export need only the actor, the critic and the observation
normalizer; :class:`TorchPolicy` rebuilds them from a checkpoint's arrays and metadata (no pickle).

:meth:`TorchPolicy.export_arrays` hands them out under backend-neutral names (``amorctl deploy
export`` rebuilds the deterministic actor from these alone, docs/deploy.md), all float32:

- ``normalizer/mean`` [D], ``normalizer/scale`` [D]: ``x_n = clip((x - mean) / scale, -c, c)``
  with ``c = meta["obs_clip"]`` (``scale = sqrt(var) + eps``, already added);
- ``actor/<i>/weight`` [out, in], ``actor/<i>/bias`` [out] for layer i = 0..L-1 of the actor MLP:
  ``h = act(h @ W.T + b)`` between layers (``meta["activation"]``, ``"elu"`` with alpha 1), no
  activation after the last; its output is the Gaussian mean [A]; ``actor/log_std`` [A];
- ``critic/<i>/weight``, ``critic/<i>/bias``: the critic MLP the same way (output V [m]).

Meta: ``format`` (``"amorctl-mlp-policy/1"``), ``activation``, ``obs_clip``, ``actor_layers``,
``critic_layers``, ``obs_dim``, ``action_dim``, ``objectives``, ``observation_layout``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from torch import nn

from amorctl.core.config import NetworkConfig
from amorctl.core.contracts import Snapshot
from amorctl.core.errors import AmorError
from amorctl.core.torch_norm import RunningNormalizer
from amorctl.plugins.backends.host import export_snapshot
from amorctl.plugins.backends.torch_cpu.networks import Actor, Critic, load_modules


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
        m_start = obs_dim - m
        layout = meta.get("observation_layout")
        self._layout: dict[str, tuple[int, int]] = (
            {str(k): (int(v[0]), int(v[1])) for k, v in layout.items()}
            if isinstance(layout, Mapping)
            else {"observation": (0, m_start), "weights": (m_start, obs_dim)}
        )

    @property
    def observation_layout(self) -> Mapping[str, tuple[int, int]]:
        """Named ``(start, stop)`` slices of the observation. A checkpoint records only the sizes,
        so this is ``observation`` (everything before the weights) and ``weights`` (the last m),
        unless the checkpoint's metadata carries an ``observation_layout``; the env's
        ``observation_layout`` names the finer parts of a tracking observation."""
        return dict(self._layout)

    @torch.no_grad()
    def export_arrays(self) -> Snapshot:
        """The inference parameters under backend-neutral names (module docstring), float32."""
        arrays: dict[str, np.ndarray] = {
            "normalizer/mean": self.normalizer.mean.to(torch.float32).numpy().copy(),
            "normalizer/scale": (torch.sqrt(self.normalizer.var) + self.normalizer.eps)
            .to(torch.float32)
            .numpy()
            .copy(),
            "actor/log_std": self.actor.log_std.detach().to(torch.float32).numpy().copy(),
        }
        counts = {}
        for name, net in (("actor", self.actor.net), ("critic", self.critic.net)):
            linears = [layer for layer in net if isinstance(layer, nn.Linear)]
            if any(not isinstance(layer, (nn.Linear, nn.ELU)) for layer in net):
                raise AmorError(f"{name} network has a layer other than Linear/ELU; cannot export it")
            for i, layer in enumerate(linears):
                arrays[f"{name}/{i}/weight"] = layer.weight.detach().to(torch.float32).numpy().copy()
                arrays[f"{name}/{i}/bias"] = layer.bias.detach().to(torch.float32).numpy().copy()
            counts[name] = len(linears)
        return export_snapshot(self, arrays, counts)

    @torch.no_grad()
    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions [N, A] float32 for raw observations [N, D]."""
        return self.actor(self.normalizer(torch.as_tensor(obs, dtype=torch.float32))).numpy()

    @torch.no_grad()
    def values(self, obs: np.ndarray) -> np.ndarray:
        """Critic values [N, m] float32 for raw observations [N, D]."""
        return self.critic(self.normalizer(torch.as_tensor(obs, dtype=torch.float32))).numpy()
