"""Weight coverage (``amorctl pareto --coverage``): how well each region of the simplex is trained.

For K weight vectors spread evenly over the simplex regions of :mod:`amorctl.core.simplex_regions`
(dominant objective x bin of its weight), one episode each in one batched rollout:

- **predicted**: the critic's value at the episode's first state, scalarized by ``w``:
  ``w . V(s_0, w)`` (the policy's own estimate of what it will earn);
- **achieved**: the discounted scalarized return the episode then earned,
  ``sum_t gamma^t w . r_t`` with the run's ``gamma`` (the quantity the critic estimates; a time-limit
  truncation ends it, which at 10 s and gamma = 0.99 drops less than 1 %); also undiscounted;
- per region: the samples, their mean predicted and achieved value, the gap (achieved minus
  predicted; negative: the policy underdelivers where it believes it is good), survival, and the
  training episodes the run logged there (``wcount/<region>`` columns of metrics.csv, summed over
  iterations; None for runs recorded before those columns existed).

A region with a large negative gap or few training episodes is where a user's slider finds a
policy that does not do what the critic believes. Documented in docs/pareto.md ("Weight coverage").
Shapes: K samples, m objectives, R = 4 m regions.
"""

from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.analysis.eval_env import episode_limit, make_eval_env
from amorctl.core.config import TrainConfig
from amorctl.core.contracts import tracking_view
from amorctl.core.errors import AmorError
from amorctl.core.simplex_regions import BIN_EDGES, NUM_BINS, region_index, region_labels
from amorctl.core.vecenv import close_env
from amorctl.core.weights import sample_dirichlet
from amorctl.envs.wrappers import FixedWeights

WCOUNT_PREFIX = "wcount/"  # the training loop's metric prefix (amorctl.train.episode_stats)


def feasible_regions(m: int) -> np.ndarray:
    """[R] bool: regions a weight vector can fall in (the dominant weight is at least 1/m)."""
    edges = np.array((0.0, *BIN_EDGES, 1.0))
    per_bin = edges[1:] > 1.0 / m + 1e-12
    if m == 1:
        per_bin = np.zeros(NUM_BINS, dtype=bool)
        per_bin[-1] = True
    return np.tile(per_bin, m)


