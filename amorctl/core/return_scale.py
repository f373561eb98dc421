"""Per-objective return normalization of MOPPO (``[ppo] return_norm``, docs/moppo.md, Levers):
the running statistics both backends keep, as array-API functions (numpy, torch, jax.numpy).

The m objectives' returns differ in scale and sign (tracking terms carry the survival bonus,
``smooth`` is a small penalty), so with one value loss summed over the m critic outputs the large
objectives dominate the critic's shared layers, and the scalarized advantage ``A·w`` is dominated
by the objectives whose advantages are large. The statistics are exponential moving averages over
iterations (rate :data:`RATE`; the first batch initializes them) of each objective's mean and
mean square of the value targets R [B, m] and of the mean square of the advantages A [B, m]:

- ``"value"``: PopArt's target normalization without its output re-parametrization: each
  objective's value error is divided by its running return std, ``((V_k - R_k) / σ_k)²``, and the
  value clip range becomes ``ε·σ_k``. The critic keeps predicting real units, so everything that
  reads it (policies, export, the other backend) is unchanged; Adam's per-parameter step sizes
  make an explicit rescaling of the output layer (PopArt's "preserving outputs") unnecessary.
- ``"value+advantage"``: also ``Â = Σ_k w_k A_k / s_k`` with ``s_k`` the running advantage root
  mean square, so each objective moves the policy with the same strength at the same weight. This
  changes the units ``w`` trades (standardized advantages, not raw returns); the paper does not.
"""

from __future__ import annotations

from typing import Any, NamedTuple

RATE = 0.05  # per-iteration rate of the moving averages (about 20 iterations of memory)
MIN_STD = 1e-4  # floor of every std (an objective that is constant over a batch)
#: Checkpoint array names of the statistics (prefixed ``return_scale.``), the same in both backends.
STATE_KEYS = ("ret_mean", "ret_sq", "adv_sq")


class Moments(NamedTuple):
    """Per-objective statistics [m]: mean and mean square of R, mean square of A."""

    ret_mean: Any
    ret_sq: Any
    adv_sq: Any


def batch_moments(returns: Any, advantages: Any, xp: Any) -> Moments:
    """The moments of one batch of value targets and advantages [B, m]."""
    return Moments(
        xp.mean(returns, axis=0), xp.mean(returns * returns, axis=0), xp.mean(advantages * advantages, axis=0)
    )


def fold(running: Moments, batch: Moments, rate: Any) -> Moments:
    """``running + rate · (batch - running)`` per statistic (rate 1 replaces: the first batch)."""
    return Moments(*(r + rate * (b - r) for r, b in zip(running, batch, strict=True)))


def return_std(moments: Moments, xp: Any) -> Any:
    """[m] running std of the returns, floored at :data:`MIN_STD`."""
    var = xp.clip(moments.ret_sq - moments.ret_mean**2, 0.0, None)
    return xp.clip(xp.sqrt(var), MIN_STD, None)


def advantage_std(moments: Moments, xp: Any) -> Any:
    """[m] running root mean square of the advantages (GAE advantages have mean ≈ 0), floored."""
    return xp.clip(xp.sqrt(moments.adv_sq), MIN_STD, None)
