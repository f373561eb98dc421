"""Sweeps over weights in one batched rollout each: Pareto fronts (``amorctl pareto``, the paper's
Fig. 4); one objective's weight against its return (``evaluate --sweep``, Fig. 6) is in
:mod:`amorctl.analysis.level_sweep`.

A sweep over K weight vectors is one :func:`amorctl.analysis.rollout.rollout` with one weight
vector per environment. Every episode's env is seeded from ``seed`` and the episode's key (motion
group, sample index, episode) alone (:func:`~amorctl.analysis.eval_env.episode_seeds`), so a
sample's returns do not depend on the other samples in the batch: a block of samples evaluated
on its own (a ``torchrun`` rank) gives the rows the whole sweep gives. Nothing here prints.
Documents: docs/pareto.md, docs/evaluate.md, docs/distributed.md.

Shapes: K = weight vectors, G = motion groups, E = episodes per weight, L = sweep levels,
m = objectives.
"""

from __future__ import annotations

import csv
import io
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from amorctl.analysis.eval_env import (
    ALL_MOTIONS,
    Progress,
    close_env,
    episode_limit,
    episode_seeds,
    make_eval_env,
)
from amorctl.analysis.front import (
    FrontSummary,
    HypervolumeMethod,
    SurvivorFront,
    summarize_fronts,
    survivor_means,
)
from amorctl.analysis.rollout import Episodes, rollout
from amorctl.core.config import TrainConfig
from amorctl.core.errors import AmorError

DEFAULT_SWEEP_LEVELS = (0.0, 0.25, 0.5, 0.75, 1.0)
# Rows per policy call in a sweep. BLAS (PyTorch's MKL) picks its matmul kernel by the batch's
# shape, so a row's actions could round differently in a batch of another size; in fixed-shape
# calls a row's result depends on the row alone (measured: docs/distributed.md).
POLICY_ROWS = 128


def fixed_shape_policy(policy: Any, rows: int = POLICY_ROWS) -> Any:
    """``policy`` called on blocks of exactly ``rows`` observations (the last block padded with
    copies of the last row), so an env's actions do not depend on how many envs the batch has."""

    def act(obs: np.ndarray) -> np.ndarray:
        n = len(obs)
        padded = np.concatenate([obs, np.repeat(obs[-1:], -n % rows, axis=0)]) if n % rows else obs
        return np.concatenate([np.asarray(policy(padded[i : i + rows])) for i in range(0, n, rows)])[:n]

    return act


# ---------------------------------------------------------------------------- pareto
@dataclass
class ParetoGroup:
    """One motion's front.

    Attributes:
        motion: the motion name (or ``"all"``).
        points: [K, m] mean unscaled returns over E episodes, one row per sampled weight.
        points_std: [K, m] their standard deviation over the E episodes.
        survival: [K] fraction of the E episodes that reached the time limit.
        equal_point: [m] the mean returns of the equal-weights (1/m) policy.
        summary: the front metrics of ``points`` (:class:`~amorctl.analysis.front.FrontSummary`).
        survivor_points: [K, m] mean returns over the surviving episodes only (NaN rows: all fell).
        survivors: the front of the surviving rows, at the same reference point
            (:class:`~amorctl.analysis.front.SurvivorFront`).
        equal_survival: fraction of the equal-weights policy's E episodes that survived.
    """

    motion: str
    points: np.ndarray
    points_std: np.ndarray
    survival: np.ndarray
    equal_point: np.ndarray
    summary: FrontSummary
    survivor_points: np.ndarray
    survivors: SurvivorFront
    equal_survival: float = 1.0


@dataclass
class ParetoSweep:
    """The result of :func:`pareto_sweep` (also what ``pareto.json`` holds)."""

    objective_names: tuple[str, ...]
    weights: np.ndarray  # [K, m]
    sampling: str
    episodes: int
    episode_seconds: float
    groups: list[ParetoGroup]
    num_envs: int
    env_steps: int
    seconds: float
    reference_point_rule: str
    meta: dict[str, Any] = field(default_factory=dict)


