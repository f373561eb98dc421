"""Running mean and variance of a stream of batches (Chan et al.'s parallel update), written once
for numpy and torch (array-API style): the observation normalizers of both MOPPO backends and of
the HLP fold their batches with it, in float64."""

from __future__ import annotations

from typing import Any


def fold_moments(
    mean: Any, var: Any, count: Any, batch_mean: Any, batch_var: Any, batch_count: float
) -> tuple[Any, Any, Any]:
    """The statistics [D], [D], [] after folding in a batch of ``batch_count`` samples with mean
    [D] and population variance [D]: returns (mean, var, count) of the union."""
    total = count + batch_count
    delta = batch_mean - mean
    new_mean = mean + delta * batch_count / total
    m2 = var * count + batch_var * batch_count + delta**2 * count * batch_count / total
    return new_mean, m2 / total, total
