"""Sweeps split across the ranks of a ``torchrun`` launch, gathered at rank 0.

``amorctl pareto`` and ``amorctl evaluate --sweep`` under torchrun call these instead of
:func:`~amorctl.analysis.sweeps.pareto_sweep` / :func:`~amorctl.analysis.level_sweep.weight_sweep`.
Each rank evaluates its share in its own batched rollout with the sweep's ``seed`` and the global
indices of its rows (every episode is seeded by ``seed`` and its own key, never its position in a
batch: :func:`~amorctl.analysis.eval_env.episode_seeds`), and rank 0 puts the per-row results
back in the 1-process order and computes the summaries over all of them, so it writes the same
files, with the same rows, as a 1-process sweep. Without a process group they are the plain sweeps.

- Pareto: the K weight vectors are cut into contiguous blocks (:func:`rank_rows`); every rank
  also evaluates the equal-weights vector, rank 0's is reported.
- Weight sweep: the E episodes per level are cut into blocks; the returns ``[L, E]`` are
  concatenated along the episodes, the Spearman correlation is computed over all of them.

A rank's rows are therefore the 1-process sweep's rows (docs/distributed.md: bit-identical with
the torch-cpu backend; what can differ in the last bits elsewhere).
"""

from __future__ import annotations

import dataclasses
import functools
import operator
from collections.abc import Sequence
from typing import Any

import numpy as np

from amorctl.analysis.front import HypervolumeMethod, summarize_fronts
from amorctl.analysis.level_sweep import WeightSweep, level_spearman, weight_sweep
from amorctl.analysis.sweeps import DEFAULT_SWEEP_LEVELS, ParetoGroup, ParetoSweep, pareto_sweep
from amorctl.core.config import TrainConfig
from amorctl.core.errors import AmorError
from amorctl.train.distributed import World, current, rank_rows


def pareto_sweep_ranks(
    policy: Any,
    config: TrainConfig,
    weights: np.ndarray,
    *,
    reference_point: Sequence[float] | None = None,
    hv_method: HypervolumeMethod = "auto",
    seed: int = 0,
    world: World | None = None,
    **options: Any,
) -> ParetoSweep | None:
    """:func:`~amorctl.analysis.sweeps.pareto_sweep` with the K weight vectors split over ranks.

    Returns the whole sweep at rank 0, None on the other ranks (``options``: the remaining
    keyword arguments of ``pareto_sweep``, e.g. ``motions``, ``episodes``, ``sampling``).

    Raises:
        AmorError: fewer weight vectors than ranks, or what ``pareto_sweep`` raises (on every rank).
    """
    world = world or current()
    kwargs = dict(reference_point=reference_point, hv_method=hv_method, **options)
    if not world.distributed:
        return pareto_sweep(policy, config, weights, seed=seed, **kwargs)
    w = np.asarray(weights, dtype=np.float64)
    with world.agreeing():
        if w.ndim != 2 or w.shape[0] < world.size:
            raise AmorError(f"{world.size} processes need at least {world.size} weight vectors, got {len(w)}")
        if world.rank != 0:
            kwargs["on_step"] = None  # progress of rank 0's block only
        block = rank_rows(len(w), world)
        ids = np.arange(len(w))[block]  # this block's global sample indices seed its episodes
        part = pareto_sweep(policy, config, w[block], seed=seed, sample_ids=ids, **kwargs)
    rows = [(g.points, g.points_std, g.survival, g.survivor_points) for g in part.groups]
    parts = world.gather((rows, part.num_envs, part.env_steps, part.seconds))
    if parts is None:
        return None
    groups = []
    for gi, grp in enumerate(part.groups):
        merged = [np.concatenate([p[0][gi][j] for p in parts]) for j in range(4)]
        points, points_std, survival, surv_pts = merged
        summary, survivors = summarize_fronts(
            points, surv_pts, w, reference_point, hv_method=hv_method, seed=seed
        )
        groups.append(
            ParetoGroup(
                grp.motion,
                points,
                points_std,
                survival,
                grp.equal_point,
                summary,
                surv_pts,
                survivors,
                equal_survival=grp.equal_survival,
            )
        )
    return dataclasses.replace(
        part,
        weights=w,
        groups=groups,
        num_envs=sum(p[1] for p in parts),
        env_steps=sum(p[2] for p in parts),
        seconds=max(p[3] for p in parts),
    )


def weight_sweep_ranks(
    policy: Any,
    config: TrainConfig,
    objective: str,
    *,
    levels: Sequence[float] = DEFAULT_SWEEP_LEVELS,
    episodes: int = 16,
    seed: int = 0,
    world: World | None = None,
    **options: Any,
) -> WeightSweep | None:
    """:func:`~amorctl.analysis.level_sweep.weight_sweep` with the episodes per level split over ranks.

    Returns the whole sweep at rank 0, None on the other ranks (``options``: ``motions``,
    ``on_step``).

    Raises:
        AmorError: fewer episodes than ranks, or what ``weight_sweep`` raises (on every rank).
    """
    world = world or current()
    if not world.distributed:
        return weight_sweep(policy, config, objective, levels=levels, episodes=episodes, seed=seed, **options)
    with world.agreeing():
        if episodes < world.size:
            raise AmorError(f"{world.size} processes need --episodes >= {world.size}, got {episodes}")
        if world.rank != 0:
            options["on_step"] = None
        ids = np.arange(episodes)[rank_rows(episodes, world)]
        mine = len(ids)
        part = weight_sweep(
            policy, config, objective, levels=levels, episodes=mine, seed=seed, episode_ids=ids, **options
        )
    parts = world.gather((part.returns, part.survival * mine, mine, part.motion))
    if parts is None:
        return None
    returns = np.concatenate([p[0] for p in parts], axis=1)  # [L, E]
    survival = sum(p[1] for p in parts) / episodes
    motion = None if part.motion is None else functools.reduce(operator.add, (p[3] for p in parts))
    rho, p_value = level_spearman(part.levels, returns)
    return WeightSweep(part.objective, part.levels, returns, survival, rho, p_value, motion=motion)