def pareto_sweep(
    policy: Any,
    config: TrainConfig,
    weights: np.ndarray,
    *,
    motions: Sequence[str] | None = None,
    episodes: int = 1,
    reference_point: Sequence[float] | None = None,
    hv_method: HypervolumeMethod = "auto",
    seed: int = 0,
    sampling: str = "given",
    on_step: Progress | None = None,
    sample_ids: np.ndarray | None = None,
) -> ParetoSweep:
    """Evaluate ``policy`` under every weight vector in ONE batched rollout and summarize the fronts.

    Envs: for each motion group g, each weight k (the K given plus the equal-weights 1/m vector)
    and each episode e, one env (index ``(g * (K + 1) + k) * E + e``) running one episode, its
    randomness (start clip and frame, clip switches, the toy task's noise) seeded by ``seed`` and
    ``(g, 1 + sample_ids[k], e)`` (``(g, 0, e)`` for the equal-weights vector).

    Args:
        policy: ``policy(obs [N, D]) -> actions [N, A]``.
        config: the run's config.
        weights: [K, m] rows on the simplex.
        motions: motion names (one front per motion); None: one front over random clips.
        episodes: E episodes per weight vector.
        reference_point: [m] hypervolume reference (for every group); None: the default rule of
            :func:`amorctl.analysis.front.default_reference_point`, per group.
        hv_method: ``auto`` | ``exact`` | ``monte_carlo``.
        seed: the episodes' seed (RSI, clip draws), with each episode's key.
        sampling: how ``weights`` were made (reported).
        on_step: progress callback (steps done, step cap).
        sample_ids: [K] the weights' indices in the whole sweep (default ``0 .. K-1``): a block
            of a larger sweep passes its rows' indices to get their episodes.

    Raises:
        AmorError: bad weights, episodes < 1, unknown motion, reference point of the wrong length.
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 2 or w.shape[0] < 1:
        raise AmorError(f"need at least one weight vector, got shape {w.shape}")
    if episodes < 1:
        raise AmorError(f"--episodes must be >= 1, got {episodes}")
    m = w.shape[1]
    groups = list(motions) if motions else []
    env_w, env_motion, env_seeds = _env_layout(w, len(groups), episodes, seed, sample_ids)
    n = len(env_w)
    env, names = make_eval_env(config, n, motions=groups or None, env_motion=env_motion, seed=seed)
    try:
        obj_names = tuple(env.reward_space.names)
        if len(obj_names) != m:
            raise AmorError(f"weights have {m} entries; the run has {len(obj_names)} objectives")
        if reference_point is not None and len(reference_point) != m:
            raise AmorError(
                f"--ref-point needs {m} values ({', '.join(obj_names)}), got {len(reference_point)}"
            )
        began = time.perf_counter()
        act = fixed_shape_policy(policy)
        result = rollout(act, env, env_w, episodes=1, seed=env_seeds, record_steps=False, on_step=on_step)
        seconds = time.perf_counter() - began
        steps = int(result.episodes.length.sum())
        limit = episode_limit(env)
    finally:
        close_env(env)

    motion_names = names if groups else [ALL_MOTIONS]
    out_groups = _fronts(result.episodes, w, motion_names, episodes, reference_point, hv_method, seed)
    rule = (
        "given (--ref-point)"
        if reference_point is not None
        else "per motion: min - 0.1 * (max - min) per objective over the points of all episodes and of "
        "the survivors, shared by both fronts (analysis.front.shared_reference_point)"
    )
    return ParetoSweep(
        objective_names=obj_names,
        weights=w,
        sampling=sampling,
        episodes=episodes,
        episode_seconds=limit * result.dt,
        groups=out_groups,
        num_envs=n,
        env_steps=steps,
        seconds=seconds,
        reference_point_rule=rule,
    )


def _env_layout(
    w: np.ndarray, num_motions: int, episodes: int, seed: int, sample_ids: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Which env runs what, in :func:`pareto_sweep`'s env order: each env's weights [N, m] (the K
    rows of ``w`` and the equal-weights vector, ``episodes`` envs each, for every motion group),
    its motion group [N] (None without ``num_motions``) and its episode seed [N]."""
    k, m = w.shape
    g = max(1, num_motions)
    all_w = np.vstack([w, np.full((1, m), 1.0 / m)])  # [K+1, m]
    per_group = (k + 1) * episodes
    env_motion = np.repeat(np.arange(g), per_group) if num_motions else None
    ids = np.arange(k) if sample_ids is None else np.asarray(sample_ids, dtype=np.int64).reshape(-1)
    if ids.shape != (k,):
        raise AmorError(f"sample_ids: need {k} indices, one per weight vector, got {ids.size}")
    slots = np.concatenate([1 + ids, [0]])  # [K+1]; 0: the equal-weights vector
    grid = np.meshgrid(np.arange(g), slots, np.arange(episodes), indexing="ij")
    env_seeds = episode_seeds(seed, np.stack(grid, axis=-1).reshape(g * per_group, 3))  # as env_w
    env_w = np.tile(np.repeat(all_w, episodes, axis=0), (g, 1))  # [N, m]
    return env_w, env_motion, env_seeds


