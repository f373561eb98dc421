"""The actor pi(a | s, c, w), the vector critic V(s, c, w) in R^m, and the observation normalizer.

Observations already carry the context c and the weights w (the last m entries), so both
networks take the (normalized) observation vector as their whole input.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from amorctl.core.running_moments import fold_moments


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


class RunningNormalizer(nn.Module):
    """Running mean/std of observations (parallel Welford / Chan update), saved with the policy.

    Buffers: ``mean`` [D], ``var`` [D] (float64 for exact accumulation), ``count`` [] float64.
    ``forward(x [B, D]) -> clip((x - mean) / (sqrt(var) + eps), -clip, clip)`` in float32. The
    additive ``eps`` (as rsl_rl's) keeps near-constant features (a reference that barely varies,
    the weights under ``--fixed-weights``) from being blown up to ±clip by tiny deviations.
    """

    def __init__(self, dim: int, clip: float = 10.0, eps: float = 1e-2) -> None:
        super().__init__()
        self.clip = clip
        self.eps = eps
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Fold a batch x [B, D] into the running statistics."""
        x = x.to(torch.float64).reshape(-1, self.mean.shape[0])
        batch_count = x.shape[0]
        if batch_count == 0:
            return
        self.fold(x.mean(0), x.var(0, unbiased=False), batch_count)

    @torch.no_grad()
    def fold(self, batch_mean: torch.Tensor, batch_var: torch.Tensor, batch_count: float) -> None:
        """Fold a batch's float64 mean [D], population variance [D] and size into the statistics
        (data-parallel training computes them over all ranks' batches)."""
        mean, var, count = fold_moments(self.mean, self.var, self.count, batch_mean, batch_var, batch_count)
        self.mean.copy_(mean)
        self.var.copy_(var)
        self.count.copy_(count)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        std = (torch.sqrt(self.var) + self.eps).to(torch.float32)
        y = (x - self.mean.to(torch.float32)) / std
        return torch.clamp(y, -self.clip, self.clip)


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
