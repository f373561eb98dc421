"""Figures of ``amorctl pareto`` (the paper's Fig. 4), ``amorctl evaluate --sweep`` (Fig. 6) and
``amorctl tune`` (w(t) over the rewards, the teaser / Fig. 7).

matplotlib with the non-interactive Agg backend (works headless); files are written atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amorctl.core.files import atomic_path

if TYPE_CHECKING:
    from amorctl.tune.session import TuneRollout


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, paths: list[Path]) -> None:
    for path in paths:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format=path.suffix.lstrip(".").lower(), dpi=110, bbox_inches="tight")


def pareto_figure(sweep: Any, paths: list[Path]) -> None:
    """Pairwise panels of objectives like the paper's Fig. 4, saved to every path (PNG, SVG).

    Panel (row j-1, column i) for objectives i < j plots objective i (x) against j (y): one colour
    per motion, points non-dominated in that panel's two objectives outlined in black, the
    equal-weights (1/m) policy marked with a cross. With two objectives it is one panel.

    Args:
        sweep: an :class:`amorctl.analysis.sweeps.ParetoSweep`.
        paths: output files; the format follows the suffix.
    """
    plt = _pyplot()
    names = sweep.objective_names
    m = len(names)
    cells = max(1, m - 1)
    size = 2.4 if m > 2 else 4.5
    fig, axes = plt.subplots(cells, cells, figsize=(size * cells, size * cells), squeeze=False)
    colours = plt.get_cmap("tab10").colors
    for row in range(cells):
        for col in range(cells):
            ax = axes[row][col]
            i, j = col, row + 1
            if m < 2 or i >= j:
                ax.set_visible(False)
                continue
            for gi, grp in enumerate(sweep.groups):
                c = colours[gi % len(colours)]
                pts = grp.points
                nd = grp.summary.pairwise.get((i, j), np.zeros(len(pts), dtype=bool))
                ax.scatter(pts[~nd, i], pts[~nd, j], s=9, color=c, alpha=0.55, linewidths=0)
                ax.scatter(
                    pts[nd, i], pts[nd, j], s=18, color=c, edgecolors="black", linewidths=0.8,
                    label=grp.motion if (row, col) == (0, 0) else None,
                )  # fmt: skip
                ax.scatter(
                    [grp.equal_point[i]], [grp.equal_point[j]], marker="x", s=70, color=c, linewidths=2.0,
                )  # fmt: skip
            if row == cells - 1:
                ax.set_xlabel(names[i])
            if col == 0:
                ax.set_ylabel(names[j])
            ax.tick_params(labelsize=7)
    handles, labels = axes[0][0].get_legend_handles_labels()
    from matplotlib.lines import Line2D

    handles.append(Line2D([], [], marker="x", color="black", linestyle="", markersize=8, markeredgewidth=2))
    labels.append("equal weights (1/m), motion's colour")
    if m <= 2:
        axes[0][0].legend(handles, labels, fontsize=8, loc="best")
    else:  # the empty upper-right triangle holds the legend
        fig.subplots_adjust(top=0.95)
        fig.legend(handles, labels, loc="upper right", bbox_to_anchor=(0.98, 0.93), fontsize=9, frameon=False)
    k = sweep.weights.shape[0]
    fig.suptitle(
        f"Pareto front: {k} weight vectors ({sweep.sampling}), {sweep.episodes} episode(s) each; "
        "outlined: non-dominated in the panel's pair",
        fontsize=9,
    )
    _save(fig, paths)
    plt.close(fig)


def sweep_figure(sweep: Any, path: Path) -> None:
    """The distribution of one objective's unweighted return per weight level (the paper's Fig. 6).

    Violins with the individual episodes jittered on top and the Spearman correlation in the title.

    Args:
        sweep: an :class:`amorctl.analysis.sweeps.WeightSweep`.
        path: output file (PNG or SVG by suffix).
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    data = [r[np.isfinite(r)] for r in sweep.returns]
    pos = np.arange(len(data))
    usable = [d if len(d) else np.array([np.nan]) for d in data]
    if all(len(d) > 1 and np.ptp(d) > 0 for d in data):
        ax.violinplot(usable, positions=pos, showmeans=True, widths=0.8)
    else:
        ax.boxplot(usable, positions=pos, widths=0.5)
    rng = np.random.default_rng(0)
    for p, d in zip(pos, data, strict=True):
        ax.scatter(p + rng.uniform(-0.12, 0.12, len(d)), d, s=6, color="black", alpha=0.5)
    ax.set_xticks(pos, [f"{lv:.2f}" for lv in sweep.levels])
    ax.set_xlabel(f"weight of {sweep.objective} (others share the rest equally)")
    ax.set_ylabel(f"unweighted cumulative {sweep.objective} reward")
    ax.set_title(
        f"{sweep.objective}: Spearman ρ = {sweep.spearman_rho:.3f} (p = {sweep.spearman_p:.2g})", fontsize=10
    )
    _save(fig, [path])
    plt.close(fig)


def plot_rollout(rollout: TuneRollout, path: str | Path, title: str = "") -> None:
    """PNG of w(t) as stacked areas (top) over the per-objective rewards r_i(t) (bottom), atomically.

    The paper's teaser / Fig. 7 style: the colour of an objective is the same in both panels, so
    a reader sees which reward moves when its weight does.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = rollout.objective_names
    colors = plt.get_cmap("tab10")(np.arange(len(names)) % 10)
    fig, (ax_w, ax_r) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True, height_ratios=[1, 1.4])
    t = rollout.times
    ax_w.stackplot(t, rollout.weights.T, labels=list(names), colors=colors, step="post", alpha=0.9)
    ax_w.set_ylim(0, 1)
    ax_w.set_ylabel("weights w(t)")
    ax_w.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    for i, name in enumerate(names):
        ax_r.plot(t, rollout.rewards[:, i], color=colors[i], lw=1.2, label=name)
    ax_r.set_ylabel("reward r_i(t)")
    ax_r.set_xlabel("time (s)")
    for tt in t[rollout.terminated]:
        ax_r.axvline(tt, color="k", ls=":", lw=1)
    ax_w.set_title(title or f"amorctl tune — {rollout.motion or 'run'}")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)
