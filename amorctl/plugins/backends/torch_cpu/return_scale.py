"""torch-cpu's running per-objective return scale (``[ppo] return_norm``): the statistics of
:mod:`amorctl.core.return_scale` (what they mean and how the loss uses them) kept in float64."""

from __future__ import annotations

import torch

from amorctl.core import return_scale as rs


class ReturnScale:
    """Running per-objective first and second moments of returns and advantages, float64.

    Args:
        m: number of objectives.
        advantage: also scale the advantages per objective (``"value+advantage"``).
    """

    def __init__(self, m: int, advantage: bool) -> None:
        self.advantage = advantage
        ones = torch.ones(m, dtype=torch.float64)
        self.moments = rs.Moments(torch.zeros(m, dtype=torch.float64), ones, ones.clone())  # [m] each
        self.updates = 0

    @torch.no_grad()
    def update(self, returns: torch.Tensor, advantages: torch.Tensor) -> None:
        """Fold one batch of value targets and advantages [B, m] into the moving averages."""
        self.update_moments(*rs.batch_moments(returns.double(), advantages.double(), xp=torch))

    @torch.no_grad()
    def update_moments(self, mean: torch.Tensor, sq: torch.Tensor, adv_sq: torch.Tensor) -> None:
        """Fold one batch given by its moments [m] (mean and mean square of R, mean square of A)."""
        rate = 1.0 if self.updates == 0 else rs.RATE
        batch = rs.Moments(mean.double(), sq.double(), adv_sq.double())
        self.moments = rs.fold(self.moments, batch, rate)
        self.updates += 1

    def return_std(self) -> torch.Tensor:
        """[m] float32 running std of the returns (floored at ``MIN_STD``)."""
        return rs.return_std(self.moments, xp=torch).float()

    def advantage_std(self) -> torch.Tensor:
        """[m] float32 running root mean square of the advantages (floored at ``MIN_STD``)."""
        return rs.advantage_std(self.moments, xp=torch).float()

    def state(self) -> dict[str, torch.Tensor]:
        """The statistics by checkpoint key (without the ``return_scale.`` prefix)."""
        return dict(zip(rs.STATE_KEYS, self.moments, strict=True))

    def load_state(self, arrays: dict[str, torch.Tensor], updates: int) -> None:
        """Restore :meth:`state` and the update count."""
        self.moments = rs.Moments(*(arrays[k].clone() for k in rs.STATE_KEYS))
        self.updates = updates
