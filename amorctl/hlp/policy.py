"""pi_H(w_t | s_t, c_t): a Gaussian over m logits pushed through a softmax, so w_t lies on the simplex.

The actor is a 3-layer ELU MLP giving the logits' mean mu [N, m]; a state-independent log-std
[m] sets the spread. PPO treats the logits u ~ N(mu, sigma) as the action (log-probabilities and
entropy are the Gaussian's); the env receives ``w = softmax(u)``. The critic is a second ELU MLP
with one output. Inputs are normalized by a running mean/std (:func:`hlp_normalizer`).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import torch
from torch import nn

from amorctl.core.ppo_math import gaussian_log_prob
from amorctl.core.torch_norm import RunningNormalizer


def mlp(sizes: list[int], out: int) -> nn.Sequential:
    """ELU MLP ``sizes[0] -> sizes[1] ... -> out`` (no activation on the output)."""
    layers: list[nn.Module] = []
    for a, b in itertools.pairwise(sizes):
        layers += [nn.Linear(a, b), nn.ELU()]
    layers.append(nn.Linear(sizes[-1], out))
    return nn.Sequential(*layers)


def hlp_normalizer(dim: int, clip: float = 10.0) -> RunningNormalizer:
    """The HLP's running mean/std (policy inputs, discriminator windows): the shared normalizer
    with the HLP's scale ``sqrt(var + 1e-8)`` (:mod:`amorctl.core.torch_norm`)."""
    return RunningNormalizer(dim, clip=clip, eps=1e-8, eps_inside_sqrt=True)


def softmax_weights(logits: torch.Tensor) -> torch.Tensor:
    """w = softmax(u) [N, m], computed in float64 and renormalized so every row sums to 1 exactly
    to float32 precision and is >= 0, for any finite logits (the max is subtracted first)."""
    w = torch.softmax(logits.to(torch.float64), dim=-1)
    return (w / w.sum(-1, keepdim=True)).to(torch.float32)


class HlpActorCritic(nn.Module):
    """Actor (logit mean + log-std) and critic of the HLP.

    Args:
        obs_dim: the HLP observation size (the LLP observation without its last m entries).
        m: objectives.
        actor_hidden / critic_hidden: ELU MLP widths.
        init_std: initial standard deviation of the logits.
        obs_clip: normalizer clip.
    """

    def __init__(
        self,
        obs_dim: int,
        m: int,
        actor_hidden: tuple[int, ...],
        critic_hidden: tuple[int, ...],
        init_std: float,
        obs_clip: float,
    ) -> None:
        super().__init__()
        self.obs_dim, self.m = obs_dim, m
        self.normalizer = hlp_normalizer(obs_dim, obs_clip)
        self.actor = mlp([obs_dim, *actor_hidden], m)
        self.critic = mlp([obs_dim, *critic_hidden], 1)
        self.log_std = nn.Parameter(torch.full((m,), math.log(init_std)))
        with torch.no_grad():  # start near uniform w: small last layer (as rsl_rl / PPO practice)
            self.actor[-1].weight.mul_(0.01)
            self.actor[-1].bias.zero_()

    def mean(self, obs_n: torch.Tensor) -> torch.Tensor:
        """The mean logits [N, m] of the Gaussian over logits (std ``exp(log_std)``) for
        normalized observations [N, obs_dim]."""
        return self.actor(obs_n)

    def value(self, obs_n: torch.Tensor) -> torch.Tensor:
        """V(s, c) [N] for normalized observations."""
        return self.critic(obs_n).squeeze(-1)

    @torch.no_grad()
    def act(
        self, obs: np.ndarray, generator: torch.Generator | None, deterministic: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """For raw observations [N, obs_dim]: (w [N, m], logits u [N, m], log-prob [N], value [N]).

        ``deterministic`` uses the mean logits (evaluation, tracing, tuning)."""
        x = self.normalizer(torch.as_tensor(obs, dtype=torch.float32))
        mu = self.mean(x)
        noise = torch.randn(mu.shape, generator=generator)
        u = mu if deterministic else mu + self.log_std.exp() * noise
        return (
            softmax_weights(u).numpy(),
            u.numpy(),
            gaussian_log_prob(u, mu, self.log_std, xp=torch).numpy(),
            self.value(x).numpy(),
        )
