"""Evaluate a trained run: Pareto sweeps over weights, tracking metrics, weight sweeps.

The library behind ``amorctl pareto`` and ``amorctl evaluate`` (docs/pareto.md, docs/evaluate.md).
Everything runs batched: a sweep over K weight vectors is one :func:`amorctl.analysis.rollout.rollout`
with one weight vector per environment. Nothing here prints.

Shapes: K = weight vectors, G = motion groups, E = episodes per weight, m = objectives.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.analysis.front import FrontSummary, HypervolumeMethod, summarize_front
from amorctl.analysis.rollout import Rollout, WeightsSource, rollout, tracking_env
from amorctl.core.config import TrainConfig
from amorctl.core.contracts import Policy
from amorctl.core.errors import AmorError
from amorctl.core.schedule import Schedule
from amorctl.core.vecenv import VectorEnv
from amorctl.core.weights import format_weights
from amorctl.envs.factory import make_env
from amorctl.motion.resolve import resolve_name
from amorctl.train.rundir import RunDir

ALL_MOTIONS = "all"  # the group name when no --motion is given (episodes draw clips at random)
JOINT_GROUP_LABELS = {"upper": "up", "lower": "lo", "feet": "feet"}
DEFAULT_SWEEP_LEVELS = (0.0, 0.25, 0.5, 0.75, 1.0)

Progress = Callable[[int, int], None]


# ---------------------------------------------------------------------------- run and env
def open_run(run: Path) -> tuple[Policy, TrainConfig]:
    """The newest checkpoint's policy and the config of the run in ``run`` (see :class:`RunDir`)."""
    opened = RunDir.open(run)
    return opened.policy(), opened.config


def check_objective(name: str, names: Sequence[str]) -> int:
    """Index of objective ``name``; AmorError listing the objectives when unknown."""
    if name not in names:
        raise AmorError(f"unknown objective {name!r}; the run's objectives are {', '.join(names)}")
    return list(names).index(name)


def make_eval_env(
    config: TrainConfig,
    num_envs: int,
    *,
    motions: Sequence[str] | None = None,
    env_motion: np.ndarray | None = None,
    seed: int = 0,
) -> tuple[VectorEnv, list[str]]:
    """The run's env sized to ``num_envs``, optionally restricted to named motions.

    Args:
        config: the run's config.
        num_envs: N.
        motions: motion (clip) names as the user typed them; resolved against the run's dataset.
        env_motion: [N] index into ``motions`` per env: each env always tracks that motion.
            Without it, episodes draw among ``motions`` at random.
        seed: the env's seed.

    Returns:
        (env, resolved motion names; ``[ALL_MOTIONS]`` when ``motions`` is empty).

    Raises:
        AmorError: motions for a run without motions (toy, gym), or an unknown motion name.
    """
    if num_envs < 1:
        raise AmorError(f"need at least one environment, got {num_envs}")
    if motions and config.env.kind != "tracking":
        raise AmorError(f"--motion needs a motion-tracking run; this run's env is {config.env.kind!r}")
    cfg = dataclasses.replace(
        config,
        env=dataclasses.replace(config.env, num_envs=int(num_envs)),
        run=dataclasses.replace(config.run, seed=int(seed)),
    )
    env = make_env(cfg)
    if not motions:
        return env, [ALL_MOTIONS]
    inner = tracking_env(env)
    try:
        if inner is None:
            raise AmorError("--motion: this run's env has no motion library")
        clip_names = [c.name for c in inner.library.clips]
        where = f"the run's {inner.library.character} dataset"
        resolved = [resolve_name(q, clip_names, where) for q in motions]
        indices = np.array([clip_names.index(r) for r in resolved], dtype=np.int64)
        if env_motion is None:
            inner.select_clips(clips=indices)
        else:
            inner.select_clips(env_clips=indices[np.asarray(env_motion, dtype=np.int64)])
    except BaseException:
        _close(env)
        raise
    return env, resolved


def _close(env: Any) -> None:
    close = getattr(env, "close", None)
    if callable(close):
        close()


