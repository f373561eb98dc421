"""The running observation normalizer of every torch learner here (MOPPO on torch-cpu, the HLP's
policy and discriminator), as a module whose buffers travel in checkpoints.

Statistics fold in with :func:`amorctl.core.running_moments.fold_moments` (the jax-mjx backend's
host normalizer folds with the same function). Two scale conventions, one per learner, so that
trained policies act as they did: MOPPO divides by ``sqrt(var) + eps`` (``eps`` = 0.01, as
rsl_rl: a near-constant feature, such as the weights under ``--fixed-weights``, is not blown up
to ±clip by tiny deviations); the HLP by ``sqrt(var + eps)`` (``eps`` = 1e-8).
"""

from __future__ import annotations

import torch
from torch import nn

from amorctl.core.running_moments import fold_moments


class RunningNormalizer(nn.Module):
    """Running mean/std of inputs (parallel Welford / Chan update), applied as clipped z-scores.

    Buffers: ``mean`` [D], ``var`` [D] (float64 for exact accumulation), ``count`` [] float64.
    ``forward(x [B, D]) -> clip((x - mean) / scale, -clip, clip)`` with ``scale = sqrt(var) + eps``
    (float32 out), or ``sqrt(var + eps)`` with ``eps_inside_sqrt`` (in ``x``'s dtype).

    Args:
        dim: D.
        clip: the bound of the normalized values.
        eps: the scale's epsilon.
        eps_inside_sqrt: the HLP's convention (see the module docstring).
    """

    def __init__(
        self, dim: int, clip: float = 10.0, eps: float = 1e-2, eps_inside_sqrt: bool = False
    ) -> None:
        super().__init__()
        self.clip = clip
        self.eps = eps
        self.eps_inside_sqrt = eps_inside_sqrt
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Fold a batch x [B, D] into the running statistics."""
        x = x.detach().to(torch.float64).reshape(-1, self.mean.shape[0])
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
        if self.eps_inside_sqrt:
            std = torch.sqrt(self.var + self.eps).to(x.dtype)
            y = (x - self.mean.to(x.dtype)) / std
        else:
            std = (torch.sqrt(self.var) + self.eps).to(torch.float32)
            y = (x - self.mean.to(torch.float32)) / std
        return torch.clamp(y, -self.clip, self.clip)
