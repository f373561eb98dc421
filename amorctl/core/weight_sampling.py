"""Where on the simplex training episodes draw their weights ``w`` (docs/moppo.md, "Levers").

The paper draws ``w ~ Dirichlet(1)`` per episode. With m = 7 that almost never visits the
corners and edges a sweep or a user's slider reaches (``P(w_k > 0.5) = 0.5^6``).
:class:`WeightSampler` mixes, per episode, five kinds of draw:

- ``corner``: a simplex corner ``e_k`` (one objective only), k uniform;
- ``edge``: an edge midpoint ``(e_j + e_k) / 2``, the pair uniform;
- ``axis``: a point of the sweep line of objective k, ``w_k = u ~ U(0, 1)``, the other m - 1
  entries ``(1 - u) / (m - 1)`` ("one objective heavy": what ``evaluate --sweep`` visits);
- ``adaptive``: near an anchor weight (:meth:`anchors`), the anchor chosen with probability
  increasing in how far the achieved scalarized return of its episodes lags the critic's
  prediction (:meth:`observe`, :meth:`anchor_probabilities`), in the spirit of Alegre et al.
  (2023): train where the policy underdelivers;
- ``dirichlet``: the rest, ``Dirichlet(alpha)``.

With every fraction 0 the draw is exactly ``Dirichlet(alpha)`` from the same generator calls as
:func:`amorctl.core.weights.sample_dirichlet`, so runs without levers are unchanged. The sampler's
state (the anchors' lag estimates) is JSON (:meth:`state` / :meth:`load_state`), saved with the
env's snapshot, so runs resume bit-exactly.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from amorctl.core.env_random import EnvRandom, PerEnvRandom
from amorctl.core.errors import AmorError
from amorctl.core.weights import sample_dirichlet

#: Axis levels of the adaptive anchors besides the centre (the sweep levels above 0).
ANCHOR_LEVELS = (0.25, 0.5, 0.75, 1.0)
#: Adaptive draws are ``(1 - JITTER) * anchor + JITTER * Dirichlet(1)``: near, not on, the anchor.
JITTER = 0.1
#: Per-episode rate of the exponential moving averages of the lags and of the return scale.
LAG_RATE = 0.02


class WeightSampler:
    """Per-episode weight draws for m objectives (see the module docstring).

    Args:
        m: number of objectives.
        alpha: Dirichlet concentration of the ``dirichlet`` draws (1 = uniform, the paper).
        corner_fraction, edge_fraction, axis_fraction, adaptive_fraction: the share of episodes
            of each kind; their sum must be at most 1, the rest are ``dirichlet``.
    """

    def __init__(
        self,
        m: int,
        alpha: float = 1.0,
        corner_fraction: float = 0.0,
        edge_fraction: float = 0.0,
        axis_fraction: float = 0.0,
        adaptive_fraction: float = 0.0,
    ) -> None:
        fractions = np.array([corner_fraction, edge_fraction, axis_fraction, adaptive_fraction])
        if m < 1 or not alpha > 0 or (fractions < 0).any() or fractions.sum() > 1 + 1e-9:
            raise AmorError(
                f"weight sampler: need m >= 1, alpha > 0 and fractions >= 0 summing to at most 1, "
                f"got m={m}, alpha={alpha}, fractions={fractions.tolist()}"
            )
        self.m = m
        self.alpha = float(alpha)
        self.fractions = fractions  # [4] corner, edge, axis, adaptive
        self.anchors = anchor_weights(m)  # [K, m]
        k = len(self.anchors)
        self.lag = np.zeros(k)  # [K] EMA of (predicted - achieved) / scale of the anchor's episodes
        self.count = np.zeros(k, dtype=np.int64)  # [K] episodes observed per anchor
        self.scale = 0.0  # EMA of |achieved scalarized return| over all episodes (0 = none yet)

    @property
    def plain(self) -> bool:
        """True when every draw is Dirichlet(alpha) (no mixing, no adaptation)."""
        return not self.fractions.any()

    @property
    def adaptive(self) -> bool:
        """True when some draws follow the anchors' lags (the trainer then calls :meth:`observe`)."""
        return bool(self.fractions[3] > 0)

    def draw(self, rand: EnvRandom, ids: np.ndarray) -> np.ndarray:
        """Weights [k, m] float32 for the envs ``ids`` [k] from an env's draws
        (:mod:`amorctl.core.env_random`): the batch generator, or each env's own."""
        if self.plain and self.alpha == 1.0:  # the paper's draw, exactly as before the levers
            return rand.dirichlet(ids, self.m)
        if isinstance(rand, PerEnvRandom):
            rows = [self.sample(rand.gens[i], 1) for i in np.asarray(ids, dtype=np.int64)]
            return np.concatenate(rows) if rows else np.zeros((0, self.m), np.float32)
        return self.sample(rand.rng, len(ids))  # type: ignore[attr-defined]

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Draw n weight vectors. Returns [n, m] float32 rows on the simplex."""
        m = self.m
        if self.plain or m == 1:
            return sample_dirichlet(rng, n, m, self.alpha)
        kind = np.searchsorted(np.cumsum(self.fractions), rng.random(n), side="right")  # [n] 0..4
        w = np.zeros((n, m))
        rows = np.arange(n)
        pick = rng.integers(m, size=n)  # the heavy objective (corner, axis) or an edge's first end
        other = (pick + 1 + rng.integers(m - 1, size=n)) % m  # an edge's second end, != pick
        level = rng.random(n)
        corner, edge, axis = kind == 0, kind == 1, kind == 2
        w[rows[corner], pick[corner]] = 1.0
        w[rows[edge], pick[edge]] = 0.5
        w[rows[edge], other[edge]] = 0.5
        w[axis] = ((1.0 - level[axis]) / (m - 1))[:, None]
        w[rows[axis], pick[axis]] = level[axis]
        adaptive = kind == 3
        anchor = rng.choice(len(self.anchors), size=n, p=self.anchor_probabilities())
        noise = sample_dirichlet(rng, n, m, dtype=np.float64)
        w[adaptive] = (1 - JITTER) * self.anchors[anchor[adaptive]] + JITTER * noise[adaptive]
        rest = kind == 4
        w[rest] = sample_dirichlet(rng, n, m, self.alpha, dtype=np.float64)[rest]
        return (w / w.sum(axis=1, keepdims=True)).astype(np.float32)

    def anchor_probabilities(self) -> np.ndarray:
        """[K] the adaptive draws' anchor probabilities: ``softmax(z)`` of the lags standardized
        over the anchors (uniform while they are all equal); anchors never observed count as the
        most lagging one (optimism: unvisited regions are tried)."""
        lag = self.lag.copy()
        seen = self.count > 0
        if seen.any():
            lag[~seen] = lag[seen].max()
        std = lag.std()
        z = (lag - lag.mean()) / std if std > 1e-12 else np.zeros_like(lag)
        p = np.exp(z - z.max())
        return p / p.sum()

    def observe(self, weights: np.ndarray, predicted: np.ndarray, achieved: np.ndarray) -> None:
        """Fold finished episodes into the anchors' lags.

        Args:
            weights: [E, m] the episodes' weights (each is assigned to its nearest anchor, L1).
            predicted: [E] the critic's scalarized value ``V(s_0)·w`` at each episode's start.
            achieved: [E] the discounted scalarized return the episode achieved (bootstrapped
                with ``V(final_obs)·w`` when truncated).
        """
        weights = np.asarray(weights, dtype=np.float64).reshape(-1, self.m)
        predicted, achieved = (
            np.asarray(predicted, np.float64).ravel(),
            np.asarray(achieved, np.float64).ravel(),
        )
        if len(weights) == 0:
            return
        keep = (1 - LAG_RATE) ** len(achieved)
        level = float(np.abs(achieved).mean())
        self.scale = level if self.scale == 0.0 else keep * self.scale + (1 - keep) * level
        gap = (predicted - achieved) / max(self.scale, 1e-8)
        nearest = np.abs(weights[:, None, :] - self.anchors[None]).sum(-1).argmin(1)  # [E]
        for k in np.unique(nearest):
            mine = gap[nearest == k]
            keep_k = (1 - LAG_RATE) ** len(mine) if self.count[k] else 0.0
            self.lag[k] = keep_k * self.lag[k] + (1 - keep_k) * float(mine.mean())
            self.count[k] += len(mine)

    def state(self) -> dict[str, Any]:
        """The adaptive state as JSON-ready data (:meth:`load_state` restores it)."""
        return {"lag": self.lag.tolist(), "count": self.count.tolist(), "scale": self.scale}

    def load_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`state`. Raises AmorError when it was saved for another anchor set."""
        lag, count = np.asarray(state["lag"], np.float64), np.asarray(state["count"], np.int64)
        if lag.shape != self.lag.shape or count.shape != self.count.shape:
            raise AmorError(f"weight sampler state has {lag.size} anchors, this sampler {self.lag.size}")
        self.lag, self.count, self.scale = lag, count, float(state["scale"])


def anchor_weights(m: int) -> np.ndarray:
    """The adaptive anchors: the centre (1/m each) and, per objective k, the sweep-line points
    ``w_k`` in :data:`ANCHOR_LEVELS` (rest equal). Returns [1 + 4m, m] float64 (one row for m = 1)."""
    if m == 1:
        return np.ones((1, 1))
    rows = [np.full(m, 1.0 / m)]
    for k in range(m):
        for level in ANCHOR_LEVELS:
            w = np.full(m, (1.0 - level) / (m - 1))
            w[k] = level
            rows.append(w)
    return np.asarray(rows)
