"""``amorctl data``: inspect motion datasets."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, print_json
from amorctl.core.errors import AmorError
from amorctl.motion.dataset import load_dataset

app = typer.Typer(help="Inspect motion datasets (.mcap).", no_args_is_help=True)


@app.command("show")
def show(
    dataset: Annotated[Path, typer.Argument(help="Dataset file written by `amorctl preprocess`.")],
    json_out: JsonFlag = False,
) -> None:
    """List the clips with frame counts, durations, sources and retargeting errors, and the
    SHA-256 of every array, of the attachment and of the metadata (checked while loading)."""
    lib = load_dataset(dataset)
    integrity = lib.metadata.get("integrity", {})
    clips = [
        {
            "name": c.name,
            "frames": c.num_frames,
            "duration_s": lib.clip_duration(c),
            "source": c.source,
            "source_fps": c.source_fps,
            "sha256": c.sha256,
            "licence": c.licence,
            "retarget_error_m": c.retarget_error,
        }
        for c in lib.clips
    ]
    if json_out:
        print_json(
            {
                "dataset": dataset,
                "character": lib.character,
                "fps": lib.fps,
                "num_frames": lib.num_frames,
                "frame_dim": lib.frame_dim,
                "latent_dim": lib.latent_dim,
                "joint_names": list(lib.joint_names),
                "end_effectors": list(lib.end_effectors),
                "vae": lib.metadata.get("vae"),
                "integrity": integrity,
                "clips": clips,
            }
        )
        return
    console.print(
        f"[bold]{dataset}[/bold]: character {lib.character}, {lib.fps:g} Hz, {len(clips)} clips, "
        f"{lib.num_frames} frames ({lib.num_frames / lib.fps:.1f} s), frame dim {lib.frame_dim}, "
        f"latent dim {lib.latent_dim}",
        highlight=False,
    )
    table = Table()
    table.add_column("clip", no_wrap=True)
    for col in ("frames", "seconds", "retarget err (m)", "source"):
        table.add_column(col)
    for c in clips:
        table.add_row(
            c["name"], str(c["frames"]), f"{c['duration_s']:.2f}", f"{c['retarget_error_m']:.4f}", c["source"]
        )
    console.print(table)
    console.print("licences: " + "; ".join(sorted({c["licence"] for c in clips})), highlight=False)
    if not integrity.get("verified"):
        console.print(
            f"integrity: not verified ({integrity.get('reason', 'no content hashes')}); "
            "re-run `amorctl preprocess` to add them",
            highlight=False,
        )
        return
    console.print("integrity: every SHA-256 below was verified while loading", highlight=False)
    for name, digest in integrity["sha256"].items():
        console.print(f"  {name:<{_WIDTH}} {digest}", highlight=False, soft_wrap=True)
    if not integrity.get("metadata_verified"):
        console.print(
            f"  metadata: not verified ({integrity.get('reason', 'no hash')}); "
            "re-run `amorctl preprocess` to add it",
            highlight=False,
            soft_wrap=True,
        )


_WIDTH = 12 + len("attachment:")  # the longest array or attachment name column


@app.command("speeds")
def speeds(
    dataset: Annotated[Path, typer.Argument(help="Dataset file written by `amorctl preprocess`.")],
    json_out: JsonFlag = False,
) -> None:
    """How fast each clip asks the character's joints to turn, against its motors' no-load speed
    (a servo has no driving torque left above it): median and 95th-percentile joint speed, the
    share of joint samples above it, and the joint most often there (docs/preprocess.md)."""
    from amorctl.analysis.speed_demand import speed_demand
    from amorctl.registry import get_registry

    lib = load_dataset(dataset)
    registry = get_registry()
    if lib.character not in registry.names("character"):
        installed = ", ".join(registry.names("character"))
        raise AmorError(
            f"{dataset}: its character {lib.character!r} is not installed (installed: {installed})"
        )
    spec = registry.character(lib.character)
    limit = spec.actuator.no_load_speed
    rows = speed_demand(lib, limit)
    if json_out:
        print_json(
            {
                "dataset": dataset,
                "character": lib.character,
                "no_load_speed_rad_s": limit,
                "clips": [dataclasses.asdict(r) for r in rows],
            }
        )
        return
    limit_text = (
        f"no-load speed {limit:.2f} rad/s" if limit else "no torque–speed limit in its actuator model"
    )
    console.print(
        f"[bold]{dataset}[/bold]: character {lib.character}, {limit_text}; joint speeds |q̇| in rad/s "
        "(p50, p95)" + ("; above = faster than the no-load speed" if limit else ""),
        highlight=False,
    )
    table = Table()
    table.add_column("clip", no_wrap=True)
    for col in ("p50", "p95") + (
        ("p95/limit", "samples above", "frames above", "joint most above") if limit else ()
    ):
        table.add_column(col)
    for r in rows:
        cells = [r.clip, f"{r.p50_rad_s:.2f}", f"{r.p95_rad_s:.2f}"]
        if limit:
            cells += [
                f"{r.p95_ratio:.2f}",
                f"{r.share_above:.1%}",
                f"{r.frames_above:.1%}",
                r.fastest_joint or "–",
            ]
        table.add_row(*cells)
    console.print(table)
