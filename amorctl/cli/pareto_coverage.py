"""``amorctl pareto RUN --coverage``: weight coverage of the simplex (docs/pareto.md, "Weight coverage")."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rich.table import Table

from amorctl.analysis.coverage import coverage, coverage_to_dict, stratified_weights
from amorctl.cli.output import console, print_json
from amorctl.core.config import TrainConfig
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_text
from amorctl.core.weights import simplex_grid
from amorctl.train import distributed
from amorctl.train.rundir import RunDir


def coverage_command(
    run: RunDir,
    policy: Any,
    config: TrainConfig,
    motion: list[str] | None,
    samples: int,
    grid: int | None,
    seed: int,
    out: Path | None,
    json_out: bool,
) -> None:
    """Evaluate K weight vectors (spread over the regions, or ``--grid``), write coverage.{json,png,svg}."""
    if distributed.launched_rank() != 0:
        return  # one process is enough: the coverage rollout is small and not split over ranks
    m = len(policy.objectives)
    if grid is not None:
        if grid < 1:
            raise AmorError(f"--grid must be >= 1, got {grid}")
        weights = simplex_grid(m, grid)
    else:
        weights = stratified_weights(m, samples, seed=seed)
    out_dir = out if out is not None else run.output_dir("pareto")
    if not json_out:
        console.print(
            f"[bold]amorctl pareto --coverage[/bold] {run.label} · {len(weights)} weight vectors "
            f"({'simplex grid' if grid is not None else 'spread over the regions'}), one episode each",
            highlight=False,
        )
    cov = coverage(policy, config, weights, motions=motion, seed=seed, metrics_path=run.metrics_path)
    files = {s: str(out_dir / f"coverage.{s}") for s in ("json", "png", "svg")}
    doc = {"run": run.label, **coverage_to_dict(cov, files)}
    from amorctl.outputs.plots import coverage_figure

    coverage_figure(doc, [Path(files["png"]), Path(files["svg"])])
    atomic_write_text(files["json"], json.dumps(doc, indent=2) + "\n")
    if json_out:
        print_json(doc)
        return
    _print(doc, files)


def _fmt(value: float | None, spec: str) -> str:
    return "–" if value is None else format(value, spec)


def _print(doc: dict[str, Any], files: dict[str, str]) -> None:
    table = Table(title="Weight coverage per region (dominant objective : its weight)")
    for col in ("region", "samples", "predicted", "achieved", "gap", "rel. gap", "survival", "train eps"):
        left = col == "region"
        table.add_column(col, justify="left" if left else "right", no_wrap=left, overflow="fold")
    for r in doc["regions"]:
        if not r["feasible"]:
            continue
        table.add_row(
            r["region"],
            str(r["samples"]),
            _fmt(r["predicted"], ".4g"),
            _fmt(r["achieved"], ".4g"),
            _fmt(r["gap"], "+.3g"),
            _fmt(r["relative_gap"], "+.1%"),
            _fmt(r["survival"], ".0%"),
            "–" if r["training_episodes"] is None else f"{r['training_episodes']:,}",
        )
    console.print(table)
    o = doc["overall"]
    logged = "" if doc["training_logged"] else " · the run did not log its training weights (no wcount/)"
    console.print(
        f"overall: predicted {o['predicted_mean']:.4g}, achieved {o['achieved_mean']:.4g}, mean |gap| "
        f"{o['mean_abs_gap']:.4g}, correlation {_fmt(o['correlation'], '.3f')}, survival {o['survival']:.0%}"
        f"{logged}\nfigure: {files['png']} (and .svg) · numbers: {files['json']}",
        highlight=False,
        soft_wrap=True,
    )
