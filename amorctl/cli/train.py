"""``amorctl train``: train one weight-conditioned policy (MOPPO), or plain PPO with fixed weights."""

from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Group
from rich.table import Table
from rich.text import Text

from amorctl.cli.live_view import TrainingView, fmt, fmt_time
from amorctl.cli.output import console, print_json
from amorctl.core.config import ENV_KINDS, PRESETS, TrainConfig, load_config, load_preset, merge
from amorctl.core.contracts import tracking_view
from amorctl.core.errors import AmorError, AmorWarning
from amorctl.core.vecenv import VectorEnv
from amorctl.core.weights import parse_weight_pairs
from amorctl.envs.factory import TOY_CONTROL_HZ
from amorctl.sim.cpus import available_cpus, cpu_description
from amorctl.train import distributed
from amorctl.train.loop import train_run
from amorctl.train.metrics import family_survival
from amorctl.train.rundir import RunDir

#: Exit status after a signal stopped training (and a checkpoint was saved): 128 + signal number.
SIGNAL_EXIT = {"SIGINT": 130, "SIGTERM": 143}


#: the metric only a distillation student reports (docs/distill.md)
DISTILL_MAE = "distill/action_mae"
#: the metric only a kickstarted run reports: its teachers' KL term (docs/distill.md, "Kickstarting")
KICKSTART_KL = "distill/kl"


def _losses(m: dict[str, float]) -> str:
    """The update's losses: MOPPO's, a student's distillation loss and teacher action error, or
    (kickstarting) MOPPO's with the teachers' weighted KL beside them."""
    if KICKSTART_KL in m:
        return (
            f"loss {fmt(m['loss/total'])} (policy {fmt(m['loss/policy'])}, value {fmt(m['loss/value'])}, "
            f"teacher KL {fmt(m['distill/kl'])} x {fmt(m['distill/kl_coef'])})   "
            f"teacher action MAE {fmt(m[DISTILL_MAE])} rad   KL {fmt(m['kl'])}   "
            f"clip {fmt(m['clip_fraction'], '.2f')}"
        )
    if DISTILL_MAE in m:
        return (
            f"loss {fmt(m['loss/total'])} (distill {fmt(m['loss/policy'])}, value {fmt(m['loss/value'])})   "
            f"teacher action MAE {fmt(m[DISTILL_MAE])} rad   KL {fmt(m['kl'])}"
        )
    return (
        f"loss {fmt(m['loss/total'])} (policy {fmt(m['loss/policy'])}, value {fmt(m['loss/value'])}, "
        f"entropy {fmt(m['loss/entropy'])})   KL {fmt(m['kl'])}   clip {fmt(m['clip_fraction'], '.2f')}"
    )


