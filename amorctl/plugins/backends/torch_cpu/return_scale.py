"""Per-objective return normalization of MOPPO (``[ppo] return_norm``, docs/moppo.md, Levers).

The m objectives' returns differ in scale and sign (tracking terms carry the survival bonus,
``smooth`` is a small penalty), so with one value loss summed over the m critic outputs the large
objectives dominate the critic's shared layers, and the scalarized advantage ``A·w`` is dominated
by the objectives whose advantages are large. :class:`ReturnScale` keeps running per-objective
statistics of the value targets R [B, m] and of the advantages A [B, m] (exponential moving
averages over iterations, rate :data:`RATE`; the first batch initializes them):

- ``"value"``: PopArt's target normalization without its output re-parametrization: each
  objective's value error is divided by its running return std, ``((V_k - R_k) / σ_k)²``, and the
  value clip range becomes ``ε·σ_k``. The critic keeps predicting real units, so everything that
  reads it (policies, export, the other backend) is unchanged; Adam's per-parameter step sizes
  make an explicit rescaling of the output layer (PopArt's "preserving outputs") unnecessary.
- ``"value+advantage"``: also ``Â = Σ_k w_k A_k / s_k`` with ``s_k`` the running advantage std,
  so each objective moves the policy with the same strength at the same weight. This changes the
  units ``w`` trades (standardized advantages, not raw returns); the paper does not do it.
"""

from __future__ import annotations

import torch

RATE = 0.05  # per-iteration rate of the moving averages (about 20 iterations of memory)
MIN_STD = 1e-4  # floor of every std (an objective that is constant over a batch)


class ReturnScale:
    """Running per-objective first and second moments of returns and advantages, float64.

    Args:
        m: number of objectives.
        advantage: also scale the advantages per objective (``"value+advantage"``).
    """

    def __init__(self, m: int, advantage: bool) -> None:
        self.advantage = advantage
        self.ret_mean = torch.zeros(m, dtype=torch.float64)  # [m]
        self.ret_sq = torch.ones(m, dtype=torch.float64)  # [m] mean of R²
        self.adv_sq = torch.ones(m, dtype=torch.float64)  # [m] mean of A² (GAE advantages have mean ≈ 0)
        self.updates = 0

    @torch.no_grad()
    def update(self, returns: torch.Tensor, advantages: torch.Tensor) -> None:
        """Fold one batch of value targets and advantages [B, m] into the moving averages."""
        r, a = returns.double(), advantages.double()
        self.update_moments(r.mean(0), (r * r).mean(0), (a * a).mean(0))

    @torch.no_grad()
    def update_moments(self, mean: torch.Tensor, sq: torch.Tensor, adv_sq: torch.Tensor) -> None:
        """Fold one batch given by its moments [m] (mean and mean square of R, mean square of A)."""
        rate = 1.0 if self.updates == 0 else RATE
        self.ret_mean += rate * (mean.double() - self.ret_mean)
        self.ret_sq += rate * (sq.double() - self.ret_sq)
        self.adv_sq += rate * (adv_sq.double() - self.adv_sq)
        self.updates += 1

    def return_std(self) -> torch.Tensor:
        """[m] float32 running std of the returns (floored at :data:`MIN_STD`)."""
        var = torch.clamp(self.ret_sq - self.ret_mean**2, min=0.0)
        return torch.clamp(torch.sqrt(var), min=MIN_STD).float()

    def advantage_std(self) -> torch.Tensor:
        """[m] float32 running root mean square of the advantages (floored at :data:`MIN_STD`)."""
        return torch.clamp(torch.sqrt(self.adv_sq), min=MIN_STD).float()

    def state(self) -> dict[str, torch.Tensor]:
        """The statistics by checkpoint key (without the ``return_scale.`` prefix)."""
        return {"ret_mean": self.ret_mean, "ret_sq": self.ret_sq, "adv_sq": self.adv_sq}

    def load_state(self, arrays: dict[str, torch.Tensor], updates: int) -> None:
        """Restore :meth:`state` and the update count."""
        self.ret_mean, self.ret_sq, self.adv_sq = (arrays[k].clone() for k in self.state())
        self.updates = updates
