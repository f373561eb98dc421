"""``amorctl tune``: run a trained policy with weights chosen now, a weight schedule, or live."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.table import Table

from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, err_console, print_json
from amorctl.core.errors import AmorError
from amorctl.core.live_auth import check_bind


@dataclass(frozen=True)
class TuneRequest:
    """What ``amorctl tune`` was asked for (its options, by name): what the HLP path and the
    output writers read, passed as one object."""

    run: Path
    motion: str | None
    weights: str | None
    schedule: Path | None
    seconds: float | None
    out: Path | None
    plot: Path | None
    video: Path | None
    stop_on_fall: bool
    seed: int
    data: Path | None
    live: bool
    host: str
    port: int
    token: str | None
    save_to: Path
    hlp: Path | None
    scale: str | None
    json: bool

    @property
    def outputs(self) -> list[Path | None]:
        """--out, --plot, --video (None where not given)."""
        return [self.out, self.plot, self.video]


def _check_outputs(paths: list[Path | None]) -> None:
    """Fail before any work if an output's directory is missing or two outputs are the same file."""
    given = [p for p in paths if p is not None]
    if len({p.resolve() for p in given}) != len(given):
        raise AmorError("--out, --plot and --video must name different files")
    for p in given:
        if p.exists() and p.is_dir():
            raise AmorError(f"{p}: is a directory")
        if not p.parent.exists():
            raise AmorError(f"{p}: directory {p.parent} does not exist")


def _segments(rollout: Any, keyframe_times: np.ndarray) -> list[dict[str, Any]]:
    """Mean per-step rewards and action rate between consecutive keyframe times."""
    edges = [0.0, *[float(t) for t in keyframe_times if 0.0 < t < rollout.times[-1] + rollout.dt]]
    edges.append(float(rollout.times[-1] + rollout.dt))
    rate = rollout.action_rate()
    out = []
    for t0, t1 in itertools.pairwise(edges):
        sel = (rollout.times >= t0) & (rollout.times < t1)
        if not sel.any():
            continue
        out.append(
            {
                "t0": t0,
                "t1": t1,
                "steps": int(sel.sum()),
                "mean_reward": dict(
                    zip(rollout.objective_names, rollout.rewards[sel].mean(axis=0).tolist(), strict=True)
                ),
                "mean_action_rate": float(rate[sel].mean()),
            }
        )
    return out


