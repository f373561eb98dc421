"""The measurements of ``benchmarks/science.py``: each takes a trained policy and the
run's config and returns a JSON-ready dict. Rollouts go through the library
(:mod:`amorctl.analysis`), exactly as ``amorctl evaluate --sweep`` and ``amorctl pareto`` do.

Shapes: K = weight vectors, L = sweep levels, E = episodes, m = objectives.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from science_report import hv_reference, level_stats

from amorctl.analysis.eval_env import episode_limit, make_eval_env, sweep_weights
from amorctl.analysis.front import hypervolume, non_dominated_fraction
from amorctl.analysis.level_sweep import weight_sweep
from amorctl.analysis.rollout import rollout
from amorctl.analysis.sweeps import DEFAULT_SWEEP_LEVELS, pareto_sweep
from amorctl.analysis.tracking_metrics import evaluate_setting
from amorctl.core.config import TrainConfig
from amorctl.core.vecenv import close_env
from amorctl.core.weights import format_weights, parse_weights


def _limit_steps(config: TrainConfig) -> int:
    env, _ = make_eval_env(config, 1)
    try:
        return episode_limit(env)
    finally:
        close_env(env)


def survivors_rho(levels: np.ndarray, returns: np.ndarray, survived: np.ndarray | None) -> float | None:
    """Spearman ρ(w_k, return_k) over the episodes that survived (a diagnostic beside the issue's
    ρ over all episodes: it shows the trade-off among robots that stay up, apart from where they
    fell). levels [L], returns and survived [L, E]; None when fewer than 3 survivors or no spread."""
    from scipy import stats

    if survived is None:
        return None
    x = np.repeat(np.asarray(levels, dtype=np.float64), returns.shape[1])[survived.ravel()]
    y = np.asarray(returns, dtype=np.float64).ravel()[survived.ravel()]
    if len(y) < 3 or np.ptp(y) == 0 or np.ptp(x) == 0:
        return None
    return float(stats.spearmanr(x, y).statistic)


def measure_sweeps(
    policy: Any,
    config: TrainConfig,
    *,
    episodes: int,
    seed: int,
    levels: Sequence[float] = DEFAULT_SWEEP_LEVELS,
    motions: Sequence[str] | None = None,
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Claim (ii): ``weight_sweep`` (what ``evaluate --sweep`` reports) for every objective, with
    the smooth sweep's action rate and joint-velocity RMS on the same episodes. ``motions``: the
    clips episodes draw from (None: every clip of the run's dataset).

    Returns:
        (results dict, {objective: returns [L, E]} for the figure).
    """
    began = time.perf_counter()
    names = tuple(policy.objectives)
    out: dict[str, Any] = {}
    raw: dict[str, np.ndarray] = {}
    smooth_sweeps: list[dict[str, Any]] = []
    for name in names:
        ws = weight_sweep(policy, config, name, levels=levels, episodes=episodes, seed=seed, motions=motions)
        if name == "smooth" and ws.motion is not None:  # the same episodes' action rate, joint speed
            smooth_sweeps.append(ws.motion.to_dict())
        stats = level_stats(ws.levels, ws.returns, ws.survival)
        stats["spearman_rho"] = None if np.isnan(ws.spearman_rho) else float(ws.spearman_rho)
        stats["spearman_p"] = None if np.isnan(ws.spearman_p) else float(ws.spearman_p)
        stats["spearman_rho_survivors"] = survivors_rho(ws.levels, ws.returns, ws.survived)
        out[name] = stats
        raw[name] = ws.returns
        print(
            f"  sweep {name:>6}: means {' '.join(f'{v:.1f}' for v in stats['mean'])}  "
            f"rho {stats['spearman_rho']} (survivors {stats['spearman_rho_survivors']})  "
            f"monotonic {stats['monotonic']}  effect {stats['effect_size']}  "
            f"survival {' '.join(f'{v:.2f}' for v in stats['survival'])}",
            flush=True,
        )
    result: dict[str, Any] = {
        "levels": [float(v) for v in levels],
        "episodes": episodes,
        "seed": seed,
        "objectives": out,
    }
    if smooth_sweeps:
        result["smooth_motion"] = smooth_sweeps[0]
        sm = result["smooth_motion"]
        print(
            f"  smooth sweep: action rate {' '.join(f'{v:.4g}' for v in sm['action_rate'])} "
            f"(falls: {sm['action_rate_falls']}); joint-velocity RMS "
            f"{' '.join(f'{v:.4g}' for v in sm['joint_vel_rms'])} (falls: {sm['joint_vel_rms_falls']})",
            flush=True,
        )
    result["seconds"] = time.perf_counter() - began
    return result, raw


