"""Tracking metrics of a run under one weight setting (``amorctl evaluate``, the paper's Table 2).

Joint MAE (per joint group), end-effector MPJPE, survival, episode length and unscaled returns,
from the per-step arrays of a :func:`amorctl.analysis.rollout.rollout`. Nothing here prints.
Definitions: docs/evaluate.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from amorctl.analysis.eval_env import Progress, make_eval_env
from amorctl.analysis.rollout import Rollout, WeightsSource, rollout
from amorctl.core.config import TrainConfig
from amorctl.core.contracts import tracking_view
from amorctl.core.errors import AmorError
from amorctl.core.schedule import Schedule
from amorctl.core.vecenv import close_env
from amorctl.core.weights import format_weights

JOINT_GROUP_LABELS = {"upper": "up", "lower": "lo", "feet": "feet"}


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
        per_joint: with ``per_joint=True``, :func:`joint_errors` over every episode ({} otherwise).
    """

    label: str
    weights: str
    episodes: int
    metrics: dict[str, float | None]
    per_motion: dict[str, dict[str, float | None]] = field(default_factory=dict)
    per_joint: dict[str, dict[str, float]] = field(default_factory=dict)


def counted_steps(ro: Rollout) -> np.ndarray:
    """[T, N] bool: the steps the metrics count (valid steps of episodes that finished)."""
    return (ro.episode_id >= 0) & ro.valid


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
    step_mask = counted_steps(ro) & mask[None, :]  # [T, N]
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


def joint_errors(ro: Rollout, joint_names: Sequence[str]) -> dict[str, dict[str, float]]:
    """Tracking error per actuated joint over every valid step of finished episodes, in degrees.

    Per joint: ``mae_deg`` (mean ``|q - q_ref|``; their mean over joints is ``joint_mae_deg``),
    ``bias_deg`` (mean ``q - q_ref``: a steady offset in the pose rather than lag or noise),
    ``p95_deg`` (95th percentile of ``|q - q_ref|``). Empty without joint angles (non-tracking envs).

    Args:
        ro: a rollout with per-step arrays (``joint_pos``, ``ref_joint_pos`` [T, N, J]).
        joint_names: [J] the character's actuated joints, in action order.
    """
    if ro.joint_pos is None or ro.ref_joint_pos is None:
        return {}
    step_mask = counted_steps(ro)
    diff = np.degrees(ro.joint_pos[step_mask].astype(np.float64) - ro.ref_joint_pos[step_mask])  # [S, J]
    if diff.shape[1] != len(joint_names):
        raise AmorError(f"{diff.shape[1]} joint angles recorded for {len(joint_names)} joint names")
    if not diff.size:
        return {}
    err = np.abs(diff)
    mae, bias, p95 = err.mean(axis=0), diff.mean(axis=0), np.percentile(err, 95, axis=0)
    return {
        name: {"mae_deg": float(mae[j]), "bias_deg": float(bias[j]), "p95_deg": float(p95[j])}
        for j, name in enumerate(joint_names)
    }


def joint_groups(env: Any) -> dict[str, np.ndarray]:
    """{up, lo, feet: joint indices} of a tracking env's character ({} for other envs)."""
    view = tracking_view(env)
    if view is None:
        return {}
    ch = view.character
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
    per_joint: bool = False,
) -> EvalResult:
    """Evaluate one weight setting over ``episodes`` episodes per motion, in one batched rollout.

    Each of the N = E (or E per named motion) envs runs one episode from a reference-state
    initialization; the seed fixes the starts, so settings evaluated with one seed are compared
    on the same starts. ``per_joint`` adds :func:`joint_errors` over all the episodes.

    Raises:
        AmorError: episodes < 1, an unknown motion, bad weights, ``per_joint`` for an env
            without a character.
    """
    if episodes < 1:
        raise AmorError(f"--episodes must be >= 1, got {episodes}")
    g = len(motions) if motions else 1
    env_motion = np.repeat(np.arange(g), episodes) if motions else None
    env, resolved = make_eval_env(config, g * episodes, motions=motions, env_motion=env_motion, seed=seed)
    try:
        names = tuple(env.reward_space.names)
        view = tracking_view(env)
        if per_joint and view is None:
            raise AmorError(f"--per-joint needs a motion-tracking run; this run's env is {config.env.kind!r}")
        ro = rollout(policy, env, weights, episodes=1, seed=seed, on_step=on_step)
        groups = joint_groups(env)
        joints = joint_errors(ro, view.character.joint_names()) if per_joint and view is not None else {}
    finally:
        close_env(env)
    metrics = tracking_metrics(ro, groups)
    per_motion: dict[str, dict[str, float | None]] = {}
    if motions and env_motion is not None:
        for gi, name in enumerate(resolved):
            per_motion[name] = tracking_metrics(ro, groups, env_motion == gi)
    return EvalResult(label, describe_weights(weights, names), episodes, metrics, per_motion, joints)
