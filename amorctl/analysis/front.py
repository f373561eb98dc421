"""Pareto-front metrics for multi-objective returns: dominance, filtering, hypervolume, EUM, sparsity.

Every function here is pure NumPy over explicit arrays. Objectives are **maximized** (larger
returns are better), as the paper plots them. A point set is ``[n, m]``: n policies (one per
sampled weight vector), m objectives. See ``docs/pareto.md`` for the definitions.

Conventions:

- ``a`` dominates ``b`` when ``a >= b`` in every objective and ``a > b`` in at least one.
- Dominance filtering is ``moocore.is_nondominated`` (O(n log n) for m <= 3, Kung et al. above).
- Duplicates: identical points do not dominate each other, so every copy of a non-dominated point
  is kept by :func:`non_dominated_mask` (each sampled weight keeps its row; the non-dominated
  fraction counts copies). Pass ``keep_duplicates=False`` to keep only the first copy.
- Hypervolume uses ``moocore`` (which minimizes; points are negated here). It is exact up to
  :func:`exact_hypervolume_limit` non-dominated points for the number of objectives; above that
  it is a Monte Carlo estimate with a confidence interval, and the result says which was used.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations
from typing import Any, Literal

import numpy as np

from amorctl.core.errors import AmorError

HypervolumeMethod = Literal["auto", "exact", "monte_carlo"]

#: Largest number of non-dominated points for which ``hypervolume(method="auto")`` computes the
#: exact value, by number of objectives (m <= 3 is always exact: moocore is O(n log n) there).
#: Chosen so one exact call takes about a second or less on a CPU core (measured with moocore
#: 0.3 on points spread over a concave front: m=7, 256 points 0.9 s; m=8, 128 points 1.2 s;
#: m=7, 512 points ~26 s). Objective counts above 8 use 64.
EXACT_HV_MAX_POINTS: dict[int, int] = {4: 8192, 5: 2048, 6: 512, 7: 256, 8: 128}
_EXACT_HV_MAX_POINTS_HIGH_M = 64

#: Default margin of the reference-point rule, as a fraction of each objective's range.
DEFAULT_REFERENCE_MARGIN = 0.1


def _as_points(points: Any, name: str = "points") -> np.ndarray:
    """Check and convert a point set to a float64 array [n, m] with n >= 1, m >= 1, all finite."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise AmorError(f"{name}: expected a non-empty [n, m] array of returns, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise AmorError(f"{name}: contains NaN or infinite values")
    return arr


