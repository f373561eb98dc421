"""The actor pi(a | s, c, w) and the vector critic V(s, c, w) in R^m (the observation normalizer
is :class:`amorctl.core.torch_norm.RunningNormalizer`).

Observations already carry the context c and the weights w (the last m entries), so both
networks take the (normalized) observation vector as their whole input.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn


def mlp(in_dim: int, hidden: Sequence[int], out_dim: int, out_gain: float) -> nn.Sequential:
    """ELU MLP ``in_dim -> hidden... -> out_dim``, orthogonal init (gain sqrt 2), zero biases."""
    layers: list[nn.Module] = []
    last = in_dim
    for width in hidden:
        linear = nn.Linear(last, width)
        nn.init.orthogonal_(linear.weight, math.sqrt(2.0))
        nn.init.zeros_(linear.bias)
        layers += [linear, nn.ELU()]
        last = width
    head = nn.Linear(last, out_dim)
    nn.init.orthogonal_(head.weight, out_gain)
    nn.init.zeros_(head.bias)
    layers.append(head)
    return nn.Sequential(*layers)


class Actor(nn.Module):
    """Gaussian policy with a state-independent log standard deviation.

    ``forward(obs [B, D]) -> mean [B, A]``; ``log_std`` [A] is a free parameter.
    """

    def __init__(self, obs_dim: int, action_dim: int, hidden: Sequence[int], init_std: float) -> None:
        super().__init__()
        self.net = mlp(obs_dim, hidden, action_dim, out_gain=0.01)
        self.log_std = nn.Parameter(torch.full((action_dim,), math.log(init_std)))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs)


class Critic(nn.Module):
    """Vector value function: ``forward(obs [B, D]) -> V [B, m]``, one output per objective."""

    def __init__(self, obs_dim: int, num_objectives: int, hidden: Sequence[int]) -> None:
        super().__init__()
        self.net = mlp(obs_dim, hidden, num_objectives, out_gain=1.0)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs)


def modules_to_arrays(modules: dict[str, nn.Module]) -> dict[str, np.ndarray]:
    """Flatten modules' parameters and buffers into ``{"<name>.<key>": array}`` (safetensors-ready)."""
    return {
        f"{name}.{key}": tensor.detach().cpu().numpy().copy()
        for name, module in modules.items()
        for key, tensor in module.state_dict().items()
    }


def load_modules(modules: dict[str, nn.Module], arrays: dict[str, np.ndarray]) -> None:
    """Inverse of :func:`modules_to_arrays`; strict, so a mismatched shape or key raises RuntimeError."""
    for name, module in modules.items():
        prefix = name + "."
        tensors = {
            k[len(prefix) :]: torch.from_numpy(v.copy()) for k, v in arrays.items() if k.startswith(prefix)
        }
        module.load_state_dict(tensors, strict=True)
