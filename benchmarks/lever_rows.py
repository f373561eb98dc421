"""One lever a row: tracking runs trained with and without a lever, compared at equal env steps.

Each ``--run LABEL=DIR`` is a run directory (a stage's working copy, ``runs/stages/NAME``, or any
tracking run); ``LABEL=DIR@ITERATION`` takes that run as it was at one of its checkpoints (its
learning curve up to there), so one long run gives rows at several budgets. For each, the newest
(or the named) checkpoint is evaluated under uniform ``w`` on every clip of
its dataset (``--episodes`` per clip, seed ``--seed``, deterministic policy; survival over full
episodes and joint MAE, as ``benchmarks/stage.py`` evaluates a stage), and its training curve is
read from ``metrics.csv``. Prints two markdown tables (per run: env steps, wall clock, the
training episode length at the end, clips with survival >= 90 %, mean survival and MAE; per clip:
survival / MAE of each run, ``—`` where a run's dataset lacks the clip, e.g. a run trained on
some clips with ``stage.py --clips``) and writes a figure of the training curves against env steps
(``--figure``; every 10th iteration of each run, the rows a shipped entry keeps).

    python benchmarks/lever_rows.py --run plain=runs/levers/plain/work/biped20-repertoire \\
        --run adaptive=runs/levers/adaptive/work/biped20-repertoire --figure docs/img/levers.png
    python benchmarks/lever_rows.py --run early=runs/stages/NAME@1800 --run late=runs/stages/NAME
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from science_runs import metrics_rows, trained_wall_s
from stage import evaluate_clips, write_figure

from amorctl.train.pretrained_export import METRICS_EVERY
from amorctl.train.rundir import RunDir

CURVES = (("episode/length", "training episode length (steps)"), ("return/scalarized", "return · w"))
WINDOW = 25  # iterations the end-of-training figures average over


def row(label: str, run_dir: Path, episodes: int, seed: int, iteration: int | None = None) -> dict[str, Any]:
    """The run's evaluation per clip and its training figures, at the checkpoint of ``iteration``
    (None: the newest) and its learning curve up to there."""
    run = RunDir.open(run_dir)
    ckpt = run.checkpoint(iteration)
    rows = [r for r in metrics_rows(run_dir) if float(r["iteration"]) <= ckpt.iteration]
    metrics = {k: np.array([float(r[k]) if r.get(k) else np.nan for r in rows]) for k in rows[0]}
    clips = evaluate_clips(run, episodes, seed, ckpt.iteration)
    return {
        "label": label,
        "env_steps": int(ckpt.trainer.meta["env_steps"]),
        "wall_s": trained_wall_s(rows),
        "episode_length": recent_mean(metrics["episode/length"], metrics["iteration"]),
        "clips": clips,
        "metrics": metrics,
    }


def recent_mean(values: np.ndarray, iterations: np.ndarray) -> float:
    """Mean of ``values`` [R] over the rows of the last WINDOW iterations (a shipped entry's
    metrics.csv keeps every 10th row of them); NaN where none is finite (no episode ended yet)."""
    recent = values[iterations > iterations[-1] - WINDOW]
    recent = recent[np.isfinite(recent)]
    return float(recent.mean()) if recent.size else float("nan")


def markdown(rows: list[dict[str, Any]]) -> str:
    """Two tables: one line per run (totals), then one line per clip (survival / MAE per run)."""
    lines = [
        "| run | env steps | wall clock | train episode length | clips ≥ 90 % | mean survival | mean MAE |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        surv = [e["survival"] for e in r["clips"].values()]
        mae = [e["joint_mae_deg"] for e in r["clips"].values()]
        lines.append(
            f"| {r['label']} | {r['env_steps'] / 1e6:.2f} M | {r['wall_s'] / 60:.0f} min | "
            f"{r['episode_length']:.0f} | {sum(s >= 0.9 for s in surv)} of {len(surv)} | "
            f"{np.mean(surv):.0%} | {np.mean(mae):.1f}° |"
        )
    lines += ["", "| clip |" + "".join(f" {r['label']} |" for r in rows), "| --- |" + " --- |" * len(rows)]
    for clip in dict.fromkeys(c for r in rows for c in r["clips"]):  # runs may train on different clips
        cells = "".join(f" {cell(r['clips'].get(clip))} |" for r in rows)
        lines.append(f"| {clip} |{cells}")
    return "\n".join(lines)


def cell(result: dict[str, float] | None) -> str:
    """``survival / MAE`` of one clip, or ``—`` for a clip the run's dataset does not hold."""
    return "—" if result is None else f"{result['survival']:.0%} / {result['joint_mae_deg']:.1f}°"


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(CURVES), figsize=(5.5 * len(CURVES), 3.8))
    for ax, (key, title) in zip(axes, CURVES, strict=True):
        for r in rows:
            m = r["metrics"]
            keep = m["iteration"] % METRICS_EVERY == 0  # the rows a shipped entry keeps: one sampling for all
            ax.plot(m["env_steps"][keep] / 1e6, m[key][keep], label=r["label"], lw=1)
        ax.set(xlabel="env steps (M)", title=title)
        ax.grid(alpha=0.3)
    axes[0].legend()
    write_figure(fig, path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--run", action="append", required=True, metavar="LABEL=DIR[@ITERATION]")
    parser.add_argument("--episodes", type=int, default=8, help="evaluation episodes per clip")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--figure", default="", help="PNG of the training curves")
    args = parser.parse_args(argv)
    rows = []
    for spec in args.run:
        label, _, place = spec.partition("=")
        folder, at, iteration = place.partition("@")
        if not folder or (at and not iteration.isdigit()):
            parser.error(f"--run {spec!r}: write LABEL=DIR or LABEL=DIR@ITERATION")
        if not (Path(folder) / "metrics.csv").is_file():
            parser.error(f"--run {spec!r}: {folder} is not a run directory (no metrics.csv)")
        rows.append(row(label, Path(folder), args.episodes, args.seed, int(iteration) if at else None))
    print(markdown(rows))
    if args.figure:
        plot(rows, Path(args.figure))
        print(f"figure: {args.figure}")


if __name__ == "__main__":
    main()
