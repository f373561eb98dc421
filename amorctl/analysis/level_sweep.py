"""One objective's weight swept over levels, the others sharing the rest (the paper's Fig. 6):
``amorctl evaluate --sweep``. Returns, survival and the Spearman rank correlation per sweep, and
what a robot user watches per level (action rate, joint-velocity RMS: :mod:`smoothness`).
Shapes: L = levels, E = episodes per level, m = objectives."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from amorctl.analysis.eval_env import Progress, check_objective, episode_seeds, make_eval_env
from amorctl.analysis.rollout import rollout
from amorctl.analysis.smoothness import MotionSums, motion_sums
from amorctl.analysis.sweeps import DEFAULT_SWEEP_LEVELS, fixed_shape_policy, floats
from amorctl.core.config import TrainConfig
from amorctl.core.errors import AmorError
from amorctl.core.vecenv import close_env


@dataclass
class WeightSweep:
    """Returns of one objective at several levels of its weight (the paper's Fig. 6).

    Attributes:
        objective: the swept objective's name.
        levels: [L] its weight at each level (the others share ``1 - level`` equally).
        returns: [L, E] its unweighted cumulative reward per episode.
        survival: [L] survival rate per level; survived: [L, E] bool per episode (None: not kept).
        spearman_rho, spearman_p: rank correlation between weight and return over all L * E
            episodes, and its p-value (NaN when undefined, e.g. all returns equal).
        motion: per-level action rate and joint-velocity sums (None: steps not recorded).
        lengths: [L, E] control steps per episode (None: not kept); not in :meth:`to_dict`.
    """

    objective: str
    levels: np.ndarray
    returns: np.ndarray
    survival: np.ndarray
    spearman_rho: float
    spearman_p: float
    survived: np.ndarray | None = None
    motion: MotionSums | None = None
    lengths: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "objective": self.objective,
            "levels": floats(self.levels),
            "returns": floats(self.returns),
            "mean": floats(np.nanmean(self.returns, axis=1)),
            "survival": floats(self.survival),
            "spearman_rho": floats(np.float64(self.spearman_rho)),
            "spearman_p": floats(np.float64(self.spearman_p)),
            **(self.motion.to_dict() if self.motion is not None else {}),
        }


def sweep_levels_weights(index: int, m: int, levels: Sequence[float]) -> np.ndarray:
    """[L, m]: weight ``level`` on objective ``index``, the rest shared equally by the others."""
    lv = np.asarray(levels, dtype=np.float64)
    if lv.ndim != 1 or len(lv) < 3:
        raise AmorError(f"a sweep needs at least 3 levels, got {list(np.atleast_1d(lv))}")
    if ((lv < 0) | (lv > 1)).any() or not np.isfinite(lv).all():
        raise AmorError(f"sweep levels must lie in [0, 1], got {lv.tolist()}")
    if m == 1:
        raise AmorError("a weight sweep needs at least 2 objectives")
    w = np.repeat(((1.0 - lv) / (m - 1))[:, None], m, axis=1)
    w[:, index] = lv
    return w


def weight_sweep(
    policy: Any,
    config: TrainConfig,
    objective: str,
    *,
    levels: Sequence[float] = DEFAULT_SWEEP_LEVELS,
    motions: Sequence[str] | None = None,
    episodes: int = 16,
    seed: int = 0,
    on_step: Progress | None = None,
    episode_ids: np.ndarray | None = None,
) -> WeightSweep:
    """Sweep one objective's weight over ``levels`` in one batched rollout (L * E envs).

    Env ``l * E + e`` runs level l's episode e, seeded by ``seed`` and ``(l, episode_ids[e])``
    (default ``episode_ids``: ``0 .. E-1``; a block of a larger sweep passes its indices).

    Raises:
        AmorError: unknown objective, fewer than 3 levels, episodes < 1, unknown motion.
    """
    if episodes < 1:
        raise AmorError(f"--episodes must be >= 1, got {episodes}")
    names = tuple(policy.objectives)
    idx = check_objective(objective, names)
    w = sweep_levels_weights(idx, len(names), levels)
    n_lv = w.shape[0]
    n = n_lv * episodes
    ids = np.arange(episodes) if episode_ids is None else np.asarray(episode_ids, dtype=np.int64).reshape(-1)
    if ids.shape != (episodes,):
        raise AmorError(f"episode_ids: need {episodes} indices, got {ids.size}")
    grid = np.meshgrid(np.arange(n_lv), ids, indexing="ij")
    env_seeds = episode_seeds(seed, np.stack(grid, axis=-1).reshape(n, 2))
    env, _ = make_eval_env(config, n, motions=motions, seed=seed)
    try:
        ro = rollout(
            fixed_shape_policy(policy),
            env,
            np.repeat(w, episodes, axis=0),
            episodes=1,
            seed=env_seeds,
            record_steps=True,
            on_step=on_step,
        )
    finally:
        close_env(env)
    motion = motion_sums(ro, n_lv, config.env.action_mode == "residual" and config.env.kind == "tracking")
    eps = ro.episodes
    returns = np.full(n, np.nan)
    returns[eps.env] = eps.returns[:, idx]
    survived = np.zeros(n)
    survived[eps.env] = eps.survived
    lengths = np.zeros(n, dtype=np.int64)
    lengths[eps.env] = eps.length
    lengths = lengths.reshape(n_lv, episodes)
    returns = returns.reshape(n_lv, episodes)
    rho, p = level_spearman(w[:, idx], returns)
    kept = survived.reshape(n_lv, episodes) > 0.5
    return WeightSweep(objective, w[:, idx], returns, kept.mean(axis=1), rho, p, kept, motion, lengths)


def level_spearman(levels: np.ndarray, returns: np.ndarray) -> tuple[float, float]:
    """Spearman rho and p-value of weight level [L] vs return [L, E] over the finite episodes
    (NaN, NaN when undefined: fewer than 3 episodes, or all returns equal)."""
    from scipy import stats

    flat = returns.ravel()
    level_of = np.repeat(levels, returns.shape[1])
    ok = np.isfinite(flat)
    if ok.sum() < 3 or np.ptp(flat[ok]) == 0:
        return math.nan, math.nan
    res = stats.spearmanr(level_of[ok], flat[ok])
    return float(res.statistic), float(res.pvalue)
