"""``amorctl data``: inspect motion datasets."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from amorctl.cli.options import JsonFlag
from amorctl.cli.output import console, print_json
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
