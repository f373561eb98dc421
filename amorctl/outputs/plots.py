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


def _survivor_limits(sweep: Any, i: int, j: int) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """Axis limits (x, y) spanning every motion's surviving points in objectives i, j (5% margin);
    None when no weight vector survived anywhere."""
    rows = [g.survivor_points[g.survivors.survived][:, [i, j]] for g in sweep.groups]
    rows += [g.equal_point[None, [i, j]] for g in sweep.groups if g.equal_survival > 0]
    pts = np.vstack(rows) if rows else np.zeros((0, 2))
    if len(pts) == 0:
        return None
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = np.where(hi > lo, 0.05 * (hi - lo), np.maximum(np.abs(lo) * 0.05, 1e-3))
    return (lo[0] - pad[0], hi[0] + pad[0]), (lo[1] - pad[1], hi[1] + pad[1])


def pareto_figure(sweep: Any, paths: list[Path]) -> None:
    """Pairwise panels of objectives like the paper's Fig. 4, zoomed on the survivors, saved to every path.

    Panel (row j-1, column i) for objectives i < j plots objective i (x) against j (y), one colour
    per motion. Each weight vector with a surviving episode is a dot at its mean over the surviving
    episodes; dots non-dominated among the survivors in that panel's two objectives are outlined in
    black. The axes span the survivors only: a fall ends the episode early and drags every return
    down, so weight vectors whose episodes all fell are drawn apart, as grey triangles pinned to the
    panel's lower-left edge, and counted in the legend. The equal-weights (1/m) policy is a cross
    (inside the zoom when one of its episodes survived, else pinned like the fallen). Without any
    survivor the panels show every point, unzoomed. With two objectives it is one panel.

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
    k = sweep.weights.shape[0]
    fallen = sum(int((~g.survivors.survived).sum()) for g in sweep.groups)
    total = k * len(sweep.groups)
    for row in range(cells):
        for col in range(cells):
            ax = axes[row][col]
            i, j = col, row + 1
            if m < 2 or i >= j:
                ax.set_visible(False)
                continue
            limits = _survivor_limits(sweep, i, j)
            for gi, grp in enumerate(sweep.groups):
                label = grp.motion if (row, col) == (0, 0) else None
                _pareto_panel(ax, grp, i, j, colours[gi % len(colours)], limits, label)
            if limits is not None:
                ax.set_xlim(*limits[0])
                ax.set_ylim(*limits[1])
            if row == cells - 1:
                ax.set_xlabel(names[i])
            if col == 0:
                ax.set_ylabel(names[j])
            ax.tick_params(labelsize=7)
    handles, labels = axes[0][0].get_legend_handles_labels()
    from matplotlib.lines import Line2D

    handles.append(Line2D([], [], marker="x", color="black", linestyle="", markersize=8, markeredgewidth=2))
    labels.append("equal weights (1/m), motion's colour")
    handles.append(Line2D([], [], marker="v", color="0.45", linestyle="", markersize=7))
    where = "pinned to the lower-left edge" if fallen < total else "no survivor: drawn as dots"
    labels.append(f"fell in every episode: {fallen} of {total} ({where})")
    if m <= 2:
        axes[0][0].legend(handles, labels, fontsize=8, loc="best")
    else:  # the empty upper-right triangle holds the legend
        fig.subplots_adjust(top=0.95)
        fig.legend(handles, labels, loc="upper right", bbox_to_anchor=(0.98, 0.93), fontsize=9, frameon=False)
    zoom = "axes span the survivors" if fallen < total else "no survivor: all points, unzoomed"
    among = "survivors" if fallen < total else "all points"
    fig.suptitle(
        f"Pareto front: {k} weight vectors ({sweep.sampling}), {sweep.episodes} episode(s) each; "
        f"{total - fallen} of {total} survived, {fallen} fell; {zoom}; "
        f"outlined: non-dominated among {among} in the panel's pair",
        fontsize=9,
    )
    _save(fig, paths)
    plt.close(fig)


def _pareto_panel(ax: Any, grp: Any, i: int, j: int, colour: Any, limits: Any, label: str | None) -> None:
    """One motion's dots in panel (i, j): survivors (outlined if non-dominated), fallen, equal weights."""
    alive = grp.survivors.survived
    if limits is None:  # nobody survived: the old view over all points
        pts, nd = grp.points, grp.summary.pairwise.get((i, j), np.zeros(len(grp.points), dtype=bool))
    else:
        pts = grp.survivor_points[alive]
        sub = grp.survivors.summary
        none = np.zeros(len(pts), dtype=bool)
        nd = sub.pairwise.get((i, j), none) if sub is not None else none
    ax.scatter(pts[~nd, i], pts[~nd, j], s=9, color=colour, alpha=0.55, linewidths=0)
    ax.scatter(pts[nd, i], pts[nd, j], s=18, color=colour, edgecolors="black", linewidths=0.8, label=label)
    eq = np.asarray(grp.equal_point, dtype=np.float64)[[i, j]]
    if limits is None:
        ax.scatter([eq[0]], [eq[1]], marker="x", s=70, color=colour, linewidths=2.0)
        return
    (x0, x1), (y0, y1) = limits
    pinned = np.clip(eq, [x0, y0], [x1, y1])
    if np.all(np.isfinite(pinned)):
        ax.scatter([pinned[0]], [pinned[1]], marker="x", s=70, color=colour, linewidths=2.0, clip_on=False)
    gone = grp.points[~alive][:, [i, j]]
    if len(gone):
        gone = np.clip(np.nan_to_num(gone, nan=-np.inf), [x0, y0], [x1, y1])
        ax.scatter(gone[:, 0], gone[:, 1], marker="v", s=16, color="0.45", alpha=0.7, clip_on=False)