class _Display(TrainingView):
    """The live view: progress, throughput, losses, episode statistics, per-objective table."""

    def __init__(self, out: Path, config: TrainConfig, live: bool) -> None:
        super().__init__(live)
        self.out, self.config = out, config
        self.dt = 1.0 / TOY_CONTROL_HZ if config.env.kind != "gym" else None  # seconds per step

    def on_start(self, env: VectorEnv, start: int, total: int) -> None:
        view = tracking_view(env)
        if view is not None:  # the character's own control rate
            self.dt = float(view.dt)
        names = env.reward_space.names
        c = self.config
        where = c.env.character if c.env.kind == "tracking" else (c.env.gym_id or c.env.kind)
        mode = f"fixed w ({c.env.fixed_weights})" if c.env.fixed_weights else _weight_mode(c)
        if c.distill.teachers:
            role = "kickstarted by" if c.distill.rewards else "student of"
            mode += f" · {role} {len(c.distill.teachers)} teacher run(s)"
        if c.run.init_from:
            mode += f" · started from {c.run.init_from}"
        self.begin(
            names,
            start,
            f"[bold]amorctl train[/bold] {where} · backend {c.run.backend} · {c.env.num_envs} envs · "
            f"obs {env.obs_dim} · actions {env.action_dim} · {len(names)} objectives · {mode}\n"
            f"CPU: {cpu_description()} · {available_cpus()} cores for this process · "
            f"precision {c.ppo.precision} (the one in use is shown each iteration)\n"
            f"run directory: {self.out}" + (f" (resuming at iteration {start})" if start else ""),
        )

    def render(self, m: dict[str, float], total: int, elapsed: float) -> Group:
        it = int(m["iteration"])
        left = self.seconds_left(it, total, elapsed)
        seconds = f" ({fmt(m['episode/length'] * self.dt, '.2f')} s)" if self.dt else ""
        head = Text(
            f"iteration {it}/{total}   env steps {int(m['env_steps']):,}   "
            f"{m['env_steps_per_s']:,.0f} steps/s   "
            f"elapsed {fmt_time(elapsed)}   left {fmt_time(left)}\n"
            f"{_losses(m)}   "
            f"lr {fmt(m['learning_rate'])}   action std {fmt(m['action_std'])}   "
            f"{'bf16' if m.get('bf16') else 'fp32'}\n"
            f"episodes {int(m['episodes'])}   length {fmt(m['episode/length'], '.1f')} steps{seconds}   "
            f"survival {fmt(100 * m['episode/survival'], '.0f')}%   "
            f"return·w {fmt(m['return/scalarized'])}"
        )
        if families := family_survival(m):  # one number is pinned near 0 by the hardest clips
            head.append(f"\nsurvival by clip family (last 100 episodes each): {families}")
        table = Table(box=None, pad_edge=False)
        for col in ("objective", "episode return", "reward/step", "critic expl. var."):
            table.add_column(col, justify="right" if col != "objective" else "left")
        for name in self.names:
            table.add_row(
                name,
                fmt(m[f"return/{name}"]),
                fmt(m[f"reward/{name}"]),
                fmt(m[f"explained_variance/{name}"], ".2f"),
            )
        return Group(head, table)

    def line(self, m: dict[str, float]) -> str:
        return (
            f"{m['env_steps_per_s']:,.0f} steps/s ({'bf16' if m.get('bf16') else 'fp32'})  "
            f"loss {fmt(m['loss/total'])}  value {fmt(m['loss/value'])}  kl {fmt(m['kl'])}  "
            + (f"teacher action MAE {fmt(m[DISTILL_MAE])}  " if DISTILL_MAE in m else "")
            + (
                f"teacher KL {fmt(m['distill/kl'])} x {fmt(m['distill/kl_coef'])}  "
                if KICKSTART_KL in m
                else ""
            )
            + f"ep len {fmt(m['episode/length'], '.1f')}  "
            f"survival {fmt(m['episode/survival'], '.2f')}  returns {self.per_objective(m, 'return')}"
            + (f"  survival by family: {families}" if (families := family_survival(m)) else "")
        )


def _weight_mode(c: TrainConfig) -> str:
    """How MOPPO draws each episode's w, as the header says it: the paper's Dirichlet(1), or the
    [weights] mix (docs/moppo.md, "Levers"), e.g. ``w ~ Dirichlet(1) per episode, corner 10%, axis 30%``."""
    w = c.weights
    shares = {"corner": w.corner_fraction, "edge": w.edge_fraction, "axis": w.axis_fraction}
    shares["adaptive"] = w.adaptive_fraction
    mix = "".join(f", {name} {100 * share:.0f}%" for name, share in shares.items() if share > 0)
    return f"w ~ Dirichlet({w.alpha:g}) per episode{mix}"


