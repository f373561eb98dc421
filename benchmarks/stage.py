"""Train a shipped run one stage further (docs/train.md, "Training in stages").

A long run is trained in stages of at most ``--minutes`` of wall clock each, on any machine. A
stage copies the resumable entry ``SHELF/NAME`` (``amorctl runs export-pretrained --resumable``)
into ``WORK/NAME``, continues its training with the run's own config (settings never change
between stages: a stage takes no training options), evaluates the policy under uniform ``w`` per
motion family (survival over full episodes, joint MAE), and writes the entry back (built aside,
then swapped in) with the stage recorded on its card: commit, machine, wall clock, env steps and
iterations of the stage, the cumulative totals, the evaluation; and a figure of the evaluations
against cumulative env steps. A stage stopped with Ctrl-C ends like one that ran out of time (the
checkpoint it reached is written back, marked ``interrupted``).

The first stage creates the run from a preset (``--preset``, ``--character``, ``--dataset``,
``--clips`` to train on some of its clips, ``--set SECTION.KEY=VALUE``):

    python benchmarks/stage.py --run biped20-repertoire --minutes 150 --preset science --character biped20
    python benchmarks/stage.py --run biped20-repertoire --minutes 150        # every later stage
    python benchmarks/stage.py --run humanoid36-walk --minutes 150 --preset science \
        --character humanoid36 --clips walk --clips walker/            # the walking clips only
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import tomllib

sys.path.insert(0, str(Path(__file__).resolve().parent))
from science_args import config_setting
from science_runs import machine, metrics_rows

from amorctl.analysis.tracking_metrics import evaluate_setting
from amorctl.cli.live_view import fmt, fmt_time
from amorctl.core.config import TrainConfig, load_config, load_preset, override, to_toml
from amorctl.core.errors import AmorError
from amorctl.core.files import atomic_write_text
from amorctl.motion.cache import default_dataset
from amorctl.motion.dataset import load_dataset, load_encoder_bytes, write_dataset
from amorctl.plugins.backends.host import load_library
from amorctl.train import pretrained
from amorctl.train.episode_stats import clip_family
from amorctl.train.loop import train_run
from amorctl.train.metrics import family_survival
from amorctl.train.pretrained_export import DATASET_FILE, METRICS_EVERY, export_pretrained, git_commit
from amorctl.train.rundir import CONFIG_FILE, RunDir

#: ``run.iterations`` of a stage without ``--max-iterations``: the config's largest value (the
#: wall clock ends the stage long before; ``run.iterations`` only bounds the loop).
OPEN_ENDED = 100_000_000
FIGURE = "stages.png"
SURVIVAL_WINDOW = 25  # rows of the stage figure's moving mean of training survival
PROGRESS_EVERY_S = 60.0  # seconds between two progress lines while a stage trains


def first_config(args: argparse.Namespace) -> TrainConfig:
    """The new run's config: ``--preset`` (or ``--config``) with ``--character``, ``--dataset`` and
    ``--set``."""
    config = load_config(Path(args.config)) if args.config else load_preset(args.preset)
    if args.character:
        config = override(config, env__character=args.character)
    if args.dataset:
        config = override(config, env__dataset=str(Path(args.dataset).resolve()))
    for key, value, _text in args.set:
        config = override(config, **{key: value})
    if args.clips:
        subset = Path(args.work) / f"{args.run}-clips.mcap"  # beside the work copy; the entry copies it
        config = override(config, env__dataset=str(clip_subset(config, args.clips, subset).resolve()))
    return config


def clip_subset(config: TrainConfig, queries: list[str], out: Path) -> Path:
    """Write the clips of ``config``'s dataset that ``queries`` name (a clip's name, or a family
    prefix ending in ``/`` such as ``walker/``) to ``out``, with the dataset's motion encoder.

    Raises:
        AmorError: a query names no clip (the message lists the clips there are).
    """
    source = Path(config.env.dataset) if config.env.dataset else default_dataset(config.env.character)
    library = load_dataset(source)
    names = [c.name for c in library.clips]

    def named(name: str, query: str) -> bool:
        return name == query or (query.endswith("/") and name.startswith(query))

    for query in queries:
        if not any(named(n, query) for n in names):
            raise AmorError(f"--clips {query}: no such clip in {source}; clips: {', '.join(names)}")
    keep = [n for n in names if any(named(n, q) for q in queries)]
    out.parent.mkdir(parents=True, exist_ok=True)
    write_dataset(out, library.subset(keep), encoder=load_encoder_bytes(source))
    return out


def work_copy(entry: Path, work: Path) -> TrainConfig:
    """Copy the entry into ``work`` (replacing an older copy); the run's config, its dataset
    pointing at the copy."""
    if work.exists():
        shutil.rmtree(work)
    shutil.copytree(entry, work)
    for name in (pretrained.CARD_FILE, "README.md"):
        (work / name).unlink(missing_ok=True)
    config = load_config(work / CONFIG_FILE)
    if config.env.dataset == DATASET_FILE:  # the entry's own copy (its SHA-256 is checked on resume)
        config = override(config, env__dataset=str((work / DATASET_FILE).resolve()))
        atomic_write_text(work / CONFIG_FILE, to_toml(config))
    return config


def say(line: str) -> None:
    """Print a line of the stage's log at once (a stage often runs in the background under nohup,
    where stdout is block-buffered)."""
    print(line, flush=True)


def progress_printer(
    minutes: float, every_s: float = PROGRESS_EVERY_S
) -> Callable[[dict[str, float], int, float], None]:
    """``train_run``'s ``on_iteration`` for a stage: a line after the first iteration and then at
    most every ``every_s`` seconds, with the time spent of the budget, the iteration, the
    cumulative env steps, the pace, and the training episodes' length and survival (in all and
    per clip family)."""
    last = -math.inf

    def on_iteration(m: dict[str, float], _total: int, elapsed: float) -> None:
        nonlocal last
        if elapsed - last < every_s:
            return
        last = elapsed
        families = family_survival(m)
        say(
            f"{fmt_time(elapsed)} of {fmt_time(minutes * 60.0)}  it {int(m['iteration']):,}  "
            f"{int(m['env_steps']):,} env steps  {m['env_steps_per_s']:,.0f} steps/s "
            f"({'bf16' if m.get('bf16') else 'fp32'})  length {fmt(m['episode/length'], '.1f')}  "
            f"survival {fmt(m['episode/survival'], '.0%')}" + (f"  [{families}]" if families else "")
        )

    return on_iteration


def evaluate_clips(
    run: RunDir, episodes: int, seed: int, iteration: int | None = None
) -> dict[str, dict[str, float]]:
    """Survival and joint MAE under uniform ``w``, per clip ({} for envs without clips), of the
    checkpoint of ``iteration`` (None: the newest)."""
    config = run.config
    if config.env.kind != "tracking":
        return {}
    clips = [c.name for c in load_library(config.env.character, run.dataset_path()).clips]
    policy = run.policy(iteration)
    uniform = np.full(len(policy.objectives), 1.0 / len(policy.objectives))
    result = evaluate_setting(
        policy, config, uniform, label="uniform", motions=clips, episodes=episodes, seed=seed
    )
    return {
        clip: {"survival": float(m["survival_rate"]), "joint_mae_deg": float(m["joint_mae_deg"])}
        for clip, m in result.per_motion.items()
    }


def by_family(per_clip: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    """Per-clip figures averaged per motion family (``walker/turn_left0`` -> ``walker``)."""
    families: dict[str, list[dict[str, float]]] = {}
    for clip, metrics in per_clip.items():
        families.setdefault(clip_family(clip), []).append(metrics)
    return {
        family: {
            "survival": sum(m["survival"] for m in rows) / len(rows),
            "joint_mae_deg": sum(m["joint_mae_deg"] for m in rows) / len(rows),
        }
        for family, rows in families.items()
    }


def training_survival(
    run: Path, families: list[str], window: int = SURVIVAL_WINDOW
) -> dict[str, tuple[Any, Any]]:
    """{family: (env steps [T], survival of the training episodes [T])} from the run's metrics.csv
    (its ``survival/<family>`` columns at every ``METRICS_EVERY``-th iteration, the rows a shipped
    entry keeps, so a working copy and its entry draw the same curve; a moving mean over ``window``
    of those rows); {} when absent."""
    rows = [r for r in metrics_rows(run) if int(float(r["iteration"])) % METRICS_EVERY == 0]
    steps = np.array([float(r["env_steps"]) for r in rows])
    curves = {}
    for family in families:
        raw = np.array([float(r.get(f"survival/{family}") or "nan") for r in rows])
        ok = np.isfinite(raw)
        if ok.sum() >= window:
            curves[family] = (
                steps[ok][window - 1 :],
                np.convolve(raw[ok], np.ones(window) / window, "valid"),
            )
    return curves


def stage_precision(run: Path, after_iteration: int) -> str:
    """The network precision the backend chose in the iterations after ``after_iteration`` (its
    ``bf16`` metric: ``precision = "auto"`` resolves per machine, so two stages of one config can
    differ): ``bf16``, ``fp32``, ``bf16 in K of N iterations``, or ``unknown`` without metrics."""
    flags = [
        float(r["bf16"]) > 0
        for r in metrics_rows(run)
        if r.get("bf16") not in (None, "") and float(r["iteration"]) > after_iteration
    ]
    if not flags:
        return "unknown"
    if all(flags) or not any(flags):
        return "bf16" if flags[0] else "fp32"
    return f"bf16 in {sum(flags)} of {len(flags)} iterations"


def plot_stages(stages: list[dict[str, Any]], path: Path, run: Path | None = None) -> bool:
    """Survival and joint MAE per family against cumulative env steps (with ``run``, the run
    directory, also its training episodes' survival as lines); False without matplotlib or
    evaluations."""
    points = [(s["cumulative"]["env_steps"], s["evaluation"]) for s in stages if s.get("evaluation")]
    if not points:
        return False
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    fig, (ax_s, ax_m) = plt.subplots(1, 2, figsize=(12.5, 4), sharex=True)
    families = list(dict.fromkeys(f for _, ev in points for f in ev))
    colors = plt.get_cmap("tab20")  # one colour per family (the default cycle repeats after 10)
    for k, family in enumerate(families):
        style = {"color": colors(k % 20), "marker": "os^D"[k % 4], "label": family}
        xs = [x / 1e6 for x, ev in points if family in ev]
        ax_s.plot(xs, [ev[family]["survival"] for _, ev in points if family in ev], **style)
        ax_m.plot(xs, [ev[family]["joint_mae_deg"] for _, ev in points if family in ev], **style)
    for family, (x, y) in (training_survival(run, families) if run else {}).items():
        ax_s.plot(x / 1e6, y, color=colors(families.index(family) % 20), lw=0.8, alpha=0.6)
    ax_s.set(xlabel="cumulative env steps (M)", ylabel="survival over the episode", ylim=(-0.02, 1.02))
    ax_m.set(xlabel="cumulative env steps (M)", ylabel="joint MAE (deg)")
    for ax in (ax_s, ax_m):
        ax.grid(alpha=0.3)
    ax_m.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    lines = f"; training episodes' survival, mean over {SURVIVAL_WINDOW * METRICS_EVERY} iterations (lines)"
    title = "training stages: evaluation under uniform w at the end of each stage (markers)"
    fig.suptitle(title + (lines if run else ""))
    write_figure(fig, path)
    return True


def write_figure(fig: Any, path: Path | str) -> None:
    """Lay out, save (110 dpi) and close one figure of the stage benchmarks."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def taught_by(entry: Path) -> list[str]:
    """The other entries of ``entry``'s shelf that list it among their ``[distill] teachers`` (by its
    path, or as ``pretrained:NAME`` where the shelf is the package's): a newer checkpoint of
    ``entry`` would stop them from resuming (docs/distill.md)."""
    shelf = entry.parent.resolve()
    refs = {str(entry.resolve())}
    if shelf == pretrained.package_folder().resolve():
        refs.add(f"{pretrained.PREFIX}{entry.name}")
    students = []
    for other in sorted(shelf.iterdir()):
        config = other / "config.toml"
        if other.name == entry.name or not config.is_file():
            continue
        teachers = tomllib.loads(config.read_text()).get("distill", {}).get("teachers", [])
        if refs & {str(teacher) for teacher in teachers}:
            students.append(other.name)
    return students


def stage(args: argparse.Namespace) -> dict[str, Any]:
    """Run one stage; returns its card record."""
    if not pretrained.NAME_RE.match(args.run):
        raise AmorError(f"--run {args.run!r}: use lowercase letters, digits, '.', '_' or '-'")
    entry, work = Path(args.shelf) / args.run, Path(args.work) / args.run
    stages: list[dict[str, Any]] = []
    description = args.description
    if entry.exists():
        card = pretrained.read_card(entry)
        description = description or card.get("description", "")
        if not card.get("resumable"):
            raise AmorError(
                f"{entry}: not a resumable entry (its optimizer state was not kept): start a new run"
                f" from its networks (--set 'run.init_from=\"{entry}\"'), or export the run it came"
                " from with `runs export-pretrained --resumable`"
            )
        if args.preset or args.config or args.set or args.character or args.dataset or args.clips:
            raise AmorError(
                f"{entry} exists: a later stage continues with the run's own config "
                "(--preset, --config, --character, --dataset, --clips and --set only start a run)"
            )
        students = taught_by(entry)
        if students:
            raise AmorError(
                f"{entry}: {', '.join(students)} in the same shelf learned from this run ([distill] "
                "teachers), and a newer checkpoint here would stop them from resuming; train it further "
                f"in a copy (cp -r {entry} DIR/ and add --shelf DIR)"
            )
        stages = list(card.get("stages") or [])
        config = work_copy(entry, work)
        resume = True
    else:
        if not (args.preset or args.config):
            raise AmorError(f"{entry}: no such entry; the first stage needs --preset or --config")
        if work.exists():
            shutil.rmtree(work)
        config = first_config(args)
        resume = False
    before = RunDir(work).checkpoint().trainer.meta if resume else {}
    start_iteration, start_steps = int(before.get("iteration", 0)), int(before.get("env_steps", 0))
    iterations = start_iteration + args.max_iterations if args.max_iterations else OPEN_ENDED
    config = override(config, run__iterations=iterations)
    trained_by, trained_on = git_commit(Path.cwd()), machine()  # the code and machine at the start
    began = time.perf_counter()
    limit = args.minutes * 60.0
    step_limit = start_steps + args.budget_steps if args.budget_steps else None

    def stop(m: dict[str, float]) -> bool:
        if step_limit is not None and m.get("env_steps", 0) >= step_limit:
            return True
        return time.perf_counter() - began > limit

    start = f"resuming at iteration {start_iteration:,} ({start_steps:,} env steps)" if resume else "new run"
    say(
        f"stage {len(stages) + 1} of {args.run}: {start}, {args.minutes:g} min of training in {work} "
        f"(a line every {PROGRESS_EVERY_S:.0f} s; Ctrl-C ends the stage with a checkpoint)"
    )
    result = train_run(
        config,
        work,
        resume=resume,
        stop_when=stop,
        on_iteration=progress_printer(args.minutes),
        on_note=lambda note: say(f"note: {note}"),
    )
    wall = time.perf_counter() - began
    run = RunDir.open(work)
    after = run.checkpoint().trainer.meta
    say(f"evaluating iteration {int(after['iteration']):,}: uniform w, {args.eval_episodes} episode(s)/clip")
    per_clip = evaluate_clips(run, args.eval_episodes, args.eval_seed)
    previous = stages[-1]["cumulative"] if stages else {"env_steps": 0, "iterations": 0, "wall_clock_s": 0.0}
    record = {
        "stage": len(stages) + 1,
        "command": args.command_line,
        "commit": trained_by,
        "machine": trained_on,
        "precision": stage_precision(work, start_iteration),
        "wall_clock_s": round(wall, 1),
        "env_steps": int(after["env_steps"]) - start_steps,
        "iterations": int(after["iteration"]) - start_iteration,
        "cumulative": {
            "env_steps": int(after["env_steps"]),
            "iterations": int(after["iteration"]),
            "wall_clock_s": round(previous["wall_clock_s"] + wall, 1),
        },
        "interrupted": bool(result.signal),  # Ctrl-C or SIGTERM; the time or step budget is a normal end
        "evaluation": by_family(per_clip),
        "evaluation_clips": per_clip,
        "evaluation_protocol": f"uniform w, {args.eval_episodes} episodes per clip, seed {args.eval_seed}",
    }
    stages.append(record)
    figures = [work / FIGURE] if plot_stages(stages, work / FIGURE, work) else []
    total = record["cumulative"]
    export_pretrained(
        work,
        args.run,
        args.shelf,
        command=stages[0].get("command") or args.command_line,  # how the run was started
        description=description or f"{config.env.character or config.env.kind} trained in stages",
        commit=trained_by,  # the code that trained the checkpoint, not HEAD at the stage's end
        notes=f"{len(stages)} stages, {total['env_steps']:,} env steps, {total['wall_clock_s'] / 60:.0f} min",
        figures=figures,
        replace=True,
        resumable=True,
        stages=stages,
    )
    return record


def one_line_errors(call: Callable[..., Any], *args: Any) -> Any:
    """``call(*args)``; an AmorError becomes one line on stderr and its exit code, as amorctl's
    commands do (``AMORCTL_DEBUG=1``: the traceback)."""
    try:
        return call(*args)
    except AmorError as err:
        if os.environ.get("AMORCTL_DEBUG", "") not in ("", "0"):
            raise
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(err.exit_code) from None


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--run", required=True, help="the entry's name (pretrained:NAME)")
    parser.add_argument("--minutes", type=float, required=True, help="wall clock of this stage's training")
    parser.add_argument("--shelf", default="amorctl/pretrained", help="folder holding the entry")
    parser.add_argument("--work", default="runs/stages", help="folder of the working copies")
    parser.add_argument("--preset", default="", help="first stage: the preset to start from")
    parser.add_argument("--config", default="", help="first stage: a config file instead of a preset")
    parser.add_argument("--character", default="", help="first stage: the character")
    parser.add_argument("--dataset", default="", help="first stage: the clips (default: the built-in set)")
    parser.add_argument(
        "--clips",
        action="append",
        default=[],
        metavar="NAME",
        help="first stage: train on these clips of the dataset only (a name, or a family prefix "
        "ending in / such as walker/; repeatable)",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        type=config_setting,
        metavar="SECTION.KEY=VALUE",
        help="first stage",
    )
    parser.add_argument("--description", default="", help="one line for the card")
    parser.add_argument("--max-iterations", type=int, default=0, help="also end the stage after N iterations")
    parser.add_argument(
        "--budget-steps", type=int, default=0, help="also end the stage after N env steps (this stage's)"
    )
    parser.add_argument("--eval-episodes", type=int, default=8, help="episodes per clip at the stage's end")
    parser.add_argument("--eval-seed", type=int, default=1)
    args = parser.parse_args(argv)
    args.command_line = shlex.join(
        ["python", "benchmarks/stage.py", *(sys.argv[1:] if argv is None else argv)]
    )
    if args.budget_steps < 0 or args.max_iterations < 0:
        parser.error("--budget-steps and --max-iterations must be >= 0 (0: no such limit)")
    record = one_line_errors(stage, args)
    total = record["cumulative"]
    say(
        f"stage {record['stage']}: {record['iterations']:,} iterations, {record['env_steps']:,} env steps in "
        f"{record['wall_clock_s'] / 60:.1f} min; in all {total['iterations']:,} iterations, "
        f"{total['env_steps']:,} env steps"
    )
    for family, ev in record["evaluation"].items():
        say(f"  {family}: survival {ev['survival']:.0%}, joint MAE {ev['joint_mae_deg']:.1f}°")


if __name__ == "__main__":
    main()
