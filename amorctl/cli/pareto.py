"""``amorctl pareto``: the trade-off front of a trained run over sampled weights (the paper's Fig. 4)."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import typer
from rich import box
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from amorctl.analysis.eval_env import sweep_weights
from amorctl.analysis.sweep_ranks import pareto_sweep_ranks
from amorctl.analysis.sweeps import (
    pareto_csv,
    pareto_to_dict,
    parse_reference_point,
)
from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, err_console, print_json
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_text
from amorctl.train import distributed
from amorctl.train.rundir import RunDir

MotionOpt = Annotated[
    list[str] | None,
    typer.Option("--motion", "-m", help="Motion (clip) name; repeat for several, one front and colour each."),
]


@contextlib.contextmanager
def rollout_progress(enabled: bool, what: str) -> Iterator[Any]:
    """A rich progress bar on stderr fed by ``on_step(done, cap)``; yields the callback or None."""
    if not enabled:
        yield None
        return
    with Progress(
        TextColumn(f"{what}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} steps"),
        TimeElapsedColumn(),
        console=err_console,
        transient=True,
    ) as bar:
        task = bar.add_task(what, total=None)

        def on_step(done: int, cap: int) -> None:
            bar.update(task, completed=done, total=cap)

        yield on_step


def pareto(
    run: Annotated[Path, typer.Argument(help="Run directory of `amorctl train`, or pretrained:NAME.")],
    motion: MotionOpt = None,
    samples: Annotated[
        int, typer.Option("--samples", "-k", help="K weight vectors drawn from Dirichlet(1).")
    ] = 128,
    episodes: Annotated[int, typer.Option("--episodes", "-e", help="Episodes per weight vector.")] = 1,
    grid: Annotated[
        int | None,
        typer.Option(
            "--grid", help="Use the uniform simplex grid with this many divisions instead of K samples."
        ),
    ] = None,
    ref_point: Annotated[
        str | None,
        typer.Option(
            "--ref-point",
            help="Hypervolume reference: m numbers in objective order or up=..,lo=..,... "
            "(default: per motion, min - 10% of the range per objective).",
        ),
    ] = None,
    hv_method: Annotated[
        str, typer.Option("--hv-method", help="Hypervolume: auto | exact | monte_carlo.")
    ] = "auto",
    seed: Annotated[int, typer.Option("--seed", help="Seed of the weight samples and of the episodes.")] = 0,
    out: Annotated[Path | None, typer.Option("--out", help="Output directory (default RUN/pareto).")] = None,
    data: Annotated[
        Path | None,
        typer.Option(
            "--data", help="Held-out motion dataset to run on (clips re-encoded with the run's VAE)."
        ),
    ] = None,
    coverage: Annotated[
        bool,
        typer.Option(
            "--coverage",
            help="Instead of the front: predicted vs achieved scalarized return and training episodes "
            "per simplex region (K weights spread evenly over the regions; docs/pareto.md).",
        ),
    ] = False,
    json_out: JsonFlag = False,
) -> None:
    """Sample K weight vectors, evaluate all in one batched rollout, and report the Pareto front."""
    if hv_method not in ("auto", "exact", "monte_carlo"):
        raise AmorError(f"--hv-method must be auto, exact or monte_carlo, got {hv_method!r}")
    if episodes < 1:
        raise AmorError(f"--episodes must be >= 1, got {episodes}")
    opened = RunDir.open(run)
    config = opened.config_for_data(data)  # the run's dataset, moved or held-out clips
    policy = opened.policy()
    if coverage:  # weight coverage of the simplex (amorctl.cli.pareto_coverage)
        from amorctl.cli.pareto_coverage import coverage_command

        coverage_command(opened, policy, config, motion, samples, grid, seed, out, json_out)
        return
    names = tuple(policy.objectives)
    weights, sampling = sweep_weights(len(names), samples, grid=grid, seed=seed)
    reference = parse_reference_point(ref_point, names) if ref_point is not None else None
    out_dir = out if out is not None else opened.output_dir("pareto")  # pretrained: ./NAME/pareto
    quiet = distributed.launched_rank() != 0  # under torchrun rank 0 alone prints and writes
    show = not json_out and not quiet and console.is_terminal
    if not json_out and not quiet:
        console.print(
            f"[bold]amorctl pareto[/bold] {run} · {len(weights)} weight vectors ({sampling}) × "
            f"{episodes} episode(s) · {len(motion or []) or 'random'} motion(s)",
            highlight=False,
        )
    with distributed.session() as world, rollout_progress(show, "rollout") as on_step:
        sweep = pareto_sweep_ranks(  # the weight rows split over torchrun's ranks (docs/distributed.md)
            policy,
            config,
            weights,
            motions=motion,
            episodes=episodes,
            reference_point=reference,
            hv_method=hv_method,
            seed=seed,
            sampling=sampling,
            on_step=on_step,
            world=world,  # type: ignore[arg-type]
        )
    if sweep is None:  # not rank 0: rank 0 writes the files
        return

    from amorctl.outputs.plots import pareto_figure

    files = {s: str(out_dir / f"pareto.{s}") for s in ("json", "csv", "png", "svg")}
    doc = {"run": opened.label, **pareto_to_dict(sweep, files)}
    pareto_figure(sweep, [Path(files["png"]), Path(files["svg"])])
    atomic_write_text(files["csv"], pareto_csv(sweep))
    atomic_write_text(files["json"], json.dumps(doc, indent=2) + "\n")
    if json_out:
        print_json(doc)
        return
    _print_summary(doc, files)


def _survivor_cells(sv: dict[str, Any]) -> tuple[str, str, str]:
    """Survivors, their front's hypervolume and non-dominated fraction (the same reference point)."""
    total = sv["count"] + sv["fallen"]
    if sv["hypervolume"] is None:
        return f"0/{total}", "–", "–"
    return (
        f"{sv['count']}/{total}",
        f"{sv['hypervolume']['value']:.4g}",
        f"{sv['non_dominated_fraction']:.1%}",
    )