def tune(
    run: Annotated[Path, typer.Argument(help="Run directory (config.toml + checkpoints/).")],
    motion: Annotated[
        str | None, typer.Option("--motion", "-m", help="Clip to track (default: the dataset's first).")
    ] = None,
    weights: Annotated[
        str | None, typer.Option("--weights", "-w", help="Constant weights, e.g. up=1,smooth=2 (normalized).")
    ] = None,
    schedule: Annotated[
        Path | None, typer.Option("--schedule", "-s", help="Weight schedule file (docs/schedules.md).")
    ] = None,
    seconds: Annotated[
        float | None, typer.Option("--seconds", help="Rollout length (default: the motion's duration).")
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Write the rollout log (MCAP).")] = None,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="Write w(t) and rewards over time (PNG).")
    ] = None,
    video: Annotated[Path | None, typer.Option("--video", help="Render the rollout (MP4).")] = None,
    stop_on_fall: Annotated[
        bool,
        typer.Option(
            "--stop-on-fall/--no-stop-on-fall", help="End at a fall, or restart the motion and go on."
        ),
    ] = True,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the env.")] = 0,
    data: Annotated[
        Path | None,
        typer.Option(
            "--data", help="Held-out motion dataset to run on (clips re-encoded with the run's VAE)."
        ),
    ] = None,
    live: Annotated[bool, typer.Option("--live", help="Serve the live tuning page instead.")] = False,
    host: Annotated[str, typer.Option("--host", help="Address of the live page (local only by default).")] = (
        "127.0.0.1"
    ),
    port: Annotated[int, typer.Option("--port", help="Port of the live page.")] = 8080,
    token: Annotated[
        str | None,
        typer.Option(
            "--token",
            envvar="AMORCTL_TOKEN",
            show_envvar=True,
            help="Shared token of the live page: needed with a --host beyond loopback; the page's URL "
            "then carries it (prefer the environment variable, a flag shows in `ps`).",
        ),
    ] = None,
    save_to: Annotated[
        Path, typer.Option("--save-to", help="Live page: where 'save schedule' writes the keyframes.")
    ] = Path("tune-schedule.toml"),
    hlp: Annotated[
        Path | None, typer.Option("--hlp", help="An HLP directory chooses w_t every step (docs/hlp.md).")
    ] = None,
    scale: Annotated[
        str | None, typer.Option("--scale", help="With --hlp: multiply its w_t, e.g. smooth=2,vel=0.5.")
    ] = None,
    json_: JsonFlag = False,
) -> None:
    """Run the policy with weights chosen after training: constant (--weights), over time
    (--schedule), or live in the browser (--live). Prints per-objective returns."""
    from amorctl.core.schedule import load_schedule
    from amorctl.core.weights import parse_weights
    from amorctl.tune.session import PinnedMotion, run_tune

    if live:  # before any work: beyond loopback only with a token (docs/tune.md, "Security")
        token = check_bind(host, token, f"--live --host {host}")
    if hlp is not None:  # the high-level policy picks the weights (amorctl.hlp.tune)
        fields = dict(motion=motion, weights=weights, schedule=schedule, seconds=seconds, out=out)
        fields |= dict(plot=plot, video=video, stop_on_fall=stop_on_fall, seed=seed, data=data)
        fields |= dict(live=live, host=host, port=port, token=token, save_to=save_to, hlp=hlp)
        _tune_with_hlp(TuneRequest(run=run, scale=scale, json=json_, **fields))
        if live:
            from amorctl.tune.live import end_live_process

            end_live_process()
        return
    if scale is not None:
        raise AmorError("--scale edits the weights an HLP chose; it needs --hlp")
    _check_args(live, schedule, weights, out, plot, video, port)
    tenv = PinnedMotion(run, motion, seed=seed, dataset=data)
    if video is not None and not tenv.tracking:
        tenv.close()
        raise AmorError(f"--video needs a character; run {run} has env kind {tenv.config.env.kind!r}")
    try:
        w0 = parse_weights(weights, tenv.names, source="--weights") if weights is not None else None
        if live:
            from amorctl.tune.live import LiveSession, end_live_process, serve_live

            session = LiveSession(tenv, w0, save_to=save_to)
            serve_live(
                session,
                host=host,
                port=port,
                token=token,
                announce=lambda url: err_console.print(f"live page: {url}"),
            )
            tenv.close()
            end_live_process()
        sched = None
        if schedule is not None:
            sched = load_schedule(schedule, tenv.names, tenv.motions or None)
        rollout = run_tune(tenv, sched if sched is not None else w0, seconds, stop_on_fall=stop_on_fall)
    finally:
        tenv.close()
    character = tenv.view.character.name if tenv.view is not None else ""
    _write_outputs(rollout, {"run": str(run), "seed": str(seed)}, out, plot, video, character)
    kf_times = sched.track_for(tenv.motion).times if sched is not None else np.zeros(0)
    result = _result(run, rollout, kf_times, {"out": out, "plot": plot, "video": video})
    if json_:
        print_json(result)
        return
    _print_table(result)


def _tune_with_hlp(req: TuneRequest) -> None:
    """``tune --hlp``: the HLP of ``req.hlp`` chooses w_t every step (``amorctl.hlp.tune``); the same
    outputs and report as with fixed weights, plus the weights it chose."""
    from amorctl.cli.hlp import print_hlp_weights, tune_with_hlp

    _check_outputs(req.outputs)
    if req.video is not None and req.video.suffix.lower() != ".mp4":
        raise AmorError(f"--video {req.video}: the file must end in .mp4")
    ran = tune_with_hlp(req)
    if ran is None:  # the live page was served
        return
    rollout, character, extra = ran
    meta = {"run": str(req.run), "seed": str(req.seed), "hlp": str(req.hlp)}
    _write_outputs(rollout, meta, req.out, req.plot, req.video, character)
    result = {
        **_result(req.run, rollout, np.zeros(0), {"out": req.out, "plot": req.plot, "video": req.video}),
        "hlp": extra,
    }
    if req.json:
        print_json(result)
        return
    _print_table(result)
    print_hlp_weights(extra)


