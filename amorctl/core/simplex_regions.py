"""Regions of the weight simplex: which objective dominates ``w`` and by how much.

Training logs how many episodes each region got (``wcount/<region>`` in metrics.csv) and
``amorctl pareto --coverage`` groups its sampled weights the same way (docs/pareto.md), so the two
can be read side by side. The region of ``w`` is its largest entry's objective k (ties: the first)
and the bin of ``w_k`` among :data:`BIN_EDGES`: ``[0, .25)`` (near the centre, no objective
dominates much), ``[.25, .5)``, ``[.5, .75)``, ``[.75, 1]`` (near the corner ``e_k``). With m
objectives there are ``4 m`` regions; bins entirely below ``1/m`` stay empty (for m = 2 the first
two). Labels read ``<objective>:<lo>-<hi>``, e.g. ``smooth:0.75-1``.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

#: Inner edges of the bins of the dominant weight.
BIN_EDGES: tuple[float, ...] = (0.25, 0.5, 0.75)
NUM_BINS = len(BIN_EDGES) + 1


def bin_labels() -> list[str]:
    """``["0-0.25", "0.25-0.5", "0.5-0.75", "0.75-1"]``."""
    edges = (0.0, *BIN_EDGES, 1.0)
    return [f"{lo:g}-{hi:g}" for lo, hi in itertools.pairwise(edges)]


def region_labels(names: Sequence[str]) -> list[str]:
    """The ``4 m`` region labels, objective-major: ``up:0-0.25, up:0.25-0.5, ..., smooth:0.75-1``."""
    return [f"{n}:{b}" for n in names for b in bin_labels()]


def region_index(weights: np.ndarray) -> np.ndarray:
    """Region of each weight vector, indexing :func:`region_labels`.

    Args:
        weights: [N, m] rows on the simplex.

    Returns:
        [N] int64 in ``[0, 4 m)``: ``k * 4 + bin(w_k)`` with ``k = argmax(w)``.
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] < 1:
        raise ValueError(f"weights must be [N, m], got shape {w.shape}")
    k = np.argmax(w, axis=1)
    top = w[np.arange(len(w)), k]
    return (k * NUM_BINS + np.digitize(top, BIN_EDGES)).astype(np.int64)


def region_counts(weights: np.ndarray, m: int) -> np.ndarray:
    """[4 m] int64: how many of the weight vectors ``[N, m]`` fall in each region."""
    if len(weights) == 0:
        return np.zeros(m * NUM_BINS, dtype=np.int64)
    return np.bincount(region_index(weights), minlength=m * NUM_BINS).astype(np.int64)