def _command_line(ctx: typer.Context) -> tuple[dict[str, dict[str, Any]], dict[tuple[str, str], str]]:
    """The config values this command line sets and the flag of every config field ``train``
    takes. An option sets config field ``[SECTION] KEY`` when its parameter is named
    ``SECTION__KEY``, so a new option is one parameter of :func:`train` (``--env`` is parsed apart).
    Returns ({section: {key: value}} for the options given, {(section, key): flag})."""
    overrides: dict[str, dict[str, Any]] = {}
    flags: dict[tuple[str, str], str] = {("env", "kind"): "--env", ("env", "gym_id"): "--env"}
    for param in ctx.command.params:
        section, sep, key = (param.name or "").partition("__")
        if not sep:
            continue
        flags[(section, key)] = param.opts[0]
        value = ctx.params.get(param.name or "")
        if value is not None:
            overrides.setdefault(section, {})[key] = str(value) if isinstance(value, Path) else value
    return overrides, flags


def _relaunch_args(ctx: typer.Context, out: Path) -> list[str]:
    """This command line for the ranks torchrun starts: every option given, as parsed, without
    ``--nproc`` and with ``--out`` fixed (the default name carries a time stamp)."""
    args: list[str] = []
    for param in ctx.command.params:
        if param.param_type_name != "option" or param.name == "nproc":
            continue
        value = out if param.name == "out" else ctx.params.get(param.name or "")
        if param.is_flag:
            args += [param.opts[0]] if value else []
        elif value is not None:
            args += [param.opts[0], str(value)]
    return args


def _apply_flags(
    base: TrainConfig, overrides: dict[str, dict[str, Any]], flags: dict[tuple[str, str], str]
) -> TrainConfig:
    """Merge command-line values one flag at a time, so an error names the flag that set it."""
    by_flag: dict[str, dict[str, dict[str, Any]]] = {}
    for section, values in overrides.items():
        for key, value in values.items():
            flag = flags.get((section, key), "command line")
            by_flag.setdefault(flag, {}).setdefault(section, {})[key] = value
    for flag, data in by_flag.items():
        base = merge(base, data, flag)
    return base


def _resolve_config(
    preset: str | None,
    config_file: Path | None,
    overrides: dict[str, dict[str, Any]],
    flags: dict[tuple[str, str], str],
) -> TrainConfig:
    base = load_preset(preset or "quick")
    if config_file is not None:
        base = load_config(config_file, base)
    return _apply_flags(base, overrides, flags)


def _resume_config(
    out: Path, preset: str | None, config_file: Path | None, overrides: dict[str, dict[str, Any]]
) -> TrainConfig:
    """The run's own config; only ``--iterations`` may change, anything else must agree (``--data``:
    the run's dataset, as stored or moved: the same SHA-256, ``RunDir.relocate_dataset``)."""
    if preset is not None or config_file is not None:
        raise AmorError("--resume continues with the run's own config.toml; drop --preset/--config")
    run = RunDir(out)
    config = run.config
    for section, values in overrides.items():
        for key, value in values.items():
            if section == "run" and key == "iterations":
                continue
            if (section, key) == ("env", "dataset") and Path(value).is_file():
                same = Path(value).resolve() == Path(config.env.dataset).resolve()
                if same or run.relocate_dataset(value):
                    config = run.config
                    continue
            current = getattr(getattr(config, section), key)
            if value != current:
                raise AmorError(
                    f"--resume: the run in {out} has {section}.{key} = {current!r}, "
                    f"not {value!r}; it cannot change when resuming"
                )
    iterations = overrides.get("run", {}).get("iterations")
    if iterations is None:
        return config
    return merge(config, {"run": {"iterations": iterations}}, "--iterations")