def _print_summary(doc: dict[str, Any], files: dict[str, str]) -> None:
    """The front metrics per motion as a table, then timing and where the files are."""
    table = Table(
        title="Pareto front (objectives maximized; returns unscaled)",
        caption="ND: non-dominated fraction · HV: hypervolume (4 digits; full values in the JSON)",
        box=box.SIMPLE_HEAD,
        pad_edge=False,
    )
    cols = ("motion", "points", "ND", "HV", "method", "EUM", "sparsity", "survived", "HV surv.", "ND surv.")
    for col in cols:
        table.add_column(col, justify="left" if col in ("motion", "method") else "right", overflow="fold")
    for grp in doc["motions"]:
        hv = grp["hypervolume"]
        method = hv["method"] if hv["method"] == "exact" else f"MC, {hv['confidence']:.0%} CI ±"
        method += "" if hv["method"] == "exact" else f"{(hv['ci_high'] - hv['ci_low']) / 2:.4g}"
        table.add_row(
            grp["motion"],
            str(len(grp["points"])),
            f"{grp['non_dominated_fraction']:.1%}",
            f"{hv['value']:.4g}",
            method,
            f"{grp['expected_utility']:.4g}",
            f"{grp['sparsity']:.4g}",
            *_survivor_cells(grp["survivors"]),
        )
    console.print(table)
    t = doc["timing"]
    console.print(
        f"{t['num_envs']} envs, {t['env_steps']:,} env steps in {t['seconds']:.1f} s · "
        f"reference point: {doc['reference_point_rule']}\n"
        f"figure: {files['png']} (and .svg) · numbers: {files['json']}, {files['csv']}",
        highlight=False,
        soft_wrap=True,
    )