def dominates(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether ``a`` Pareto-dominates ``b`` (maximization); broadcasts over leading axes.

    Args:
        a: [..., m] objective values.
        b: [..., m] objective values (broadcastable with ``a``).

    Returns:
        [...] bool: ``all(a >= b) and any(a > b)`` along the last axis.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return np.all(a >= b, axis=-1) & np.any(a > b, axis=-1)


def non_dominated_mask(points: np.ndarray, *, keep_duplicates: bool = True) -> np.ndarray:
    """Mark the points that no other point dominates (maximization).

    Ties in some objectives are fine: a point is only removed if another point is at least as good
    everywhere and strictly better somewhere. A single point is non-dominated. If all points but
    one are dominated, only that one is marked.

    Args:
        points: [n, m] objective values, n >= 1.
        keep_duplicates: identical non-dominated points are all marked (True, the default) or only
            the first occurrence (False).

    Returns:
        [n] bool mask, True for the non-dominated points.
    """
    import moocore  # imported here, as in hypervolume(): only the front metrics need it

    pts = _as_points(points)
    # moocore's keep_weakly=True keeps every copy of a non-dominated point, False only the first
    return np.asarray(moocore.is_nondominated(pts, maximise=True, keep_weakly=keep_duplicates), dtype=bool)


def non_dominated(points: np.ndarray, *, keep_duplicates: bool = True) -> np.ndarray:
    """The non-dominated subset of ``points`` in their original order.

    Args:
        points: [n, m] objective values.
        keep_duplicates: see :func:`non_dominated_mask`.

    Returns:
        [k, m] float64, 1 <= k <= n.
    """
    pts = _as_points(points)
    return pts[non_dominated_mask(pts, keep_duplicates=keep_duplicates)]


def pairwise_non_dominated_masks(points: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    """For every pair of objectives (i, j), i < j, the points non-dominated in that pair alone.

    This is what each panel of the paper's Fig. 4 outlines. Duplicates (in the pair) are all kept.

    Args:
        points: [n, m] objective values, m >= 2.

    Returns:
        {(i, j): [n] bool mask}, m * (m - 1) / 2 entries, keys in lexicographic order.
    """
    pts = _as_points(points)
    m = pts.shape[1]
    if m < 2:
        raise AmorError(f"points: pairwise fronts need at least 2 objectives, got {m}")
    return {(i, j): non_dominated_mask(pts[:, [i, j]]) for i, j in combinations(range(m), 2)}


def non_dominated_fraction(points: np.ndarray) -> float:
    """Fraction of the n points that are non-dominated in all m objectives (copies counted).

    Args:
        points: [n, m] objective values.

    Returns:
        float in (0, 1].
    """
    return float(np.mean(non_dominated_mask(points)))


def default_reference_point(points: np.ndarray, margin: float = DEFAULT_REFERENCE_MARGIN) -> np.ndarray:
    """The default hypervolume reference point: per-objective minimum minus ``margin`` times the range.

    ``r_k = min_i J_ik - margin * (max_i J_ik - min_i J_ik)``. Where an objective has zero range
    (one point, or all equal), ``max(|min_i J_ik|, 1)`` stands in for the range, so the reference
    is always strictly below every point and every point contributes volume. The result depends on
    the point set: to compare hypervolumes across runs, pass one fixed reference point instead.

    Args:
        points: [n, m] objective values.
        margin: fraction of the range, > 0.

    Returns:
        [m] float64 reference point.
    """
    pts = _as_points(points)
    if not (math.isfinite(margin) and margin > 0):
        raise AmorError(f"reference margin must be a positive number, got {margin}")
    lo = pts.min(axis=0)
    span = pts.max(axis=0) - lo
    span = np.where(span > 0, span, np.maximum(np.abs(lo), 1.0))
    return lo - margin * span


def exact_hypervolume_limit(m: int) -> int | None:
    """Most non-dominated points for which ``method="auto"`` is exact in m objectives (None: no limit)."""
    if m <= 3:
        return None
    return EXACT_HV_MAX_POINTS.get(m, _EXACT_HV_MAX_POINTS_HIGH_M)


@dataclass(frozen=True)
class HypervolumeResult:
    """A hypervolume value and how it was obtained.

    Attributes:
        value: the hypervolume (exact, or the Monte Carlo mean).
        method: ``"exact"`` or ``"monte_carlo"``.
        ci_low, ci_high: the confidence interval; both equal ``value`` when exact.
        confidence: the interval's level (e.g. 0.95); 1.0 when exact.
        n_samples: Monte Carlo samples in total (0 when exact).
        n_points: non-dominated points strictly better than the reference that were measured.
        reference_point: [m] the reference point used.
    """

    value: float
    method: Literal["exact", "monte_carlo"]
    ci_low: float
    ci_high: float
    confidence: float
    n_samples: int
    n_points: int
    reference_point: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (the reference point as a list)."""
        return {
            "value": self.value,
            "method": self.method,
            "ci_low": self.ci_low,
            "ci_high": self.ci_high,
            "confidence": self.confidence,
            "n_samples": self.n_samples,
            "n_points": self.n_points,
            "reference_point": [float(v) for v in self.reference_point],
        }


def hypervolume(
    points: np.ndarray,
    reference_point: np.ndarray | Sequence[float] | None = None,
    *,
    method: HypervolumeMethod = "auto",
    max_exact_points: int | None = None,
    n_samples: int = 262_144,
    n_batches: int = 16,
    confidence: float = 0.95,
    seed: int | np.random.Generator | None = 0,
) -> HypervolumeResult:
    """Hypervolume (maximization) of the region dominated by ``points`` and bounded below by the reference.

    Only non-dominated points strictly better than the reference in every objective contribute;
    the others add no volume and are dropped first.

    ``method="auto"`` is exact (``moocore.hypervolume``) when the number of such points is at most
    ``max_exact_points`` (default :func:`exact_hypervolume_limit` for m objectives), otherwise a
    Monte Carlo estimate: ``n_batches`` independent ``moocore.hv_approx(method="DZ2019-MC")``
    estimates of ``n_samples / n_batches`` random directions each (an unbiased estimator of the
    exact polar-coordinate integral); ``value`` is their mean and the interval is the Student-t
    interval of that mean. ``"exact"`` / ``"monte_carlo"`` force one method.

    Args:
        points: [n, m] objective values.
        reference_point: [m], or None for :func:`default_reference_point`.
        method: ``"auto"``, ``"exact"`` or ``"monte_carlo"``.
        max_exact_points: overrides the exact-size threshold of ``"auto"``.
        n_samples: Monte Carlo directions in total (split over the batches).
        n_batches: independent Monte Carlo batches (>= 2) behind the interval.
        confidence: level of the Monte Carlo interval, in (0, 1).
        seed: seeds the Monte Carlo batches (a fixed default keeps reports reproducible).

    Returns:
        :class:`HypervolumeResult`.
    """
    import moocore  # imported here: only this function needs the compiled library

    pts = _as_points(points)
    m = pts.shape[1]
    ref = default_reference_point(pts) if reference_point is None else np.asarray(reference_point, float)
    if ref.shape != (m,) or not np.all(np.isfinite(ref)):
        raise AmorError(f"reference point: expected {m} finite values, got {np.asarray(reference_point)}")
    if method not in ("auto", "exact", "monte_carlo"):
        raise AmorError(f"hypervolume method must be auto, exact or monte_carlo, got {method!r}")

    front = non_dominated(pts, keep_duplicates=False)
    front = front[np.all(front > ref, axis=1)]
    k = front.shape[0]
    if k == 0:
        return HypervolumeResult(0.0, "exact", 0.0, 0.0, 1.0, 0, 0, ref)

    limit = max_exact_points if max_exact_points is not None else exact_hypervolume_limit(m)
    use_exact = method == "exact" or (method == "auto" and (limit is None or k <= limit))
    if use_exact:
        value = float(moocore.hypervolume(-front, ref=-ref))  # moocore minimizes
        return HypervolumeResult(value, "exact", value, value, 1.0, 0, k, ref)

    if n_batches < 2 or n_samples < n_batches:
        raise AmorError("Monte Carlo hypervolume needs n_batches >= 2 and n_samples >= n_batches")
    if not 0 < confidence < 1:
        raise AmorError(f"confidence must be in (0, 1), got {confidence}")
    from scipy import stats

    rng = np.random.default_rng(seed)
    per_batch = n_samples // n_batches
    estimates = np.array(
        [
            moocore.hv_approx(-front, ref=-ref, nsamples=per_batch, method="DZ2019-MC", seed=rng)
            for _ in range(n_batches)
        ]
    )
    mean = float(estimates.mean())
    sem = float(estimates.std(ddof=1) / math.sqrt(n_batches))
    half = float(stats.t.ppf(0.5 + confidence / 2, df=n_batches - 1)) * sem
    return HypervolumeResult(
        mean, "monte_carlo", mean - half, mean + half, confidence, per_batch * n_batches, k, ref
    )


def expected_utility(points: np.ndarray, weights: np.ndarray) -> float:
    """Expected utility metric (EUM): the mean over weights of the best linear utility on the front.

    ``EUM = (1/K) sum_k max_i w_k . J_i`` (Zintgraf et al. 2015; morl-baselines
    ``expected_utility``). Dominated points never change the max, so pass all points or the front.

    Args:
        points: [n, m] objective values.
        weights: [K, m] weight vectors (typically the sampled ones, rows on the simplex).

    Returns:
        float.
    """
    pts = _as_points(points)
    w = _as_points(weights, "weights")
    if w.shape[1] != pts.shape[1]:
        raise AmorError(f"weights have {w.shape[1]} objectives but points have {pts.shape[1]}")
    return float(np.mean(np.max(w @ pts.T, axis=1)))


def sparsity(front: np.ndarray) -> float:
    """Sparsity of a front (PGMORL, Xu et al. 2020; morl-baselines ``sparsity``).

    Per objective, sort the values and sum the squared gaps between neighbours; add over objectives
    and divide by ``n - 1``. Lower is denser. 0 for fewer than two points. Apply it to the distinct
    non-dominated points (as :func:`summarize_front` does: copies would add zero gaps and lower it);
    it says nothing about the front's extent.

    Args:
        front: [n, m] objective values.

    Returns:
        float >= 0.
    """
    pts = _as_points(front, "front")
    n = pts.shape[0]
    if n < 2:
        return 0.0
    gaps = np.diff(np.sort(pts, axis=0), axis=0)  # [n-1, m]
    return float(np.sum(gaps**2) / (n - 1))


@dataclass(frozen=True)
class FrontSummary:
    """All the front numbers of one evaluation.

    Attributes:
        non_dominated: [n] bool, non-dominated in all m objectives (copies kept).
        pairwise: {(i, j): [n] bool} non-dominated in objectives i and j alone.
        non_dominated_fraction: mean of ``non_dominated``.
        hypervolume: :class:`HypervolumeResult`.
        expected_utility: EUM over the given weights.
        sparsity: sparsity of the distinct non-dominated points.
    """

    non_dominated: np.ndarray
    pairwise: dict[tuple[int, int], np.ndarray]
    non_dominated_fraction: float
    hypervolume: HypervolumeResult
    expected_utility: float
    sparsity: float


def summarize_front(
    points: np.ndarray,
    weights: np.ndarray,
    reference_point: np.ndarray | Sequence[float] | None = None,
    *,
    hv_method: HypervolumeMethod = "auto",
    seed: int | np.random.Generator | None = 0,
) -> FrontSummary:
    """Compute every metric of ``docs/pareto.md`` for one point set.

    Args:
        points: [n, m] per-objective returns, one row per sampled weight vector.
        weights: [K, m] the weights for the expected utility (usually the n sampled ones).
        reference_point: [m] or None for :func:`default_reference_point`.
        hv_method: passed to :func:`hypervolume`.
        seed: seeds a Monte Carlo hypervolume.

    Returns:
        :class:`FrontSummary`.
    """
    pts = _as_points(points)
    mask = non_dominated_mask(pts)
    pairwise = pairwise_non_dominated_masks(pts) if pts.shape[1] >= 2 else {}
    return FrontSummary(
        non_dominated=mask,
        pairwise=pairwise,
        non_dominated_fraction=float(mask.mean()),
        hypervolume=hypervolume(pts, reference_point, method=hv_method, seed=seed),
        expected_utility=expected_utility(pts, weights),
        sparsity=sparsity(non_dominated(pts, keep_duplicates=False)),
    )


@dataclass(frozen=True)
class SurvivorFront:
    """The front of the weight vectors whose episodes survived (reached the time limit).

    A fall ends the episode early and folds every objective's return into one low number, so the
    fallen points sit in a corner of every panel and stretch the front. This is the front of the
    others, each point the mean over its surviving episodes only (docs/pareto.md).

    Attributes:
        survived: [K] bool, at least one of the weight vector's episodes survived.
        non_dominated: [K] bool, non-dominated among the survivors (False for fallen rows).
        summary: the metrics over the survivors' rows (None when no weight vector survived);
            its masks index the survivors in order (``np.flatnonzero(survived)``).
    """

    survived: np.ndarray
    non_dominated: np.ndarray
    summary: FrontSummary | None

    def to_dict(self, points: np.ndarray) -> dict[str, Any]:
        """The ``survivors`` object of pareto.json (docs/pareto.md); ``points`` [K, m] are the
        survivors' means (NaN rows become rows of None)."""
        s = self.summary
        rows = np.asarray(points, dtype=np.float64)
        return {
            "count": int(self.survived.sum()),
            "fallen": int((~self.survived).sum()),
            "points": [[float(v) if math.isfinite(v) else None for v in row] for row in rows],
            "non_dominated": [bool(v) for v in self.non_dominated],
            "non_dominated_fraction": None if s is None else s.non_dominated_fraction,
            "hypervolume": None if s is None else s.hypervolume.to_dict(),
            "expected_utility": None if s is None else s.expected_utility,
            "sparsity": None if s is None else s.sparsity,
        }


def survivor_means(returns: np.ndarray, survived: np.ndarray) -> np.ndarray:
    """[K, m] mean return over each weight vector's surviving episodes (NaN rows where all fell).

    Args:
        returns: [K, E, m] per-episode returns.
        survived: [K, E] 1 where the episode reached the time limit, else 0.
    """
    alive = np.asarray(survived) > 0.5  # [K, E]
    count = alive.sum(axis=1)  # [K]
    total = np.where(alive[..., None], returns, 0.0).sum(axis=1)  # [K, m]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count[:, None] > 0, total / np.maximum(count, 1)[:, None], np.nan)


def shared_reference_point(points: np.ndarray, survivor_points: np.ndarray) -> np.ndarray:
    """One reference point for the front of all episodes and the survivors' front: the default rule
    (:func:`default_reference_point`) over the rows of both (NaN rows of fallen vectors skipped).

    Args:
        points: [K, m] mean returns over all episodes.
        survivor_points: [K, m] mean returns over surviving episodes (NaN rows where none survived).

    Returns:
        [m] float64.
    """
    rows = np.vstack([_as_points(points), np.asarray(survivor_points, dtype=np.float64)])
    return default_reference_point(rows[np.all(np.isfinite(rows), axis=1)])


def summarize_fronts(
    points: np.ndarray,
    survivor_points: np.ndarray,
    weights: np.ndarray,
    reference_point: np.ndarray | Sequence[float] | None = None,
    *,
    hv_method: HypervolumeMethod = "auto",
    seed: int | np.random.Generator | None = 0,
) -> tuple[FrontSummary, SurvivorFront]:
    """:func:`summarize_front` of all points and of the survivors, at ONE reference point.

    Args:
        points: [K, m] mean returns over all episodes of each weight vector.
        survivor_points: [K, m] mean returns over the surviving episodes (NaN rows: none survived).
        weights: [K, m] the weight vectors (the survivors' EUM uses their own rows).
        reference_point: [m], or None for :func:`shared_reference_point`.
        hv_method, seed: passed to :func:`hypervolume`.

    Returns:
        (summary of all points, :class:`SurvivorFront`).
    """
    pts = _as_points(points)
    surv = np.asarray(survivor_points, dtype=np.float64)
    if surv.shape != pts.shape:
        raise AmorError(f"survivor points have shape {surv.shape}, points {pts.shape}")
    ref = shared_reference_point(pts, surv) if reference_point is None else reference_point
    summary = summarize_front(pts, weights, ref, hv_method=hv_method, seed=seed)
    alive = np.all(np.isfinite(surv), axis=1)
    nd = np.zeros(len(pts), dtype=bool)
    if not alive.any():
        return summary, SurvivorFront(alive, nd, None)
    w = np.asarray(weights, dtype=np.float64)
    sub = summarize_front(surv[alive], w[alive], ref, hv_method=hv_method, seed=seed)
    nd[alive] = sub.non_dominated
    return summary, SurvivorFront(alive, nd, sub)