def _fronts(
    eps: Episodes,
    w: np.ndarray,
    motions: Sequence[str],
    episodes: int,
    reference_point: Sequence[float] | None,
    hv_method: HypervolumeMethod,
    seed: int,
) -> list[ParetoGroup]:
    """One :class:`ParetoGroup` per motion from the episodes of the env layout of :func:`pareto_sweep`."""
    (k, m), g = w.shape, len(motions)
    n = g * (k + 1) * episodes
    returns = np.full((n, m), np.nan)
    returns[eps.env] = eps.returns
    survived = np.zeros(n)
    survived[eps.env] = eps.survived
    returns = returns.reshape(g, k + 1, episodes, m)
    survived = survived.reshape(g, k + 1, episodes)
    out = []
    for gi in range(g):
        pts = returns[gi, :k].mean(axis=1)
        surv_pts = survivor_means(returns[gi, :k], survived[gi, :k])
        summary, survivors = summarize_fronts(
            pts, surv_pts, w, reference_point, hv_method=hv_method, seed=seed
        )
        out.append(
            ParetoGroup(
                motion=motions[gi],
                points=pts,
                points_std=returns[gi, :k].std(axis=1),
                survival=survived[gi, :k].mean(axis=1),
                equal_point=returns[gi, k].mean(axis=0),
                summary=summary,
                survivor_points=surv_pts,
                survivors=survivors,
                equal_survival=float(survived[gi, k].mean()),
            )
        )
    return out


