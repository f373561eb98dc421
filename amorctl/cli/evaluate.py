"""``amorctl evaluate``: tracking error, survival and returns of a run under chosen weights (Table 2),
weight sweeps of one objective (Fig. 6), and videos."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.table import Table

from amorctl.analysis.eval_env import check_objective, make_eval_env
from amorctl.analysis.rollout import WeightsSource, rollout
from amorctl.analysis.sweep_ranks import weight_sweep_ranks
from amorctl.analysis.sweeps import DEFAULT_SWEEP_LEVELS
from amorctl.analysis.tracking_metrics import EvalResult, evaluate_setting
from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, print_json
from amorctl.cli.pareto import MotionOpt, rollout_progress
from amorctl.core.contracts import tracking_view
from amorctl.core.errors import AmorError
from amorctl.core.schedule import Schedule, load_schedule
from amorctl.core.vecenv import close_env
from amorctl.core.weights import parse_weights
from amorctl.train import distributed
from amorctl.train.rundir import RunDir

ROWS = (
    ("joint MAE (deg)", "joint_mae_deg", ".2f"),
    ("  up", "joint_mae_deg/up", ".2f"),
    ("  lo", "joint_mae_deg/lo", ".2f"),
    ("  feet", "joint_mae_deg/feet", ".2f"),
    ("MPJPE end effectors (mm)", "mpjpe_mm", ".1f"),
    ("survival rate", "survival_rate", ".1%"),
    ("episode length (s)", "episode_length_s", ".2f"),
)


def _fmt(value: Any, spec: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return format(value, spec)


def _settings(
    names: tuple[str, ...], weights: str | None, schedule: Schedule | None, compare: bool
) -> list[tuple[str, WeightsSource]]:
    uniform = np.full(len(names), 1.0 / len(names))
    given: list[tuple[str, WeightsSource]] = []
    if weights is not None:
        given.append(("weights", parse_weights(weights, names, source="--weights")))
    if schedule is not None:
        given.append(("schedule", schedule))
    if compare:
        return [("uniform", uniform), *given]
    if len(given) > 1:
        raise AmorError("give --weights or --schedule, not both (or add --compare to see them side by side)")
    return given or [("uniform", uniform)]


def _parse_levels(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise AmorError(f"--levels: {text!r} is not a comma-separated list of numbers") from None


def _table(results: list[EvalResult], names: tuple[str, ...]) -> Table:
    table = Table(title="Tracking performance (returns unscaled)")
    table.add_column("metric")
    for r in results:
        table.add_column(f"{r.label}\n[dim]{r.weights}[/dim]", justify="right")
    for label, key, spec in ROWS:
        if all(r.metrics.get(key) is None for r in results):
            continue
        table.add_row(label, *(_fmt(r.metrics.get(key), spec) for r in results))
    for name in names:
        table.add_row(
            f"return {name}",
            *(
                f"{_fmt(r.metrics[f'return/{name}'], '.2f')} ± {_fmt(r.metrics[f'return_std/{name}'], '.2f')}"
                for r in results
            ),
        )
    return table


def _video(
    path: Path,
    policy: Any,
    config: Any,
    source: WeightsSource,
    motions: list[str] | None,
    seconds: float,
    seed: int,
) -> dict[str, Any]:
    """Roll out one env for one episode (at most ``seconds``) and render it with ghost and weights."""
    from amorctl.outputs.video import render_video

    if config.env.kind != "tracking":
        raise AmorError(f"--video needs a motion-tracking run; this run's env is {config.env.kind!r}")
    env, _ = make_eval_env(config, 1, motions=motions[:1] if motions else None, seed=seed)
    try:
        view = tracking_view(env)
        if view is None:
            raise AmorError("--video: this run's env has no motion to render")
        steps = max(1, round(seconds / view.dt))
        ro = rollout(policy, env, source, episodes=1, seed=seed, max_steps=steps, record_qpos=True)
        assert ro.qpos is not None and ro.frame_index is not None and ro.weights is not None
        info = render_video(
            path,
            view.character.name,
            ro.qpos[:, 0],
            ref_qpos=view.reference_qpos(ro.frame_index[:, 0]),
            weights=ro.weights[:, 0],
            objective_names=ro.objective_names,
            fps=1.0 / view.dt,
        )
    finally:
        close_env(env)
    return {
        "path": str(info.path),
        "frames": info.frames,
        "width": info.width,
        "height": info.height,
        "fps": info.fps,
        "gl_backend": info.gl_backend,
    }


def evaluate(
    run: Annotated[Path, typer.Argument(help="Run directory written by `amorctl train`.")],
    weights: Annotated[
        str | None,
        typer.Option("--weights", "-w", help="Weights, e.g. up=1,smooth=0.5 (normalized; others 0)."),
    ] = None,
    schedule: Annotated[
        Path | None, typer.Option("--schedule", help="Weight schedule file w(t) (TOML, docs/schedules.md).")
    ] = None,
    motion: MotionOpt = None,
    episodes: Annotated[int, typer.Option("--episodes", "-e", help="Episodes per setting (and motion).")] = 8,
    compare: Annotated[
        bool, typer.Option("--compare", help="Side by side: uniform, --weights, --schedule (Table 2).")
    ] = False,
    sweep: Annotated[
        str | None,
        typer.Option("--sweep", help="Sweep this objective's weight (others share the rest): Fig. 6 plot."),
    ] = None,
    levels: Annotated[
        str, typer.Option("--levels", help="Sweep levels of the weight, comma-separated (at least 3).")
    ] = ",".join(str(v) for v in DEFAULT_SWEEP_LEVELS),
    video: Annotated[
        Path | None,
        typer.Option("--video", help="Render an MP4: the character, the reference ghost, the weights."),
    ] = None,
    video_seconds: Annotated[float, typer.Option("--video-seconds", help="Length of the video.")] = 10.0,
    per_joint: Annotated[
        bool,
        typer.Option("--per-joint", help="Also each joint's error: MAE, mean offset (bias), 95th pct."),
    ] = False,
    out: Annotated[
        Path | None, typer.Option("--out", help="Directory for the sweep figure (default RUN/evaluate).")
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the episodes' starts.")] = 0,
    data: Annotated[
        Path | None,
        typer.Option(
            "--data", help="Held-out motion dataset to run on (clips re-encoded with the run's VAE)."
        ),
    ] = None,
    hlp: Annotated[
        list[Path] | None,
        typer.Option(
            "--hlp", help="HLP directory: Table 2 rows beside uniform, needs --compare (docs/hlp.md)."
        ),
    ] = None,
    hlp_envs: Annotated[int, typer.Option("--hlp-envs", help="Table 2: episodes per row.")] = 16,
    hlp_seconds: Annotated[float, typer.Option("--hlp-seconds", help="Table 2: seconds per episode.")] = 10.0,
    disc_steps: Annotated[
        int, typer.Option("--disc-steps", help="Table 2: training steps of the evaluation discriminator.")
    ] = 300,
    json_out: JsonFlag = False,
) -> None:
    """Joint MAE, MPJPE, survival, episode length and returns per weight setting."""
    if episodes < 1:
        raise AmorError(f"--episodes must be >= 1, got {episodes}")
    if video is not None and video.suffix.lower() != ".mp4":
        raise AmorError(f"--video {video}: the file must end in .mp4")
    if hlp:  # Table 2 with the high-level policy (amorctl.hlp.eval_discriminator)
        from amorctl.cli.hlp import evaluate_hlp

        others = {"--schedule": schedule, "--sweep": sweep, "--video": video}
        evaluate_hlp(
            run,
            hlp,
            weights,
            motion,
            compare,
            hlp_envs,
            hlp_seconds,
            disc_steps,
            seed,
            json_out,
            others,
            data,
        )
        return
    opened = RunDir.open(run)
    config = opened.config_for_data(data)  # the run's dataset, moved or held-out clips
    policy = opened.policy()
    for flag, given in (("--video", video is not None), ("--per-joint", per_joint)):
        if given and config.env.kind != "tracking":
            raise AmorError(f"{flag} needs a motion-tracking run; this run's env is {config.env.kind!r}")
    names = tuple(policy.objectives)
    sched = load_schedule(schedule, names) if schedule is not None else None
    settings = _settings(names, weights, sched, compare)
    sweep_levels = _parse_levels(levels) if sweep is not None else []
    if sweep is not None:
        check_objective(sweep, names)
    quiet = distributed.launched_rank() != 0  # under torchrun: rank 0 alone evaluates the settings
    show = not json_out and not quiet and console.is_terminal
    sweep_doc = None
    if sweep is not None:  # first, while every torchrun rank takes part (docs/distributed.md)
        figure = (out if out is not None else opened.output_dir("evaluate")) / f"sweep-{sweep}.png"
        sweep_doc = _sweep(policy, config, sweep, sweep_levels, motion, episodes, seed, figure, show)
    if quiet:
        return

    results = _evaluate_settings(policy, config, settings, motion, episodes, seed, show, per_joint)
    video_doc = None
    if video is not None:
        video_doc = _video(video, policy, config, settings[-1][1], motion, video_seconds, seed)

    doc = {
        "run": str(run),
        "objectives": list(names),
        "episodes": episodes,
        "motions": list(motion or []),
        "settings": [
            {
                "label": r.label,
                "weights": r.weights,
                "episodes": r.episodes,
                "metrics": r.metrics,
                "per_motion": r.per_motion,
                "per_joint": r.per_joint,
            }
            for r in results
        ],
        "sweep": sweep_doc,
        "video": video_doc,
    }
    if json_out:
        print_json(doc)
        return
    _print_report(doc, results, names)


def _evaluate_settings(
    policy: Any,
    config: Any,
    settings: list[tuple[str, WeightsSource]],
    motions: list[str] | None,
    episodes: int,
    seed: int,
    show: bool,
    per_joint: bool = False,
) -> list[EvalResult]:
    """One :class:`EvalResult` per ``(label, weight source)`` of ``settings``, in order, each with a
    progress bar when ``show`` (and its per-joint errors with ``per_joint``)."""
    results: list[EvalResult] = []
    for label, source in settings:
        with rollout_progress(show, f"evaluate {label}") as on_step:
            result = evaluate_setting(
                policy,
                config,
                source,
                label=label,
                motions=motions,
                episodes=episodes,
                seed=seed,
                on_step=on_step,
                per_joint=per_joint,
            )
        results.append(result)
    return results


def _sweep(
    policy: Any,
    config: Any,
    objective: str,
    levels: list[float],
    motions: list[str] | None,
    episodes: int,
    seed: int,
    figure: Path,
    show: bool,
) -> dict[str, Any] | None:
    """Run the weight sweep of ``objective`` (its episodes split over torchrun's ranks), draw its
    figure; the ``sweep`` part of the JSON (None on ranks other than 0)."""
    from amorctl.outputs.plots import sweep_figure

    with distributed.session() as world, rollout_progress(show, f"sweep {objective}") as on_step:
        ws = weight_sweep_ranks(
            policy,
            config,
            objective,
            levels=levels,
            motions=motions,
            episodes=episodes,
            seed=seed,
            on_step=on_step,
            world=world,
        )
    if ws is None:
        return None
    sweep_figure(ws, figure)
    return {**ws.to_dict(), "figure": str(figure)}


def _joint_table(results: list[EvalResult]) -> Table:
    """Per-joint MAE and bias (degrees) of each setting, the first setting's worst joint first."""
    table = Table(title="Error per joint (deg)")
    table.add_column("joint")
    for r in results:
        table.add_column(f"MAE\n[dim]{r.label}[/dim]", justify="right")
        table.add_column(f"bias\n[dim]{r.label}[/dim]", justify="right")
    first = results[0].per_joint
    for joint in sorted(first, key=lambda j: -first[j]["mae_deg"]):
        cells: list[str] = []
        for r in results:
            error = r.per_joint[joint]
            cells += [f"{error['mae_deg']:.2f}", f"{error['bias_deg']:+.2f}"]
        table.add_row(joint, *cells)
    return table


def _print_report(doc: dict[str, Any], results: list[EvalResult], names: tuple[str, ...]) -> None:
    """The metrics table (and the per-joint one), then the sweep's and the video's one-line summaries."""
    console.print(_table(results, names))
    if results and results[0].per_joint:
        console.print(_joint_table(results))
    sweep_doc, video_doc = doc["sweep"], doc["video"]
    if sweep_doc is not None:
        means = ", ".join(
            f"{lv:.2f}: {_fmt(mu, '.2f')}"
            for lv, mu in zip(sweep_doc["levels"], sweep_doc["mean"], strict=True)
        )
        console.print(
            f"sweep of {sweep_doc['objective']}: mean return per weight level {means}\n"
            f"Spearman rank correlation (weight vs return): ρ = {_fmt(sweep_doc['spearman_rho'], '.3f')} "
            f"(p = {_fmt(sweep_doc['spearman_p'], '.2g')}) · figure: {sweep_doc['figure']}",
            highlight=False,
            soft_wrap=True,
        )
    if video_doc is not None:
        console.print(
            f"video: {video_doc['path']} ({video_doc['frames']} frames, MUJOCO_GL={video_doc['gl_backend']})",
            highlight=False,
        )