def measure_front(
    policy: Any, config: TrainConfig, *, samples: int, seed: int, motion: str = "walk"
) -> dict[str, Any]:
    """Claim (i): ``samples`` Dirichlet(1) weights, one episode each on ``motion``; non-dominated
    fraction and hypervolume (fixed reference, :func:`science_report.hv_reference`) on all
    episodes and on the survivors only."""
    names = tuple(policy.objectives)
    m = len(names)
    steps = _limit_steps(config)
    ref = hv_reference(m, steps, names.index("smooth") if "smooth" in names else None)
    w, sampling = sweep_weights(m, samples, seed=seed)
    sweep = pareto_sweep(
        policy, config, w, motions=[motion], episodes=1, reference_point=ref, seed=seed, sampling=sampling
    )
    grp = sweep.groups[0]
    scale = float(steps) ** m
    survived = grp.survival >= 1.0

    def part(points: np.ndarray) -> dict[str, Any]:
        if len(points) == 0:
            return {
                "count": 0,
                "non_dominated_fraction": None,
                "hypervolume": {"value": 0.0, "method": "exact"},
            }
        hv = hypervolume(points, ref).to_dict()
        for key in ("value", "ci_low", "ci_high"):
            hv[key] = hv[key] / scale
        return {
            "count": len(points),
            "non_dominated_fraction": non_dominated_fraction(points),
            "hypervolume": hv,
        }

    out = {
        "samples": samples,
        "seed": seed,
        "motion": grp.motion,
        "objectives": list(names),
        "reference_point": [float(v) for v in ref],
        "hv_scale": float(steps),
        "survival_rate": float(grp.survival.mean()),
        "all": part(grp.points),
        "survivors": part(grp.points[survived]),
        "equal_weights_point": [float(v) for v in grp.equal_point],
        "seconds": sweep.seconds,
        "env_steps": sweep.env_steps,
    }
    print(
        f"  front on {grp.motion}: survival {out['survival_rate']:.3f}; non-dominated all "
        f"{out['all']['non_dominated_fraction']}, survivors {out['survivors']['non_dominated_fraction']} "
        f"({out['survivors']['count']} survivors); "
        f"HV (normalized) all {out['all']['hypervolume']['value']:.4g}, "
        f"survivors {out['survivors']['hypervolume']['value']:.4g}",
        flush=True,
    )
    return out


def tracking_heavy_text(names: Sequence[str]) -> str:
    """The tracking-heavy weights of the learning bar: 0.3 on each joint-position objective (up,
    lo, feet), the remaining 0.1 shared by the others."""
    joints = [n for n in ("up", "lo", "feet") if n in names]
    rest = [n for n in names if n not in joints]
    pairs = [f"{n}=0.3" for n in joints] + [f"{n}={0.1 / max(len(rest), 1):.6g}" for n in rest]
    return ",".join(pairs)


def measure_bar(
    policy: Any, config: TrainConfig, *, episodes: int, seed: int, motions: Sequence[str] | None = None
) -> dict[str, Any]:
    """Learning bar: survival over 10 s under uniform weights; joint MAE under tracking-heavy weights
    vs uniform, on the same starts. ``motions``: ``episodes`` split evenly over these clips (None:
    episodes draw from every clip of the run's dataset)."""
    names = tuple(policy.objectives)
    if motions:
        episodes = max(1, episodes // len(motions))  # evaluate_setting runs this many per motion
    out: dict[str, Any] = {"episodes": episodes * len(motions or [0]), "seed": seed}
    settings = {"uniform": np.full(len(names), 1.0 / len(names))}
    settings["tracking_heavy"] = parse_weights(tracking_heavy_text(names), names)
    for key, w in settings.items():
        res = evaluate_setting(policy, config, w, label=key, motions=motions, episodes=episodes, seed=seed)
        met = res.metrics
        out[key] = {
            "weights": format_weights(w, names),
            "survival_rate": met["survival_rate"],
            "joint_mae_deg": met["joint_mae_deg"],
            "mpjpe_mm": met["mpjpe_mm"],
            "episode_length_s": met["episode_length_s"],
        }
        print(
            f"  bar {key}: survival {met['survival_rate']:.3f}, joint MAE {met['joint_mae_deg']:.2f} deg, "
            f"MPJPE {met['mpjpe_mm']:.1f} mm",
            flush=True,
        )
    return out


def scalarized(policy: Any, config: TrainConfig, weights: np.ndarray, seed: int) -> dict[str, float]:
    """Mean scalarized return ``w_e · J_e`` and survival over one episode per weight row [E, m]."""
    env, _ = make_eval_env(config, weights.shape[0], seed=seed)
    try:
        ro = rollout(policy, env, weights, episodes=1, seed=seed, record_steps=False)
    finally:
        close_env(env)
    eps = ro.episodes
    value = (eps.returns * weights[eps.env]).sum(axis=1)
    return {"return": float(value.mean()), "survival": float(eps.survived.mean()), "episodes": eps.count}


def fixed_points(
    policies: Sequence[Any],
    config: TrainConfig,
    weights: np.ndarray,
    *,
    episodes: int,
    seed: int,
    motion: str,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean returns [K, m] and survival [K] of policy k under weights[k] on ``motion``, E episodes each."""
    pts, surv = [], []
    for pol, w in zip(policies, weights, strict=True):
        sweep = pareto_sweep(pol, config, w[None, :], motions=[motion], episodes=episodes, seed=seed)
        pts.append(sweep.groups[0].points[0])
        surv.append(float(sweep.groups[0].survival[0]))
    return np.asarray(pts), np.asarray(surv)