def sample_weights(
    m: int, samples: int | None = None, *, grid: int | None = None, seed: int = 0
) -> tuple[np.ndarray, str]:
    """The K weight vectors of a sweep: Dirichlet(1) samples, or a uniform simplex grid.

    Returns:
        ([K, m] float64 rows on the simplex, a description such as ``"dirichlet(1)"``).

    Raises:
        AmorError: ``samples < 1`` or ``grid < 1``.
    """
    from amorctl.core.weights import sample_dirichlet, simplex_grid

    if grid is not None:
        if grid < 1:
            raise AmorError(f"--grid must be >= 1 divisions, got {grid}")
        return simplex_grid(m, grid), f"simplex grid ({grid} divisions)"
    k = 64 if samples is None else samples
    if k < 1:
        raise AmorError(f"--samples must be >= 1, got {k}")
    w = sample_dirichlet(np.random.default_rng(seed), k, m).astype(np.float64)
    return w / w.sum(axis=1, keepdims=True), "dirichlet(1)"


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
    """

    motion: str
    points: np.ndarray
    points_std: np.ndarray
    survival: np.ndarray
    equal_point: np.ndarray
    summary: FrontSummary


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
) -> ParetoSweep:
    """Evaluate ``policy`` under every weight vector in ONE batched rollout and summarize the fronts.

    Envs: for each motion group g, each weight k (the K given plus the equal-weights 1/m vector)
    and each episode e, one env (index ``(g * (K + 1) + k) * E + e``) running one episode.

    Args:
        policy: ``policy(obs [N, D]) -> actions [N, A]``.
        config: the run's config.
        weights: [K, m] rows on the simplex.
        motions: motion names (one front per motion); None: one front over random clips.
        episodes: E episodes per weight vector.
        reference_point: [m] hypervolume reference (for every group); None: the default rule of
            :func:`amorctl.analysis.front.default_reference_point`, per group.
        hv_method: ``auto`` | ``exact`` | ``monte_carlo``.
        seed: env seed (RSI, clip draws).
        sampling: how ``weights`` were made (reported).
        on_step: progress callback (steps done, step cap).

    Raises:
        AmorError: bad weights, episodes < 1, unknown motion, reference point of the wrong length.
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 2 or w.shape[0] < 1:
        raise AmorError(f"need at least one weight vector, got shape {w.shape}")
    if episodes < 1:
        raise AmorError(f"--episodes must be >= 1, got {episodes}")
    k, m = w.shape
    groups = list(motions) if motions else []
    g = max(1, len(groups))
    all_w = np.vstack([w, np.full((1, m), 1.0 / m)])  # [K+1, m]
    per_group = (k + 1) * episodes
    n = g * per_group
    env_motion = np.repeat(np.arange(g), per_group) if groups else None
    env, names = make_eval_env(config, n, motions=groups or None, env_motion=env_motion, seed=seed)
    try:
        obj_names = tuple(env.reward_space.names)
        if len(obj_names) != m:
            raise AmorError(f"weights have {m} entries; the run has {len(obj_names)} objectives")
        if reference_point is not None and len(reference_point) != m:
            raise AmorError(
                f"--ref-point needs {m} values ({', '.join(obj_names)}), got {len(reference_point)}"
            )
        env_w = np.tile(np.repeat(all_w, episodes, axis=0), (g, 1))  # [N, m]
        began = time.perf_counter()
        result = rollout(policy, env, env_w, episodes=1, seed=seed, record_steps=False, on_step=on_step)
        seconds = time.perf_counter() - began
        steps = int(result.episodes.length.sum())
        limit = int(getattr(tracking_env(env) or env, "max_episode_steps", 0) or getattr(env, "max_steps", 0))
    finally:
        _close(env)

    eps = result.episodes
    returns = np.full((n, m), np.nan)
    returns[eps.env] = eps.returns
    survived = np.zeros(n)
    survived[eps.env] = eps.survived
    returns = returns.reshape(g, k + 1, episodes, m)
    survived = survived.reshape(g, k + 1, episodes)
    out_groups = []
    for gi in range(g):
        pts = returns[gi, :k].mean(axis=1)
        summary = summarize_front(pts, w, reference_point, hv_method=hv_method, seed=seed)
        out_groups.append(
            ParetoGroup(
                motion=names[gi] if groups else ALL_MOTIONS,
                points=pts,
                points_std=returns[gi, :k].std(axis=1),
                survival=survived[gi, :k].mean(axis=1),
                equal_point=returns[gi, k].mean(axis=0),
                summary=summary,
            )
        )
    rule = (
        "given (--ref-point)"
        if reference_point is not None
        else "per motion: min - 0.1 * (max - min) per objective (analysis.front.default_reference_point)"
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


def _floats(a: np.ndarray) -> list[Any]:
    """A JSON-ready nested list (NaN/inf become None)."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 0:
        v = float(arr)
        return v if math.isfinite(v) else None  # type: ignore[return-value]
    return [_floats(x) for x in arr]


def pareto_to_dict(sweep: ParetoSweep, files: dict[str, str] | None = None) -> dict[str, Any]:
    """The JSON document of a sweep (schema: docs/pareto.md, :data:`PARETO_JSON_SCHEMA`)."""
    names = sweep.objective_names
    groups = []
    for grp in sweep.groups:
        s = grp.summary
        groups.append(
            {
                "motion": grp.motion,
                "points": _floats(grp.points),
                "points_std": _floats(grp.points_std),
                "survival": _floats(grp.survival),
                "equal_weights_point": _floats(grp.equal_point),
                "non_dominated": [bool(v) for v in s.non_dominated],
                "pairwise_non_dominated": {
                    f"{names[i]}/{names[j]}": [bool(v) for v in mask] for (i, j), mask in s.pairwise.items()
                },
                "non_dominated_fraction": s.non_dominated_fraction,
                "hypervolume": s.hypervolume.to_dict(),
                "expected_utility": s.expected_utility,
                "sparsity": s.sparsity,
            }
        )
    return {
        "objectives": list(names),
        "weights": _floats(sweep.weights),
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
    unscaled return), ``J_<obj>_std``, survival, non_dominated, ``nd_<a>_<b>`` per objective pair.
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
            )
        writer.writerow(
            [grp.motion, "equal"]
            + [repr(1.0 / m)] * m
            + [repr(float(v)) for v in grp.equal_point]
            + [""] * m
            + ["", ""]
            + [""] * len(pairs)
        )
    return buf.getvalue()


# ---------------------------------------------------------------------------- tracking metrics
@dataclass
class EvalResult:
    """Metrics of one weight setting (a row of the Table 2-like comparison).

    Attributes:
        label: ``uniform``, ``weights``, ``schedule``, or a sweep level.
        weights: a description of the weights (``up=0.5,...`` or the schedule file).
        episodes: episodes evaluated.
        metrics: joint MAE in degrees (``joint_mae_deg`` total and ``joint_mae_deg/<group>`` for
            up / lo / feet), ``mpjpe_mm`` (end effectors), ``survival_rate``,
            ``episode_length_steps`` / ``episode_length_s`` (means), ``return/<objective>`` and
            ``return_std/<objective>`` (unscaled cumulative rewards). Tracking metrics are None
            for envs without a reference motion.
        per_motion: the same metrics per motion when motions were named.
    """

    label: str
    weights: str
    episodes: int
    metrics: dict[str, float | None]
    per_motion: dict[str, dict[str, float | None]] = field(default_factory=dict)


def tracking_metrics(
    ro: Rollout, groups: dict[str, np.ndarray] | None = None, env_mask: np.ndarray | None = None
) -> dict[str, float | None]:
    """Metrics of the finished episodes of ``ro`` (optionally only envs in ``env_mask`` [N]).

    Joint MAE (degrees) and MPJPE (mm) are means over every valid step of finished episodes (and
    over joints / end effectors): ``mean |q - q_ref|`` and ``mean ||p - p_ref||`` with p the
    end-effector positions relative to the root in its heading frame (root-aligned MPJPE).

    Args:
        ro: a rollout with per-step arrays.
        groups: {label: joint indices [j]} for per-group MAE (e.g. up / lo / feet).
        env_mask: [N] bool, envs to include (default all).
    """
    eps = ro.episodes
    n = ro.valid.shape[1]
    mask = np.ones(n, dtype=bool) if env_mask is None else np.asarray(env_mask, dtype=bool)
    sel = mask[eps.env]
    names = ro.objective_names
    out: dict[str, float | None] = {}
    count = int(sel.sum())
    if count == 0:
        raise AmorError("no episode finished; raise --episodes or the step limit")
    out["episodes"] = float(count)
    out["survival_rate"] = float(eps.survived[sel].mean())
    out["episode_length_steps"] = float(eps.length[sel].mean())
    out["episode_length_s"] = float(eps.length[sel].mean() * ro.dt)
    for i, name in enumerate(names):
        out[f"return/{name}"] = float(eps.returns[sel, i].mean())
        out[f"return_std/{name}"] = float(eps.returns[sel, i].std())
    step_mask = (ro.episode_id >= 0) & ro.valid & mask[None, :]  # [T, N]
    if ro.joint_pos is None or ro.ref_joint_pos is None or ro.ee_pos is None or ro.ref_ee_pos is None:
        out["joint_mae_deg"] = None
        out["mpjpe_mm"] = None
        for label in groups or {}:
            out[f"joint_mae_deg/{label}"] = None
        return out
    err = np.abs(ro.joint_pos[step_mask] - ro.ref_joint_pos[step_mask])  # [S, J] rad
    out["joint_mae_deg"] = float(np.degrees(err.mean())) if err.size else None
    for label, idx in (groups or {}).items():
        idx = np.asarray(idx, dtype=np.int64)
        out[f"joint_mae_deg/{label}"] = (
            float(np.degrees(err[:, idx].mean())) if len(idx) and err.size else None
        )
    dist = np.linalg.norm(ro.ee_pos[step_mask] - ro.ref_ee_pos[step_mask], axis=-1)  # [S, E] m
    out["mpjpe_mm"] = float(1000.0 * dist.mean()) if dist.size else None
    return out


def joint_groups(env: Any) -> dict[str, np.ndarray]:
    """{up, lo, feet: joint indices} of a tracking env's character ({} for other envs)."""
    inner = tracking_env(env)
    if inner is None:
        return {}
    ch = inner.character
    return {label: np.array(ch.group_indices(group)) for group, label in JOINT_GROUP_LABELS.items()}


def describe_weights(source: WeightsSource, names: Sequence[str]) -> str:
    """A short text for a weight source: ``up=0.5,...``, ``schedule <file>`` or ``per env``."""
    if isinstance(source, Schedule):
        return f"schedule {source.source}"
    if callable(source):
        return "time-varying"
    w = np.asarray(source, dtype=np.float64)
    return format_weights(w, names) if w.ndim == 1 else "per env"


def evaluate_setting(
    policy: Any,
    config: TrainConfig,
    weights: WeightsSource,
    *,
    label: str,
    motions: Sequence[str] | None = None,
    episodes: int = 8,
    seed: int = 0,
    on_step: Progress | None = None,
) -> EvalResult:
    """Evaluate one weight setting over ``episodes`` episodes per motion, in one batched rollout.

    Each of the N = E (or E per named motion) envs runs one episode from a reference-state
    initialization; the seed fixes the starts, so settings evaluated with one seed are compared
    on the same starts.

    Raises:
        AmorError: episodes < 1, an unknown motion, bad weights.
    """
    if episodes < 1:
        raise AmorError(f"--episodes must be >= 1, got {episodes}")
    g = len(motions) if motions else 1
    env_motion = np.repeat(np.arange(g), episodes) if motions else None
    env, resolved = make_eval_env(config, g * episodes, motions=motions, env_motion=env_motion, seed=seed)
    try:
        names = tuple(env.reward_space.names)
        ro = rollout(policy, env, weights, episodes=1, seed=seed, on_step=on_step)
        groups = joint_groups(env)
    finally:
        _close(env)
    metrics = tracking_metrics(ro, groups)
    per_motion: dict[str, dict[str, float | None]] = {}
    if motions and env_motion is not None:
        for gi, name in enumerate(resolved):
            per_motion[name] = tracking_metrics(ro, groups, env_motion == gi)
    return EvalResult(label, describe_weights(weights, names), episodes, metrics, per_motion)


# ---------------------------------------------------------------------------- weight sweep (Fig. 6)
@dataclass
class WeightSweep:
    """Returns of one objective at several levels of its weight (the paper's Fig. 6).

    Attributes:
        objective: the swept objective's name.
        levels: [L] its weight at each level (the others share ``1 - level`` equally).
        returns: [L, E] its unweighted cumulative reward per episode.
        survival: [L] survival rate per level.
        spearman_rho, spearman_p: rank correlation between weight and return over all L * E
            episodes, and its p-value (NaN when undefined, e.g. all returns equal).
    """

    objective: str
    levels: np.ndarray
    returns: np.ndarray
    survival: np.ndarray
    spearman_rho: float
    spearman_p: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "objective": self.objective,
            "levels": _floats(self.levels),
            "returns": _floats(self.returns),
            "mean": _floats(np.nanmean(self.returns, axis=1)),
            "survival": _floats(self.survival),
            "spearman_rho": _floats(np.float64(self.spearman_rho)),
            "spearman_p": _floats(np.float64(self.spearman_p)),
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
) -> WeightSweep:
    """Sweep one objective's weight over ``levels`` in one batched rollout (L * E envs).

    Raises:
        AmorError: unknown objective, fewer than 3 levels, episodes < 1, unknown motion.
    """
    from scipy import stats

    if episodes < 1:
        raise AmorError(f"--episodes must be >= 1, got {episodes}")
    names = tuple(policy.objectives)
    idx = check_objective(objective, names)
    w = sweep_levels_weights(idx, len(names), levels)
    n_lv = w.shape[0]
    n = n_lv * episodes
    env, _ = make_eval_env(config, n, motions=motions, seed=seed)
    try:
        ro = rollout(
            policy,
            env,
            np.repeat(w, episodes, axis=0),
            episodes=1,
            seed=seed,
            record_steps=False,
            on_step=on_step,
        )
    finally:
        _close(env)
    eps = ro.episodes
    returns = np.full(n, np.nan)
    returns[eps.env] = eps.returns[:, idx]
    survived = np.zeros(n)
    survived[eps.env] = eps.survived
    returns = returns.reshape(n_lv, episodes)
    level_of = np.repeat(w[:, idx], episodes)
    ok = np.isfinite(returns.ravel())
    rho, p = math.nan, math.nan
    if ok.sum() >= 3 and np.ptp(returns.ravel()[ok]) > 0:
        res = stats.spearmanr(level_of[ok], returns.ravel()[ok])
        rho, p = float(res.statistic), float(res.pvalue)
    return WeightSweep(objective, w[:, idx], returns, survived.reshape(n_lv, episodes).mean(axis=1), rho, p)


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
