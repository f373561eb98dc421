"""``amorctl runs``: list local and pretrained runs; make a pretrained entry from a run."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, print_json
from amorctl.core.errors import AmorError
from amorctl.train import pretrained
from amorctl.train.rundir import RunDir

app = typer.Typer(
    help="List runs (local or pretrained) and ship a run as a pretrained entry.", no_args_is_help=True
)


def _minutes(seconds: Any) -> str:
    return "–" if seconds is None or not math.isfinite(float(seconds)) else f"{float(seconds) / 60:.1f} min"


def _local_run(path: Path) -> dict[str, Any] | None:
    """One local run's row (None when ``path`` holds no run); damaged runs say why."""
    run = RunDir(path)
    if not run.config_path.is_file():
        return None
    row: dict[str, Any] = {
        "run": str(path),
        "character": None,
        "env_kind": None,
        "iteration": None,
        "survival": None,
        "problem": None,
    }
    try:
        cfg = run.config
        row["env_kind"] = cfg.env.kind
        row["character"] = cfg.env.character if cfg.env.kind == "tracking" else (cfg.env.gym_id or None)
        found = run.checkpoints()
        row["iteration"] = found[-1][0] if found else None
        if run.metrics_path.is_file():
            with run.metrics_path.open(newline="", encoding="utf-8") as f:
                last: dict[str, str] = {}
                for last in csv.DictReader(f):  # noqa: B007 (the last row is wanted)
                    pass
            value = float(last.get("episode/survival", "nan") or "nan")
            row["survival"] = value if math.isfinite(value) else None
    except AmorError as err:
        row["problem"] = str(err)
    return row


def local_runs(folder: Path) -> list[dict[str, Any]]:
    """Rows of :func:`_local_run` for ``folder`` itself if it is a run, else for its subfolders."""
    if not folder.is_dir():
        raise AmorError(f"{folder}: not a directory")
    own = _local_run(folder)
    if own is not None:
        return [own]
    rows = [_local_run(sub) for sub in sorted(folder.iterdir()) if sub.is_dir()]
    return [r for r in rows if r is not None]


def _families(motions: list[str]) -> str:
    """``walk, walker, run`` from clip names: their families, in order, a family of one clip named
    by that clip (``dance_a`` alone, not ``dance``)."""
    from amorctl.train.episode_stats import clip_family

    members: dict[str, list[str]] = {}
    for motion in motions:
        members.setdefault(clip_family(motion), []).append(motion)
    return ", ".join(clips[0] if len(clips) == 1 else family for family, clips in members.items())


#: A clip counts as tracked when this share of its evaluation episodes survive (the repertoire
#: targets' bar, docs/repertoire.md).
TRACKED_SURVIVAL = 0.9


def _headline(card: dict[str, Any]) -> str:
    """The entry's headline figures: its last stage's evaluation at uniform ``w`` (how many clips
    are tracked and which families, per clip when the stage recorded clips, else per family
    averaged), else the last training iteration's survival."""
    stages = card.get("stages") or []
    clips = stages[-1].get("evaluation_clips") if stages else None
    evaluation = stages[-1].get("evaluation") if stages else None
    if clips:
        tracked = [name for name, v in clips.items() if v["survival"] >= TRACKED_SURVIVAL]
        mean = sum(v["survival"] for v in clips.values()) / len(clips)
        mae = sum(v["joint_mae_deg"] for v in clips.values()) / len(clips)
        which = f" ({_families(tracked)})" if tracked else ""
        return (
            f"{len(tracked)}/{len(clips)} clips ≥ {TRACKED_SURVIVAL:.0%} survival{which}; "
            f"mean survival {mean:.0%}, joint MAE {mae:.1f}° (uniform w)"
        )
    if evaluation:
        survival = sum(v["survival"] for v in evaluation.values()) / len(evaluation)
        mae = sum(v["joint_mae_deg"] for v in evaluation.values()) / len(evaluation)
        return f"survival {survival:.0%}, joint MAE {mae:.1f}° (uniform w, per family)"
    value = (card.get("summary") or {}).get("episode/survival")
    return "–" if value is None else f"survival {value:.0%} (training)"


def _pretrained_block(reference: str, card: dict[str, Any]) -> str:
    """Three lines on a pretrained entry: what it was trained on and for how long, its headline
    figures, and how it was made."""
    motions = card.get("motions") or []
    noun = "clip" if len(motions) == 1 else "clips"
    clips = f"{len(motions)} {noun} ({_families(motions)})" if motions else "clips not recorded"
    stages = len(card.get("stages") or [])
    in_stages = f" in {stages} stage{'s' if stages != 1 else ''}" if stages else ""
    commit = (card.get("commit") or "an unrecorded commit")[:12]
    started = f" · started from {Path(card['init_from']).name}" if card.get("init_from") else ""
    return (
        f"\n{reference}  {card.get('character')} · {clips} · "
        f"{card.get('env_steps', 0) / 1e6:.1f} M env steps{in_stages}, {_minutes(card.get('wall_time_s'))}"
        f"{started}\n"
        f"  measured: {_headline(card)}\n"
        f"  {card.get('description') or '(no description)'}; trained by "
        f"`{card.get('command') or 'not recorded'}` at {commit}"
    )