def train(
    ctx: typer.Context,
    env__character: Annotated[
        str | None,
        typer.Option("--character", "-c", help="Character plugin to train (default: the preset's, biped20)."),
    ] = None,
    config_file: Annotated[
        Path | None,
        typer.Option("--config", help="TOML config on top of the preset (unknown keys are rejected)."),
    ] = None,
    preset: Annotated[
        str | None, typer.Option("--preset", help=f"Preset: {' | '.join(PRESETS)} (default quick).")
    ] = None,
    run__backend: Annotated[str | None, typer.Option("--backend", help="Training backend plugin.")] = None,
    env__dataset: Annotated[
        Path | None,
        typer.Option(
            "--data", help="Motion dataset (default: the character's built-in clips, cached on first use)."
        ),
    ] = None,
    out: Annotated[
        Path | None, typer.Option("--out", help="Run directory (default runs/<env>-<time>).")
    ] = None,
    run__seed: Annotated[int | None, typer.Option("--seed", help="Seed of env, networks and noise.")] = None,
    run__iterations: Annotated[
        int | None, typer.Option("--iterations", help="Total training iterations.")
    ] = None,
    resume: Annotated[
        bool, typer.Option("--resume", help="Continue the run in --out from its newest checkpoint.")
    ] = False,
    run__init_from: Annotated[
        str | None,
        typer.Option(
            "--init-from",
            help="Start a new run from another run's networks: RUN, pretrained:NAME, optionally "
            "@ITERATION (docs/train.md).",
        ),
    ] = None,
    env__fixed_weights: Annotated[
        str | None,
        typer.Option(
            "--fixed-weights", help="Plain PPO with one fixed w, e.g. up=1,smooth=0.5 (normalized; others 0)."
        ),
    ] = None,
    env: Annotated[
        str | None,
        typer.Option(
            "--env", help="tracking (default) | toy | toy-smooth | gym:<Gymnasium id> with a vector reward."
        ),
    ] = None,
    env__num_envs: Annotated[int | None, typer.Option("--num-envs", help="Parallel environments.")] = None,
    json_out: Annotated[
        bool, typer.Option("--json", help="Print a JSON summary at the end, no live view.")
    ] = False,
    nproc: Annotated[
        int | None,
        typer.Option(
            "--nproc",
            min=1,
            help="Train data-parallel over N processes on this machine (launches torchrun; "
            "docs/distributed.md).",
        ),
    ] = None,
) -> None:
    """Train one policy for every trade-off between the objectives (MOPPO, the AMOR paper's Section 4)."""
    fixed_weights = env__fixed_weights
    if fixed_weights is not None and fixed_weights.strip().lower() != "uniform":
        parse_weight_pairs(fixed_weights, source="--fixed-weights")  # '' and 'up=1,,lo=1' refused here
    overrides, flags = _command_line(ctx)
    if env is not None:
        kind, _, gym_id = env.partition(":")
        if kind not in ENV_KINDS or (kind == "gym") != bool(gym_id):
            choices = ", ".join(k for k in ENV_KINDS if k != "gym")
            raise AmorError(f"--env {env!r}: expected {choices} or gym:<id>")
        overrides.setdefault("env", {}).update(kind=kind, gym_id=gym_id or None)
        overrides["env"] = {k: v for k, v in overrides["env"].items() if v is not None}
    if resume:
        if out is None:
            raise AmorError("--resume needs --out, the run directory to continue")
        config = _resume_config(out, preset, config_file, overrides)
    else:
        config = _resolve_config(preset, config_file, overrides, flags)
        if out is None:
            what = config.env.character if config.env.kind == "tracking" else config.env.kind
            out = Path("runs") / f"{what}-{time.strftime('%Y%m%d-%H%M%S')}"

    if nproc is not None and nproc > 1 and distributed.launched_world_size() == 1:
        distributed.local_config(config, distributed.World(0, nproc))  # num_envs divisible: checked here
        raise typer.Exit(_launch(nproc, _relaunch_args(ctx, out)))
    with distributed.session() as world:
        if world.distributed and not resume:
            out = world.broadcast(out)  # the default name has a time stamp: rank 0's
        code = _train_here(config, out, resume, json_out, world, fixed_weights)
    if code:  # after the session: the ranks leave the process group together (distributed.session)
        raise typer.Exit(code)