def floats(a: np.ndarray) -> list[Any]:
    """A JSON-ready nested list (NaN/inf become None)."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 0:
        v = float(arr)
        return v if math.isfinite(v) else None  # type: ignore[return-value]
    return [floats(x) for x in arr]


def pareto_to_dict(sweep: ParetoSweep, files: dict[str, str] | None = None) -> dict[str, Any]:
    """The JSON document of a sweep (schema: docs/pareto.md, :data:`PARETO_JSON_SCHEMA`)."""
    names = sweep.objective_names
    groups = []
    for grp in sweep.groups:
        s = grp.summary
        groups.append(
            {
                "motion": grp.motion,
                "points": floats(grp.points),
                "points_std": floats(grp.points_std),
                "survival": floats(grp.survival),
                "equal_weights_point": floats(grp.equal_point),
                "non_dominated": [bool(v) for v in s.non_dominated],
                "pairwise_non_dominated": {
                    f"{names[i]}/{names[j]}": [bool(v) for v in mask] for (i, j), mask in s.pairwise.items()
                },
                "non_dominated_fraction": s.non_dominated_fraction,
                "hypervolume": s.hypervolume.to_dict(),
                "expected_utility": s.expected_utility,
                "sparsity": s.sparsity,
                "survivors": grp.survivors.to_dict(grp.survivor_points),
            }
        )
    return {
        "objectives": list(names),
        "weights": floats(sweep.weights),
        "sampling": sweep.sampling,
        "samples": int(sweep.weights.shape[0]),
        "episodes": sweep.episodes,
        "episode_seconds": sweep.episode_seconds,
        "reference_point_rule": sweep.reference_point_rule,
        "motions": groups,
        "timing": {"num_envs": sweep.num_envs, "env_steps": sweep.env_steps, "seconds": sweep.seconds},
        "files": files or {},
        **sweep.meta,
    }


def pareto_csv(sweep: ParetoSweep) -> str:
    """``pareto.csv``: one row per (motion, weight vector), plus the equal-weights row per motion.

    Columns: motion, sample (index, or ``equal`` for 1/m), ``w_<obj>``, ``J_<obj>`` (mean
    unscaled return), ``J_<obj>_std``, survival, non_dominated, ``nd_<a>_<b>`` per objective pair,
    ``J_<obj>_survivors`` (mean over surviving episodes; nan when all fell), non_dominated_survivors.
    """
    names = sweep.objective_names
    m = len(names)
    pairs = [(i, j) for i in range(m) for j in range(i + 1, m)]
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(
        ["motion", "sample"]
        + [f"w_{n}" for n in names]
        + [f"J_{n}" for n in names]
        + [f"J_{n}_std" for n in names]
        + ["survival", "non_dominated"]
        + [f"nd_{names[i]}_{names[j]}" for i, j in pairs]
        + [f"J_{n}_survivors" for n in names]
        + ["non_dominated_survivors"]
    )
    for grp in sweep.groups:
        s = grp.summary
        for k in range(sweep.weights.shape[0]):
            writer.writerow(
                [grp.motion, k]
                + [repr(float(v)) for v in sweep.weights[k]]
                + [repr(float(v)) for v in grp.points[k]]
                + [repr(float(v)) for v in grp.points_std[k]]
                + [repr(float(grp.survival[k])), int(s.non_dominated[k])]
                + [int(s.pairwise[p][k]) for p in pairs]
                + [repr(float(v)) for v in grp.survivor_points[k]]
                + [int(grp.survivors.non_dominated[k])]
            )
        writer.writerow(
            [grp.motion, "equal"]
            + [repr(1.0 / m)] * m
            + [repr(float(v)) for v in grp.equal_point]
            + [""] * m
            + ["", ""]
            + [""] * len(pairs)
            + [""] * (m + 1)
        )
    return buf.getvalue()


def parse_reference_point(text: str, names: Sequence[str]) -> np.ndarray:
    """Parse ``--ref-point``: m comma-separated numbers in objective order, or ``name=value`` for
    every objective (``up=0,lo=0,...``). Returns [m] float64.

    Raises:
        AmorError: wrong count, an unknown or missing name, or a value that is not a finite number.
    """
    parts = [p.strip() for p in text.split(",") if p.strip()]
    m = len(names)
    values: dict[str, float] = {}
    named = any("=" in p for p in parts)
    for pos, part in enumerate(parts):
        if named:
            key, sep, value = (s.strip() for s in part.partition("="))
            if not sep or key not in names:
                raise AmorError(
                    f"--ref-point: {part!r} is not objective=value (objectives: {', '.join(names)})"
                )
        else:
            if len(parts) != m:
                raise AmorError(f"--ref-point needs {m} numbers ({', '.join(names)}), got {len(parts)}")
            key, value = names[pos], part
        try:
            number = float(value)
        except ValueError:
            raise AmorError(f"--ref-point: {key}={value!r} is not a number") from None
        if not math.isfinite(number):
            raise AmorError(f"--ref-point: {key}={value} is not finite")
        values[key] = number
    missing = [n for n in names if n not in values]
    if missing:
        raise AmorError(f"--ref-point: no value for {', '.join(missing)}")
    return np.array([values[n] for n in names], dtype=np.float64)