@app.command("list")
def list_runs(
    folder: Annotated[Path, typer.Argument(help="Folder of run directories (or one run) to list.")] = Path(
        "runs"
    ),
    pretrained_only: Annotated[
        bool,
        typer.Option("--pretrained", help="List the pretrained runs instead, with how they were trained."),
    ] = False,
    json_out: JsonFlag = False,
) -> None:
    """Local runs in FOLDER (default ./runs), or with --pretrained the shipped pretrained runs."""
    if pretrained_only:
        found = pretrained.entries()
        doc: Any = {
            "folders": [str(f) for f in pretrained.search_folders()],
            "pretrained": [{"reference": e.reference, "path": str(e.path), **e.card} for e in found],
        }
        if json_out:
            print_json(doc)
            return
        if not found:
            console.print(
                f"no pretrained runs installed (searched: {', '.join(doc['folders'])}; "
                f"add folders with ${pretrained.PATH_ENV})",
                highlight=False,
            )
            return
        console.print("Pretrained runs (use as RUN: pretrained:<name>)", style="bold", highlight=False)
        for e in found:
            console.print(_pretrained_block(e.reference, e.card), highlight=False, soft_wrap=True)
        return
    rows = local_runs(folder)
    if json_out:
        print_json({"folder": str(folder), "runs": rows})
        return
    if not rows:
        console.print(f"no runs in {folder}", highlight=False)
        return
    table = Table(title=f"Runs in {folder}")
    for col in ("run", "env", "character", "newest checkpoint", "last survival", "problem"):
        table.add_column(col, overflow="fold")
    for r in rows:
        surv = "–" if r["survival"] is None else f"{r['survival']:.0%}"
        it = "–" if r["iteration"] is None else str(r["iteration"])
        table.add_row(r["run"], str(r["env_kind"]), str(r["character"]), it, surv, r["problem"] or "")
    console.print(table)


@app.command("export-pretrained")
def export_pretrained_cmd(
    run: Annotated[Path, typer.Argument(help="Run directory to ship.")],
    name: Annotated[str, typer.Option("--name", help="Entry name: RUN is then pretrained:NAME.")],
    out: Annotated[
        Path,
        typer.Option("--out", help="Folder receiving NAME/ (amorctl/pretrained ships it in the package)."),
    ],
    iteration: Annotated[
        int | None, typer.Option("--iteration", help="Checkpoint iteration (default: the newest).")
    ] = None,
    command: Annotated[str, typer.Option("--command", help="The command that trained the run.")] = "",
    description: Annotated[str, typer.Option("--description", help="One line on what it does.")] = "",
    notes: Annotated[str, typer.Option("--notes", help="Free text for the card (measured figures).")] = "",
    figure: Annotated[
        list[Path] | None, typer.Option("--figure", help="Image copied into the entry; repeatable.")
    ] = None,
    commit: Annotated[
        str | None,
        typer.Option("--commit", help="Code version (default: git HEAD of the current directory)."),
    ] = None,
    replace: Annotated[
        bool, typer.Option("--replace", help="Replace an existing entry of that name.")
    ] = False,
    resumable: Annotated[
        bool,
        typer.Option(
            "--resumable",
            help="Keep the whole training state (optimizer, RNG, env), so that the entry can be "
            "trained further with benchmarks/stage.py (about 4x the size).",
        ),
    ] = False,
    teacher: Annotated[
        bool,
        typer.Option(
            "--teacher",
            help="An entry only read as a kickstarting teacher ([distill] teachers): stripped, and "
            "its dataset without the motion encoder (about a fifth of the size).",
        ),
    ] = False,
    json_out: JsonFlag = False,
) -> None:
    """Write OUT/NAME: one checkpoint (without optimizer state unless --resumable), config, dataset,
    card.json, README.md."""
    from amorctl.train.pretrained_export import export_pretrained

    entry = export_pretrained(
        run,
        name,
        out,
        iteration=iteration,
        command=command,
        description=description,
        notes=notes,
        figures=figure or [],
        commit=commit,
        replace=replace,
        resumable=resumable,
        teacher=teacher,
    )
    size = sum(p.stat().st_size for p in entry.path.rglob("*") if p.is_file())
    if json_out:
        print_json({"path": str(entry.path), "bytes": size, "card": entry.card})
        return
    console.print(
        f"wrote {entry.path} ({size / 1e6:.1f} MB, iteration {entry.card['iteration']}); "
        f"use it as {entry.reference} once {entry.path.parent} is the package's pretrained/ folder "
        f"or listed in ${pretrained.PATH_ENV}",
        highlight=False,
        soft_wrap=True,
    )
