"""``amorctl hlp``: train a high-level policy that picks AMOR's weights (paper Section 6), trace it."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Group
from rich.table import Table
from rich.text import Text

from amorctl.cli.live_view import TrainingView, fmt
from amorctl.cli.output import console, print_json
from amorctl.core.errors import AmorError
from amorctl.hlp.config import PRESETS, HlpConfig, load_hlp_config, load_hlp_preset, merge

if TYPE_CHECKING:
    from amorctl.cli.tune import TuneRequest

app = typer.Typer(
    help="High-level policy (HLP): PPO picks the weights w_t of a frozen AMOR policy every control "
    "step, rewarded by a motion discriminator (paper Section 6). See docs/hlp.md.",
    no_args_is_help=True,
)

MotionsOpt = Annotated[list[str] | None, typer.Option("--motion", "-m", help="Clip name (repeatable).")]
RunDataOpt = Annotated[
    Path | None,
    typer.Option("--data", help="The AMOR run's own motion dataset where it is now (after it moved)."),
]


class _Display(TrainingView):
    """The live view of ``hlp train``: progress, discriminator, PPO and mean w per objective."""

    def __init__(self, out: Path, live: bool) -> None:
        super().__init__(live)
        self.out = out

    def on_start(self, s: Any, start: int, total: int) -> None:
        self.begin(
            s.meta["objectives"],
            start,
            f"[bold]amorctl hlp train[/bold] on {s.run.path} (AMOR iteration {s.llp_checkpoint.iteration}, "
            f"frozen) · {s.env.num_envs} envs · {len(s.meta['objectives'])} objectives\n"
            f"HLP directory: {self.out}" + (f" (resuming at iteration {start})" if start else ""),
        )

    def render(self, m: dict[str, float], total: int, elapsed: float) -> Group:
        it = int(m["iteration"])
        left = self.seconds_left(it, total, elapsed)
        g = m.get
        head = Text(
            f"iteration {it}/{total}   env steps {int(m['env_steps']):,}   "
            f"{m['env_steps_per_s']:,.0f} steps/s   elapsed {elapsed:.0f} s   left {left:.0f} s\n"
            f"reward r^D {fmt(m['reward/mean'])}   episode return {fmt(m['episode/return'])}   "
            f"length {fmt(m['episode/length'], '.1f')}   w entropy {fmt(m['w/entropy'])}\n"
            f"D: acc dataset {fmt(g('disc/accuracy_dataset', math.nan), '.2f')}   "
            f"acc policy {fmt(g('disc/accuracy_policy_rollout', math.nan), '.2f')}   "
            f"logit dataset {fmt(g('disc/logit_dataset', math.nan))}   "
            f"logit policy {fmt(g('disc/logit_policy_rollout', math.nan))}   "
            f"gp {fmt(g('disc/gp', math.nan))}\n"
            f"PPO: loss {fmt(m['loss/total'])}   value {fmt(m['loss/value'])}   kl {fmt(m['kl'])}   "
            f"logit std {fmt(m['logit_std'])}"
        )
        table = Table(box=None, pad_edge=False)
        table.add_column("objective")
        table.add_column("mean w_t", justify="right")
        for name in self.names:
            table.add_row(name, fmt(m[f"w/{name}"], ".3f"))
        return Group(head, table)

    def line(self, m: dict[str, float]) -> str:
        acc = "/".join(
            fmt(m.get(f"disc/accuracy_{k}", math.nan), ".2f") for k in ("dataset", "policy_rollout")
        )
        return f"r^D {fmt(m['reward/mean'])}  D acc {acc}  w {self.per_objective(m, 'w', '.3f')}"


def _config(
    preset: str | None,
    config_file: Path | None,
    window: int | None,
    motions: list[str] | None,
    iterations: int | None,
    seed: int | None,
    num_envs: int | None,
) -> HlpConfig:
    base = load_hlp_preset(preset or "v30")
    if config_file is not None:
        base = load_hlp_config(config_file, base)
    flags: list[tuple[str, dict[str, Any]]] = [
        ("--window", {"discriminator": {"window": window}}),
        ("--motion", {"env": {"motions": list(motions) if motions else None}}),
        ("--iterations", {"run": {"iterations": iterations}}),
        ("--seed", {"run": {"seed": seed}}),
        ("--num-envs", {"env": {"num_envs": num_envs}}),
    ]
    for flag, data in flags:
        data = {s: {k: v for k, v in d.items() if v is not None} for s, d in data.items()}
        if any(data.values()):
            base = merge(base, data, flag)
    return base


@app.command("train")
def train(
    run: Annotated[Path, typer.Argument(help="The AMOR run directory (its newest checkpoint is frozen).")],
    out: Annotated[
        Path | None, typer.Option("--out", help="HLP directory (default RUN/hlp/v<V>-<time>).")
    ] = None,
    window: Annotated[
        int | None, typer.Option("--window", "-V", help="Discriminator window V (frames).")
    ] = None,
    motion: MotionsOpt = None,
    iterations: Annotated[int | None, typer.Option("--iterations", help="Total PPO iterations.")] = None,
    config_file: Annotated[
        Path | None, typer.Option("--config", help="HLP TOML on top of the preset.")
    ] = None,
    preset: Annotated[
        str | None, typer.Option("--preset", help=f"{' | '.join(PRESETS)} (default v30).")
    ] = None,
    seed: Annotated[int | None, typer.Option("--seed", help="Seed of env, networks, noise.")] = None,
    num_envs: Annotated[int | None, typer.Option("--num-envs", help="Parallel environments.")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue the HLP in --out.")] = False,
    data: RunDataOpt = None,
    json_out: Annotated[bool, typer.Option("--json", help="JSON summary at the end, no live view.")] = False,
) -> None:
    """Train an HLP on the run's frozen AMOR policy with the discriminator reward r^D."""
    from amorctl.hlp.run import HlpDir, train_hlp

    if window is not None and window < 1:
        raise AmorError(f"--window {window}: V must be >= 1 (frames per discriminator window)")
    if resume:
        if out is None:
            raise AmorError("--resume needs --out, the HLP directory to continue")
        if preset is not None or config_file is not None or window is not None or motion:
            raise AmorError(
                "--resume continues with the HLP's own hlp.toml; drop --preset/--config/--window/--motion"
            )
        own = HlpDir.open(out).config
        config = (
            own if iterations is None else merge(own, {"run": {"iterations": iterations}}, "--iterations")
        )
    else:
        config = _config(preset, config_file, window, motion, iterations, seed, num_envs)
        if out is None:
            from amorctl.train.rundir import RunDir  # pretrained:NAME writes to ./NAME/hlp

            stamp = f"v{config.discriminator.window}-{time.strftime('%Y%m%d-%H%M%S')}"
            out = RunDir(run).output_dir("hlp") / stamp
    display = _Display(out, live=console.is_terminal and not json_out)
    try:
        result = train_hlp(
            run,
            out,
            config,
            resume=resume,
            data=data,
            on_start=None if json_out else display.on_start,
            on_iteration=None if json_out else display.on_iteration,
        )
    finally:
        display.stop()
    summary = {
        "out": str(result.out),
        "start_iteration": result.start_iteration,
        "end_iteration": result.end_iteration,
        "interrupted": result.interrupted,
        "checkpoint": str(result.checkpoint) if result.checkpoint else None,
        "llp_fingerprint": result.llp_fingerprint_after,
        "metrics": {k: v for k, v in result.last_metrics.items() if math.isfinite(v)},
    }
    if json_out:
        print_json(summary)
    else:
        state = "interrupted" if result.interrupted else "done"
        console.print(
            f"{state} at iteration {result.end_iteration}; checkpoint {summary['checkpoint']}",
            highlight=False,
        )
    if result.interrupted:
        raise typer.Exit(130)


