"""The figures of benchmarks/science.py: level means per swept objective, MOPPO vs PPO curves."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def _pyplot() -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def plot_sweeps(res: dict[str, Any], raw: dict[str, np.ndarray], path: Path) -> bool:
    plt = _pyplot()
    if plt is None:
        return False
    names = list(res["objectives"])
    cols = 4
    fig, axes = plt.subplots(2, cols, figsize=(14, 6.4))
    levels = np.array(res["levels"])
    for ax, name in zip(axes.flat, names, strict=False):
        s, r = res["objectives"][name], raw[name]
        for i, lv in enumerate(levels):
            ax.scatter(np.full(r.shape[1], lv), r[i], s=6, alpha=0.35, color="tab:blue")
        ax.errorbar(levels, s["mean"], yerr=s["std"], color="k", marker="o", capsize=3)
        ax.set_title(
            f"{name}: ρ {s['spearman_rho'] if s['spearman_rho'] is None else round(s['spearman_rho'], 2)}"
        )
        ax.set_xlabel(f"w_{name}")
        ax.grid(alpha=0.3)
    last = axes.flat[len(names)] if len(names) < 2 * cols else None
    sm = res.get("smooth_motion")
    if last is not None and sm:
        ax2 = last.twinx()
        last.plot(levels, sm["action_rate"], "o-", color="tab:red", label="action rate (rad²)")
        ax2.plot(levels, sm["joint_vel_rms"], "s--", color="tab:green", label="joint vel RMS (rad/s)")
        last.set_title("smooth sweep: motion")
        last.set_xlabel("w_smooth")
        last.legend(loc="upper left", fontsize=7)
        ax2.legend(loc="upper right", fontsize=7)
    fig.suptitle("claim (ii): return of each objective vs its weight (rest equal); dots = episodes")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def plot_curves(rows: list[dict[str, Any]], path: Path, character: str) -> bool:
    plt = _pyplot()
    if plt is None:
        return False
    x = np.array([r["env_steps"] for r in rows]) / 1e6
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for key, label, style in (
        ("ppo_uniform", "PPO (fixed uniform w), at uniform w", "s-"),
        ("moppo_uniform", "MOPPO, at uniform w", "o-"),
        ("moppo_random", "MOPPO, at Dirichlet w", "^--"),
    ):
        axes[0].plot(x, [r[key]["return"] for r in rows], style, label=label)
        axes[1].plot(x, [r[key]["survival"] for r in rows], style, label=label)
    axes[0].set_ylabel("scalarized return w·J (10 s episode)")
    axes[1].set_ylabel("survival over 10 s")
    axes[1].set_ylim(-0.03, 1.03)
    for ax in axes:
        ax.set_xlabel("env steps (millions)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{character} walking: MOPPO vs PPO at equal env steps")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True
