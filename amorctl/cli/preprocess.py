"""``amorctl preprocess``: mocap files in, an MCAP motion dataset out (docs/preprocess.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from amorctl.cli.options import CharacterOpt, JsonFlag
from amorctl.cli.output import console, err_console, print_json
from amorctl.motion.preprocess import PreprocessReport
from amorctl.motion.preprocess import Progress as Hooks
from amorctl.motion.preprocess import preprocess as run_preprocess
from amorctl.motion.tempo import parse_tempo
from amorctl.motion.vae import VaeConfig

_DEFAULT = VaeConfig()


def preprocess(
    character: CharacterOpt,
    out: Annotated[Path, typer.Option("--out", "-o", help="Dataset file to write (.mcap).")],
    files: Annotated[
        list[Path] | None, typer.Argument(help="Motion files (DeepMimic .txt/.json, .bvh, .npz).")
    ] = None,
    builtin: Annotated[
        str | None, typer.Option("--builtin", help="Add a built-in motion set: 'deepmimic' (20 clips).")
    ] = None,
    fmt: Annotated[
        str | None, typer.Option("--format", help="deepmimic | bvh | npz | a plugin's (default: by suffix).")
    ] = None,
    joint_map: Annotated[Path | None, typer.Option("--map", help="TOML joint map for BVH files.")] = None,
    licence: Annotated[
        str | None,
        typer.Option("--licence", help="Licence of the FILES, recorded per clip (default: unknown)."),
    ] = None,
    vae: Annotated[bool, typer.Option("--vae/--no-vae", help="Train the motion VAE and store z_t.")] = True,
    vae_epochs: Annotated[int, typer.Option(help="VAE training epochs.")] = _DEFAULT.epochs,
    vae_window: Annotated[
        int, typer.Option(help="VAE half window W (window = 2W+1 frames).")
    ] = _DEFAULT.window,
    vae_latent: Annotated[int, typer.Option(help="VAE latent size.")] = _DEFAULT.latent_dim,
    vae_kl_weight: Annotated[float, typer.Option(help="VAE KL weight.")] = _DEFAULT.kl_weight,
    holdout: Annotated[
        list[str] | None, typer.Option("--holdout", help="Clip held out of VAE training (repeatable).")
    ] = None,
    seed: Annotated[int, typer.Option(help="Random seed of the VAE.")] = _DEFAULT.seed,
    max_joint_speed: Annotated[
        str | None,
        typer.Option(
            "--max-joint-speed",
            help="IK retargeting: bound every joint's speed, rad/s, or 'motor' for the character's "
            "no-load speed (default: 30 rad/s, a solver bound).",
        ),
    ] = None,
    tempo: Annotated[
        list[str] | None,
        typer.Option(
            "--tempo",
            help="Play clips at this rate before retargeting (0.5 = half speed): FACTOR for every "
            "clip, CLIP=FACTOR for one (repeatable).",
        ),
    ] = None,
    json_out: JsonFlag = False,
) -> None:
    """Import, retarget onto --character, compute frames and VAE latents; write --out atomically."""
    cfg = (
        VaeConfig(
            epochs=vae_epochs,
            window=vae_window,
            latent_dim=vae_latent,
            kl_weight=vae_kl_weight,
            holdout=tuple(holdout or ()),
            seed=seed,
        )
        if vae
        else None
    )
    report = _run_with_progress(
        list(files or []),
        quiet=json_out,
        character=character,
        out=out,
        builtin=builtin,
        fmt=fmt,
        joint_map=joint_map,
        licence=licence,
        vae=cfg,
        max_joint_speed=max_joint_speed,
        tempo=parse_tempo(tempo or []),
    )
    if json_out:
        print_json(
            {
                "out": report.out,
                "character": report.character,
                "fps": report.fps,
                "num_frames": report.num_frames,
                "clips": report.clips,
                "vae": report.vae,
                "timings_s": report.timings,
            }
        )
        return
    _print_report(report)


def _run_with_progress(files: list[Path], *, quiet: bool, **kwargs: Any) -> PreprocessReport:
    """``motion.preprocess.preprocess(files, **kwargs)`` with progress bars for the clips and the VAE
    on stderr (none with ``quiet`` or when stderr is not a terminal)."""
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.fields[info]}"),
        console=err_console,
        transient=True,
        disable=quiet or not err_console.is_terminal,
    ) as bar:
        clips_task = bar.add_task("clips", total=None, info="")
        vae_task = bar.add_task("VAE", total=None, info="", visible=False)

        def on_clip(i: int, n: int, name: str) -> None:
            bar.update(clips_task, completed=i, total=n, info=name)

        def on_step(step: int, total: int, loss: float) -> None:
            bar.update(vae_task, completed=step, total=total, visible=True, info=f"loss {loss:.4f}")

        return run_preprocess(files, progress=Hooks(clip=on_clip, vae_step=on_step), **kwargs)


def _print_report(report: PreprocessReport) -> None:
    """The human-readable report: a table of clips, contact reports of robot clips, the VAE, timings."""
    table = Table(title=f"{report.out} ({report.character}, {report.fps:g} Hz)")
    table.add_column("clip", no_wrap=True)
    retimed = any("tempo" in c for c in report.clips)
    for col in ("frames", "seconds", "source fps", "retarget err (m)", "floor lift (m)"):
        table.add_column(col)
    if retimed:
        table.add_column("tempo")
    for c in report.clips:
        cells = [
            c["name"],
            str(c["frames"]),
            f"{c['duration_s']:.2f}",
            f"{c['source_fps']:.1f}",
            "-" if "npz_layout" in c else f"{c['retarget_error_m']:.4f}",  # robot clips: not retargeted
            f"{c.get('floor_lift_max', 0.0):.3f}",
        ]
        table.add_row(*cells, *([f"{c.get('tempo', 1.0):g}"] if retimed else []))
    console.print(table)
    for c in report.clips:
        if "npz_layout" in c:  # robot clips get a contact report instead of a retarget error
            console.print(
                f"{c['name']} ({c['npz_layout']}): penetration before lift "
                f"{c['penetration_before_lift_m']:.3f} m, lower foot hovers up to "
                f"{c['lower_foot_hover_max']:.3f} m, feet slide {c['foot_sliding']:.3f} m/s in contact",
                highlight=False,
            )
        for note in c.get("notes", ()):  # what the importer left out, e.g. npz velocities it recomputes
            console.print(f"note: {c['name']}: {note}", highlight=False, soft_wrap=True)
    if report.vae:
        v = report.vae
        console.print(
            f"VAE (W={v['window']}, L={v['latent_dim']}, KL {v['kl_weight']:g}, {v['epochs']} epochs): "
            f"held-out {', '.join(v['heldout_clips']) or '-'}: recon MSE {_fmt(v['heldout_recon_mse'])} "
            f"(untrained {_fmt(v['untrained_heldout_recon_mse'])}), train {_fmt(v['train_recon_mse'])}",
            highlight=False,
        )
    t = report.timings
    console.print(
        f"{len(report.clips)} clips, {report.num_frames} frames; {t['total']:.1f} s "
        f"(clips {t['clips']:.1f} s, VAE {t['vae']:.1f} s)",
        highlight=False,
    )


def _fmt(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.4f}"