def _check_args(
    live: bool,
    schedule: Path | None,
    weights: str | None,
    out: Path | None,
    plot: Path | None,
    video: Path | None,
    port: int,
) -> None:
    """AmorError for a combination of options that cannot work, before any work is done."""
    if live:
        if schedule is not None or out is not None or plot is not None or video is not None:
            raise AmorError(
                "--live takes no --schedule, --out, --plot or --video (save keyframes on the page)"
            )
        if not 0 < port < 65536:
            raise AmorError(f"--port must be in 1..65535, got {port}")
    elif (weights is None) == (schedule is None):
        raise AmorError("give exactly one of --weights or --schedule (or --live)")
    _check_outputs([out, plot, video])
    if video is not None and video.suffix.lower() != ".mp4":
        raise AmorError(f"--video {video}: the file must end in .mp4")


def _write_outputs(
    rollout: Any,
    meta: dict[str, str],
    out: Path | None,
    plot: Path | None,
    video: Path | None,
    character: str,
) -> None:
    """Write the MCAP log, the plot and the video (with the reference ghost) that were asked for:
    all of them or none (a failure removes the files written before it)."""
    from amorctl.outputs.mcap_log import write_rollout_mcap
    from amorctl.outputs.plots import plot_rollout

    written: list[Path] = []
    try:
        if out is not None:
            write_rollout_mcap(rollout, out, meta)
            written.append(out)
        if plot is not None:
            plot_rollout(rollout, plot, title=f"{Path(meta['run']).name} — {rollout.motion or 'rollout'}")
            written.append(plot)
        if video is not None:
            from amorctl.outputs.video import render_video

            render_video(
                video,
                character,
                rollout.qpos,
                ref_qpos=rollout.ref_qpos,
                weights=rollout.weights,
                objective_names=rollout.objective_names,
                fps=1.0 / rollout.dt,
            )
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        raise


def _result(run: Path, rollout: Any, kf_times: np.ndarray, files: dict[str, Path | None]) -> dict[str, Any]:
    """The ``--json`` document: returns, fall time, per-keyframe segments, the files written."""
    fell = np.flatnonzero(rollout.terminated)
    return {
        "run": str(run),
        "motion": rollout.motion,
        "objectives": list(rollout.objective_names),
        "steps": len(rollout.times),
        "seconds": float(len(rollout.times) * rollout.dt),
        "fell_at": float(rollout.times[fell[0]] + rollout.dt) if len(fell) else None,
        "returns": dict(zip(rollout.objective_names, rollout.returns.tolist(), strict=True)),
        "mean_action_rate": float(rollout.action_rate().mean()),
        "segments": _segments(rollout, kf_times),
        "files": {k: str(v) for k, v in files.items() if v is not None},
    }


def _print_table(result: dict[str, Any]) -> None:
    names = result["objectives"]
    head = f"{result['run']}  motion={result['motion']}  {result['steps']} steps ({result['seconds']:.2f} s)"
    if result["fell_at"] is not None:
        head += f"  fell at {result['fell_at']:.2f} s"
    console.print(head)
    table = Table("", *names, title="per-objective return (sum of rewards)")
    table.add_row("return", *(f"{result['returns'][n]:.3f}" for n in names))
    console.print(table)
    if len(result["segments"]) > 1:
        seg = Table("from s", "to s", *names, "action rate", title="mean reward per step between keyframes")
        for s in result["segments"]:
            seg.add_row(
                f"{s['t0']:.2f}",
                f"{s['t1']:.2f}",
                *(f"{s['mean_reward'][n]:.3f}" for n in names),
                f"{s['mean_action_rate']:.4g}",
            )
        console.print(seg)
    for key, value in result["files"].items():
        console.print(f"{key}: {value}")