@app.command("trace")
def trace(
    hlp_dir: Annotated[Path, typer.Argument(help="An HLP directory (from `amorctl hlp train`).")],
    motion: MotionsOpt = None,
    seconds: Annotated[
        float | None, typer.Option("--seconds", help="Seconds per motion (default: one pass).")
    ] = None,
    plot: Annotated[Path | None, typer.Option("--plot", help="Figure of w_t, log scale (.png/.svg).")] = None,
    out: Annotated[Path | None, typer.Option("--out", help="MCAP log of w_t, rewards, joint states.")] = None,
    compare: Annotated[
        Path | None, typer.Option("--compare", help="A second HLP directory to overlay.")
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Env seed.")] = 0,
    data: RunDataOpt = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the traced weights as JSON.")] = False,
) -> None:
    """Run HLP + AMOR through motions back to back; plot w_t per objective (paper Fig. 7 / 8)."""
    from amorctl.hlp.run import load_hlp
    from amorctl.hlp.trace import plot_traces, trace_hlp, write_trace_mcap

    if not motion:
        raise AmorError("--motion: name at least one motion to trace (repeat --motion for a sequence)")
    for path, what in ((plot, "--plot"), (out, "--out")):
        if path is not None and path.suffix.lower() not in (
            {".png", ".svg"} if what == "--plot" else {".mcap"}
        ):
            raise AmorError(f"{what} {path}: use {'.png or .svg' if what == '--plot' else '.mcap'}")
    hlps = [load_hlp(hlp_dir)] + ([load_hlp(compare)] if compare is not None else [])
    if compare is not None and hlps[0].meta["run"] != hlps[1].meta["run"]:
        hlps[1].dir.check_matches(hlps[0].meta, f"HLP {hlp_dir}")
    traces = [trace_hlp(h, list(motion), seconds, seed, data) for h in hlps]
    if plot is not None:
        plot_traces(traces, plot)
    if out is not None:
        write_trace_mcap(traces, out)
    summary = [
        {
            "hlp": str(h.dir.path),
            "steps": len(t.weights),
            "seconds": float(t.times[-1]),
            "joint_mae_deg": t.joint_mae_deg(),
            "falls": int(t.fell.sum()),
            "segments": [
                {
                    "motion": name,
                    "start_s": a * t.dt,
                    "end_s": b * t.dt,
                    "mean_w": dict(zip(t.objective_names, t.weights[a:b].mean(0).tolist(), strict=True)),
                }
                for a, b, name in t.segments
            ],
        }
        for h, t in zip(hlps, traces, strict=True)
    ]
    if json_out:
        print_json(
            {"traces": summary, "plot": str(plot) if plot else None, "mcap": str(out) if out else None}
        )
        return
    for item in summary:
        console.print(
            f"[bold]{item['hlp']}[/bold]: {item['steps']} steps ({item['seconds']:.1f} s), joint MAE "
            f"{item['joint_mae_deg']:.2f}°, {item['falls']} falls",
            highlight=False,
        )
        table = Table(box=None, pad_edge=False)
        table.add_column("motion")
        table.add_column("from–to (s)")
        names = hlps[0].meta["objectives"]
        for n in names:
            table.add_column(n, justify="right")
        for seg in item["segments"]:
            table.add_row(
                seg["motion"],
                f"{seg['start_s']:.2f}–{seg['end_s']:.2f}",
                *(f"{seg['mean_w'][n]:.3f}" for n in names),
            )
        console.print(table)
    for path in (plot, out):
        if path is not None:
            console.print(f"wrote {path}", highlight=False)


def parse_table_conditions(
    names: tuple[str, ...], hlp_dirs: list[Path], weights: list[str] | None
) -> list[tuple[str, str, Any]]:
    """The rows of Table 2: uniform, each ``--weights`` and each HLP directory (loaded)."""
    import numpy as np

    from amorctl.core.weights import parse_weights
    from amorctl.hlp.run import load_hlp

    m = len(names)
    rows: list[tuple[str, str, Any]] = [("uniform", "uniform", np.full(m, 1.0 / m))]
    for text in weights or []:
        rows.append((f"w = {text}", text, parse_weights(text, names)))
    for path in hlp_dirs:
        h = load_hlp(path)
        rows.append((f"HLP {path.name} (V={h.meta.get('window')})", str(path), h))
    return rows


def print_table2(table: Any) -> None:
    """Table 2 as a rich table with its caption (counts of windows and episodes)."""
    t = Table(title="Motion tracking: uniform vs HLP-chosen weights (paper Table 2)", caption=table.caption)
    for col in ("weights", "MAE (deg) ↓", "logit ↑", "episodes", "falls", "held-out windows"):
        t.add_column(col, justify="left" if col == "weights" else "right")
    for r in table.rows:
        t.add_row(
            r["label"],
            f"{r['joint_mae_deg']:.2f} ± {r['joint_mae_ci95']:.2f}",
            f"{r['logit']:.2f} ± {r['logit_ci95']:.2f}",
            str(r["episodes"]),
            str(r["falls"]),
            str(r["windows_heldout"]),
        )
    console.print(t)


def table2(
    run: Path,
    hlp_dirs: list[Path],
    weights: list[str] | None,
    options: Any,
    json_out: bool,
    show: bool = True,
) -> dict[str, Any]:
    """Compute and print Table 2 (``amorctl evaluate RUN --hlp HLPDIR --compare``); returns its JSON."""
    from amorctl.hlp.eval_discriminator import hlp_table
    from amorctl.train.rundir import RunDir

    names = tuple(RunDir.open(run).policy().objectives)
    conditions = parse_table_conditions(names, hlp_dirs, weights)
    say = (lambda line: console.print(line, highlight=False)) if show and not json_out else None
    result = hlp_table(str(run), conditions, options, say)
    data = result.to_json()
    if json_out:
        print_json(data)
    else:
        print_table2(result)
    return data


def tune_with_hlp(req: TuneRequest) -> tuple[Any, str, dict[str, Any]] | None:
    """``amorctl tune RUN --hlp HLPDIR``: the HLP picks w_t, ``--scale`` edits it (docs/hlp.md).

    Serves the live page (returns None) or returns (the :class:`TuneRollout`, the character's
    name, the ``hlp`` part of the JSON report); ``amorctl tune`` writes and prints the rest.
    """
    from amorctl.cli.output import err_console
    from amorctl.hlp.edit import parse_scales
    from amorctl.hlp.run import load_hlp
    from amorctl.hlp.tune import check_hlp_for, run_hlp_tune
    from amorctl.tune.session import PinnedMotion

    if req.weights is not None or req.schedule is not None:
        raise AmorError(
            "--hlp chooses the weights every step; drop --weights / --schedule (edit with --scale)"
        )
    if req.live and any(p is not None for p in req.outputs):
        raise AmorError("--live takes no --out, --plot or --video (save keyframes on the page)")
    if req.live and not 0 < req.port < 65536:
        raise AmorError(f"--port must be in 1..65535, got {req.port}")
    assert req.hlp is not None
    hlp = load_hlp(req.hlp)
    if req.data is not None:
        from amorctl.hlp.run import OWN_DATA
        from amorctl.train.rundir import RunDir

        RunDir.open(req.run).relocate_dataset(req.data, required=OWN_DATA)
    tenv = PinnedMotion(req.run, req.motion, seed=req.seed, dataset=req.data)
    try:
        check_hlp_for(tenv, hlp)
        scales = parse_scales(req.scale, tenv.names)
        if req.live:
            from amorctl.hlp.live import HlpLiveSession, serve_hlp_live

            session = HlpLiveSession(tenv, hlp, scales, save_to=req.save_to)
            serve_hlp_live(
                session,
                host=req.host,
                port=req.port,
                token=req.token,
                announce=lambda url: err_console.print(f"live page: {url}"),
            )
            return None
        rollout, raw = run_hlp_tune(tenv, hlp, scales, req.seconds, stop_on_fall=req.stop_on_fall)
    finally:
        tenv.close()
    names = list(rollout.objective_names)
    extra = {
        "dir": str(req.hlp),
        "scales": dict(zip(names, scales.tolist(), strict=True)),
        "mean_hlp_weights": dict(zip(names, raw.mean(0).tolist(), strict=True)),
        "mean_weights": dict(zip(names, rollout.weights.mean(0).tolist(), strict=True)),
    }
    character = tenv.view.character.name if tenv.view is not None else ""
    return rollout, character, extra


def print_hlp_weights(extra: dict[str, Any]) -> None:
    """The HLP's mean w_t, the multipliers and the mean applied weights, as a table."""
    names = list(extra["scales"])
    table = Table("", *names, title="weights: the HLP's w_t (mean) and after --scale (mean)")
    table.add_row("HLP", *(f"{extra['mean_hlp_weights'][n]:.3f}" for n in names))
    table.add_row("× scale", *(f"{extra['scales'][n]:.2f}" for n in names))
    table.add_row("applied", *(f"{extra['mean_weights'][n]:.3f}" for n in names))
    console.print(table)


def evaluate_hlp(
    run: Path,
    hlp_dirs: list[Path],
    weights: str | None,
    motions: list[str] | None,
    compare: bool,
    envs: int,
    seconds: float,
    disc_steps: int,
    seed: int,
    json_out: bool,
    other_options: dict[str, Any],
    data: Path | None = None,
) -> None:
    """``amorctl evaluate RUN --hlp HLPDIR --compare``: Table 2 (docs/hlp.md)."""
    from amorctl.hlp.eval_discriminator import TableOptions

    if not compare:
        raise AmorError("--hlp needs --compare: Table 2 sets the HLP's rows beside uniform weights")
    given = [name for name, value in other_options.items() if value]
    if given:
        raise AmorError(f"--hlp (Table 2) takes no {', '.join(given)}")
    options = TableOptions(
        num_envs=envs, seconds=seconds, steps=disc_steps, seed=seed, motions=tuple(motions or ()), data=data
    )
    options.check()
    table2(run, list(hlp_dirs), [weights] if weights else None, options, json_out)