def coverage_figure(doc: dict[str, Any], paths: list[Path]) -> None:
    """``amorctl pareto --coverage``: predicted vs achieved per sample, and per region the gap and
    the training episodes (docs/pareto.md, "Weight coverage"), saved to every path.

    Left: each sample's critic prediction ``w . V(s_0)`` (x) against its achieved discounted
    scalarized return (y), coloured by dominant objective, fallen episodes as crosses, the line
    y = x. Middle: regions as a grid (rows: dominant objective, columns: bin of its weight), colour
    the relative gap (achieved - predicted) / |predicted| (red: underdelivers), each cell annotated
    with its value and samples (colours saturate at +-50 %). Right: the same grid coloured by the
    run's training episodes per region (share of all), or a note when the run did not log them.

    Args:
        doc: :func:`amorctl.analysis.coverage.coverage_to_dict`'s document.
        paths: output files; the format follows the suffix.
    """
    plt = _pyplot()
    names = doc["objectives"]
    m = len(names)
    rows = doc["regions"]
    bins = [r["bin"] for r in rows[: len(rows) // m]]
    fig, axes = plt.subplots(1, 3, figsize=(15, 0.45 * m + 3.2), width_ratios=[1.2, 1, 1])
    ax = axes[0]
    ps = doc["per_sample"]
    pred, ach = np.asarray(ps["predicted"]), np.asarray(ps["achieved"])
    region, alive = np.asarray(ps["region"]), np.asarray(ps["survived"], dtype=bool)
    colours = plt.get_cmap("tab10")(np.arange(m) % 10)
    dom = region // (len(rows) // m)
    for k in range(m):
        sel = dom == k
        ax.scatter(pred[sel & alive], ach[sel & alive], s=14, color=colours[k], label=names[k], alpha=0.8)
        ax.scatter(pred[sel & ~alive], ach[sel & ~alive], s=22, color=colours[k], marker="x")
    lo, hi = float(min(pred.min(), ach.min())), float(max(pred.max(), ach.max()))
    ax.plot([lo, hi], [lo, hi], color="black", lw=0.8, ls="--")
    ax.set_xlabel("predicted: w · V(s0) (critic)")
    ax.set_ylabel(f"achieved: discounted w · return (γ = {doc['gamma']:g})")
    ax.legend(fontsize=7, title="dominant objective (x: fell)", title_fontsize=7, loc="best")
    corr = doc["overall"]["correlation"]
    ax.set_title(f"{doc['samples']} samples · corr {'–' if corr is None else f'{corr:.2f}'}", fontsize=9)

    def grid(key: str) -> np.ndarray:
        vals = [np.nan if r[key] is None or not r["feasible"] else r[key] for r in rows]
        return np.asarray(vals, dtype=np.float64).reshape(m, len(bins))

    gap = grid("relative_gap")
    # colours saturate at +-50 % so one runaway cell does not wash out the others (values are printed)
    bound = min(max(float(np.nanmax(np.abs(gap))), 0.05), 0.5) if np.isfinite(gap).any() else 0.5
    im = axes[1].imshow(gap, cmap="RdBu", vmin=-bound, vmax=bound, aspect="auto")
    fig.colorbar(im, ax=axes[1], fraction=0.046, label="(achieved − predicted) / |predicted|")
    share = grid("training_share")
    if doc["training_logged"]:
        im2 = axes[2].imshow(share, cmap="viridis", aspect="auto")
        fig.colorbar(im2, ax=axes[2], fraction=0.046, label="share of training episodes")
    else:
        axes[2].imshow(np.full_like(share, np.nan), aspect="auto")
        axes[2].text(
            0.5,
            0.5,
            "training weights not logged\n(run predates wcount/ columns)",
            ha="center",
            va="center",
            transform=axes[2].transAxes,
            fontsize=9,
        )
    for ax2, title in ((axes[1], "gap per region (samples)"), (axes[2], "training episodes per region")):
        ax2.set_xticks(range(len(bins)), bins, fontsize=7)
        ax2.set_yticks(range(m), names, fontsize=7)
        ax2.set_xlabel("weight of the dominant objective")
        ax2.set_title(title, fontsize=9)
    for idx, r in enumerate(rows):
        i, j = divmod(idx, len(bins))
        if r["feasible"]:
            rel = "–" if r["relative_gap"] is None else f"{r['relative_gap']:+.0%}"
            axes[1].text(j, i, f"{rel}\n({r['samples']})", ha="center", va="center", fontsize=6)
            if r["training_episodes"] is not None:
                axes[2].text(
                    j, i, f"{r['training_episodes']:,}", ha="center", va="center", fontsize=6, color="w"
                )
    fig.tight_layout()
    _save(fig, paths)
    plt.close(fig)


def sweep_figure(sweep: Any, path: Path) -> None:
    """The distribution of one objective's unweighted return per weight level (the paper's Fig. 6).

    Violins with the individual episodes jittered on top and the Spearman correlation in the title.

    Args:
        sweep: an :class:`amorctl.analysis.level_sweep.WeightSweep`.
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