def stratified_weights(m: int, samples: int, seed: int = 0) -> np.ndarray:
    """[K, m] weight vectors spread evenly over the feasible regions (K = ``samples``).

    Region r = (k, bin [lo, hi)) gets ``samples // R`` vectors (the first ``samples % R`` regions
    one more): ``w_k ~ U(max(lo, 1/m), hi)``, the rest ``(1 - w_k) * Dirichlet(1)`` over the other
    objectives, redrawn until ``w_k`` is the largest entry. Each region has at least one vector
    when ``samples >= R``.
    """
    if samples < 1:
        raise AmorError(f"--samples must be >= 1, got {samples}")
    rng = np.random.default_rng(seed)
    regions = np.flatnonzero(feasible_regions(m))
    edges = np.array((0.0, *BIN_EDGES, 1.0))
    counts = np.full(len(regions), samples // len(regions))
    counts[: samples % len(regions)] += 1
    out = []
    for r, n in zip(regions, counts, strict=True):
        k, b = divmod(int(r), NUM_BINS)
        lo, hi = max(edges[b], 1.0 / m), edges[b + 1]
        got = np.zeros((0, m))
        while len(got) < n:
            top = rng.uniform(lo, hi, size=4 * n)
            rest = sample_dirichlet(rng, 4 * n, max(m - 1, 1), dtype=np.float64) * (1.0 - top)[:, None]
            w = np.insert(rest, k, top, axis=1) if m > 1 else top[:, None]
            w = w[:, :m]
            ok = region_index(w) == r
            got = np.vstack([got, w[ok]])
        out.append(got[:n])
    w = np.vstack(out)
    return w / w.sum(axis=1, keepdims=True)


@dataclass
class Coverage:
    """The result of :func:`coverage` (``coverage.json``; schema ``COVERAGE_JSON_SCHEMA``)."""

    objective_names: tuple[str, ...]
    gamma: float
    weights: np.ndarray  # [K, m]
    region: np.ndarray  # [K] region index
    predicted: np.ndarray  # [K] w . V(s_0)
    achieved: np.ndarray  # [K] discounted scalarized return
    achieved_undiscounted: np.ndarray  # [K]
    survived: np.ndarray  # [K] bool
    training_episodes: np.ndarray | None  # [R] from metrics.csv, None when not logged
    episode_seconds: float
    seconds: float
    env_steps: int

    @property
    def labels(self) -> list[str]:
        return region_labels(self.objective_names)


def training_episodes(metrics_path: Path, names: tuple[str, ...]) -> np.ndarray | None:
    """[R] training episodes per region summed over ``metrics.csv``'s ``wcount/`` columns (None
    when the file or the columns are missing: runs trained before they were logged)."""
    if not metrics_path.is_file():
        return None
    labels = region_labels(names)
    total = np.zeros(len(labels))
    with metrics_path.open(newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        cols = [f"{WCOUNT_PREFIX}{label}" for label in labels]
        if not reader.fieldnames or not set(cols) <= set(reader.fieldnames):
            return None
        for row in reader:
            vals = np.array([float(row[c]) for c in cols])
            total += np.where(np.isfinite(vals), vals, 0.0)
    return total


def _episodes(policy: Any, env: Any, w: np.ndarray, gamma: float, seed: int, on_step: Any) -> dict[str, Any]:
    """One episode per env under fixed weights: first observation, discounted and plain scalarized
    return, survival, env steps."""
    n, m = w.shape
    wrapped = FixedWeights(env, w)
    obs, _ = wrapped.reset(seed=seed)
    obs = np.array(obs, dtype=np.float32)
    obs[:, -m:] = w  # the weights the episode runs under (FixedWeights reports them too)
    first = obs.copy()
    cap = episode_limit(env) + 1 if episode_limit(env) else 100_000
    active = np.ones(n, dtype=bool)
    survived = np.zeros(n, dtype=bool)
    disc, plain, steps, discount = np.zeros(n), np.zeros(n), 0, 1.0
    for t in range(cap):
        if not active.any():
            break
        actions = np.asarray(policy(obs), dtype=np.float32)
        obs, rewards, terminated, truncated, _ = wrapped.step(actions)
        scalar = np.sum(np.asarray(rewards, dtype=np.float64) * w, axis=1)
        disc += np.where(active, discount * scalar, 0.0)
        plain += np.where(active, scalar, 0.0)
        steps += int(active.sum())
        ended = active & (np.asarray(terminated) | np.asarray(truncated))
        survived[ended] = ~np.asarray(terminated)[ended]
        active &= ~ended
        discount *= gamma
        if on_step is not None:
            on_step(t + 1, cap)
    return {"first": first, "disc": disc, "plain": plain, "survived": survived, "steps": steps}


def coverage(
    policy: Any,
    config: TrainConfig,
    weights: np.ndarray,
    *,
    motions: list[str] | None = None,
    seed: int = 0,
    metrics_path: Path | None = None,
    on_step: Any = None,
) -> Coverage:
    """Predicted vs achieved scalarized value for each weight vector (one episode each, batched).

    Args:
        policy: a :class:`~amorctl.core.contracts.Policy` (``__call__`` and ``values``).
        config: the run's config (its ``ppo.gamma`` discounts the achieved return).
        weights: [K, m] rows on the simplex (e.g. :func:`stratified_weights`).
        motions: clips the episodes draw from (None: the run's, at random as in training).
        seed: env seed.
        metrics_path: the run's metrics.csv for the training episodes per region.
        on_step: progress callback (steps done, step cap).

    Raises:
        AmorError: weights of the wrong width, an unknown motion.
    """
    w = np.asarray(weights, dtype=np.float64)
    names = tuple(policy.objectives)
    if w.ndim != 2 or w.shape[1] != len(names) or len(w) < 1:
        raise AmorError(f"weights must be [K, {len(names)}] with K >= 1, got shape {w.shape}")
    gamma = float(config.ppo.gamma)
    env, _ = make_eval_env(config, len(w), motions=motions or None, seed=seed)
    began = time.perf_counter()
    try:
        got = _episodes(policy, env, w, gamma, seed, on_step)
        limit = episode_limit(env)
        dt = _dt(env)
    finally:
        close_env(env)
    values = np.asarray(policy.values(got["first"]), dtype=np.float64)  # [K, m]
    return Coverage(
        objective_names=names,
        gamma=gamma,
        weights=w,
        region=region_index(w),
        predicted=np.sum(values * w, axis=1),
        achieved=got["disc"],
        achieved_undiscounted=got["plain"],
        survived=got["survived"],
        training_episodes=training_episodes(metrics_path, names) if metrics_path is not None else None,
        episode_seconds=limit * dt,
        seconds=time.perf_counter() - began,
        env_steps=got["steps"],
    )


def _dt(env: Any) -> float:
    """Seconds per control step (the tracking view's, else the env's ``dt``, else 0.02 as rollouts)."""
    view = tracking_view(env)
    return float(view.dt) if view is not None else float(getattr(env, "dt", 0.02))


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(float(x)) else None


def region_table(cov: Coverage) -> list[dict[str, Any]]:
    """One row per region (all 4 m, infeasible ones with 0 samples): see the module docstring."""
    rows = []
    m = len(cov.objective_names)
    feasible = feasible_regions(m)
    total_train = None if cov.training_episodes is None else float(cov.training_episodes.sum())
    for r, label in enumerate(cov.labels):
        sel = cov.region == r
        n = int(sel.sum())
        pred = float(cov.predicted[sel].mean()) if n else math.nan
        ach = float(cov.achieved[sel].mean()) if n else math.nan
        gap = ach - pred
        train = None if cov.training_episodes is None else int(cov.training_episodes[r])
        rows.append(
            {
                "region": label,
                "objective": cov.objective_names[r // NUM_BINS],
                "bin": label.split(":", 1)[1],
                "feasible": bool(feasible[r]),
                "samples": n,
                "predicted": _num(pred),
                "achieved": _num(ach),
                "gap": _num(gap),
                "relative_gap": _num(gap / abs(pred)) if n and pred != 0 else None,
                "survival": _num(float(cov.survived[sel].mean())) if n else None,
                "training_episodes": train,
                "training_share": (train / total_train) if train is not None and total_train else None,
            }
        )
    return rows


def coverage_to_dict(cov: Coverage, files: dict[str, str] | None = None) -> dict[str, Any]:
    """The JSON document (schema :data:`amorctl.analysis.schemas.COVERAGE_JSON_SCHEMA`)."""
    pred, ach = cov.predicted, cov.achieved
    varied = len(pred) > 2 and np.std(pred) > 0 and np.std(ach) > 0
    corr = float(np.corrcoef(pred, ach)[0, 1]) if varied else math.nan
    return {
        "objectives": list(cov.objective_names),
        "gamma": cov.gamma,
        "samples": len(cov.weights),
        "episode_seconds": cov.episode_seconds,
        "regions": region_table(cov),
        "training_logged": cov.training_episodes is not None,
        "overall": {
            "predicted_mean": float(pred.mean()),
            "achieved_mean": float(ach.mean()),
            "mean_gap": float((ach - pred).mean()),
            "mean_abs_gap": float(np.abs(ach - pred).mean()),
            "correlation": _num(corr),
            "survival": float(cov.survived.mean()),
        },
        "per_sample": {
            "weights": cov.weights.tolist(),
            "region": [int(r) for r in cov.region],
            "predicted": [float(v) for v in pred],
            "achieved": [float(v) for v in ach],
            "achieved_undiscounted": [float(v) for v in cov.achieved_undiscounted],
            "survived": [bool(v) for v in cov.survived],
        },
        "timing": {"env_steps": cov.env_steps, "seconds": cov.seconds},
        "files": files or {},
    }