def _launch(nproc: int, args: list[str]) -> int:
    """Run ``amorctl train <args>`` on ``nproc`` local ranks under torchrun; its exit status."""
    command = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        f"--nproc-per-node={nproc}",
        "-m",
        "amorctl",
        "train",
        *args,
    ]
    console.print(f"launching {nproc} processes: {' '.join(command[1:])}", highlight=False, soft_wrap=True)
    proc = subprocess.Popen(command)
    # Ctrl-C reaches torchrun too (same process group), SIGTERM is passed on: torchrun forwards
    # either to the ranks, which stop after the same iteration and checkpoint; wait for that.
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: proc.send_signal(signal.SIGTERM))
    try:
        while True:
            try:
                return proc.wait()
            except KeyboardInterrupt:
                continue
    finally:
        signal.signal(signal.SIGTERM, previous)


def _jax_follower() -> bool:
    """True in a jax-mjx multi-host process other than process 0 (``AMORCTL_JAX_DISTRIBUTED=1``,
    ``JAX_PROCESS_ID`` > 0; docs/backends.md): it trains along but writes no run directory."""
    on = os.environ.get("AMORCTL_JAX_DISTRIBUTED", "") not in ("", "0")
    return on and os.environ.get("JAX_PROCESS_ID", "0").strip() not in ("", "0")


def _train_here(
    config: TrainConfig,
    out: Path,
    resume: bool,
    json_out: bool,
    world: distributed.World,
    fixed_weights: str | None,
) -> int:
    """Train in this process (one rank under torchrun); rank 0 alone prints. Returns the exit
    status: 0, or 130 / 143 when SIGINT / SIGTERM stopped the run (after its checkpoint)."""
    if _jax_follower():  # jax-mjx multi-host: the same program, but only process 0 writes `out`
        with tempfile.TemporaryDirectory(prefix="amorctl-jax-process-") as tmp:
            scratch = Path(tmp) / "run"
            if resume:  # the run as process 0 sees it (a shared filesystem, or a copy per host)
                shutil.copytree(out, scratch)
            train_run(config, scratch, resume=resume)
        return 0
    if not world.is_main:
        json_out = True  # no live view
        warnings.simplefilter("ignore", AmorWarning)  # rank 0 says it once (run_app restores this)

    display = _Display(out, config, live=console.is_terminal and not json_out)
    if config.env.kind == "tracking" and not json_out and world.is_main:
        data_note = (
            config.env.dataset or "the built-in clips (preprocessed into the cache on first use: minutes)"
        )
        console.print(
            f"preparing {config.env.num_envs} {config.env.character} envs on {data_note} …", highlight=False
        )
    try:
        result = train_run(
            config,
            out,
            resume=resume,
            on_start=None if json_out else display.on_start,
            on_iteration=None if json_out else display.on_iteration,
            on_note=lambda note: console.print(f"note: {note}", highlight=False, soft_wrap=True),
        )
    except AmorError as err:  # the env checks the names; say which flag gave them
        key = "[env] fixed_weights:"
        if fixed_weights is not None and str(err).startswith(key):
            raise AmorError("--fixed-weights:" + str(err).removeprefix(key)) from None
        raise
    finally:
        display.stop()
    summary = {
        "out": str(result.out),
        "start_iteration": result.start_iteration,
        "end_iteration": result.end_iteration,
        "interrupted": result.interrupted,
        "checkpoint": str(result.checkpoint) if result.checkpoint else None,
        "metrics": {k: v for k, v in result.last_metrics.items() if math.isfinite(v)},
    }
    code = SIGNAL_EXIT.get(result.signal, 130) if result.interrupted else 0
    if not world.is_main:  # other ranks stay quiet; their exit status still tells
        return code
    if json_out:
        print_json(summary)
        return code
    state = "interrupted" if result.interrupted else "done"
    console.print(
        f"{state} at iteration {result.end_iteration}; checkpoint {summary['checkpoint']}", highlight=False
    )
    return code
