"""``preprocess``: mocap files in, retargeted frames + motion-VAE latents out, as an MCAP dataset.

Pipeline per clip: import (any registered format) -> resample to the character's control rate ->
retarget (skeleton sources) -> frames. Then the VAE is trained on all clips but the held-out ones
and z_t is stored for every frame. Nothing is written unless every step succeeded.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.files import check_writable
from amorctl.core.specs import CharacterSpec
from amorctl.motion.builtin import builtin_clips, source_label
from amorctl.motion.clips import ClipInfo, MotionLibrary
from amorctl.motion.dataset import write_dataset
from amorctl.motion.formats import ImportOptions, import_file
from amorctl.motion.formats.deepmimic import DEEPMIMIC_LICENCE
from amorctl.motion.frames import clip_arrays, frame_layout
from amorctl.motion.kinematics import CharacterKinematics, character_kinematics
from amorctl.motion.resample import resample_character, resample_source
from amorctl.motion.retarget import retarget
from amorctl.motion.retarget.robot import finish_robot_clip
from amorctl.motion.source import CharacterMotion, SourceMotion
from amorctl.motion.tempo import Tempo, retime
from amorctl.motion.vae import VaeConfig, encode, encoder_to_bytes, train_vae
from amorctl.registry import get_registry

USER_LICENCE = "unknown (user-supplied file)"
#: Clips the VAE holds out when preprocessing the built-in DeepMimic set: one turn in each
#: direction, whose kind of motion stays represented in training by its sibling clip. (With 20
#: clips, a held-out one-of-a-kind clip such as ``dance_b`` mostly measures novelty: see
#: docs/dataset.md.)
DEEPMIMIC_HOLDOUT: tuple[str, ...] = ("walker/turn_left1", "walker/turn_right1")


@dataclass
class Progress:
    """Callbacks the CLI uses to draw progress; all optional."""

    clip: Callable[[int, int, str], None] | None = None  # (index, total, clip name) after each clip
    vae_step: Callable[[int, int, float], None] | None = None  # (step, total steps, loss)


@dataclass
class PreprocessReport:
    """What :func:`preprocess` did: per-clip rows, VAE errors, timings (seconds)."""

    out: Path
    character: str
    fps: float
    clips: list[dict[str, Any]]
    num_frames: int
    vae: dict[str, Any] | None
    timings: dict[str, float] = field(default_factory=dict)


def gather_inputs(
    files: Sequence[Path], builtin: str | None, fmt: str | None = None, licence: str | None = None
) -> list[tuple[str | None, Path, str, str | None]]:
    """(clip name or None for the importer's default, path, licence, format or None to infer) of
    every input, in order; ``fmt`` applies to ``files`` only (built-in clips know their format),
    and so does ``licence`` (default: DeepMimic's for pybullet_data files, else "unknown")."""
    inputs: list[tuple[str | None, Path, str, str | None]] = []
    if builtin:
        inputs += [(name, path, DEEPMIMIC_LICENCE, "deepmimic") for name, path in builtin_clips(builtin)]
    for f in files:
        path = Path(f)
        lic = DEEPMIMIC_LICENCE if source_label(path).startswith("pybullet_data/") else USER_LICENCE
        if licence:
            lic = licence
        inputs.append((None, path, lic, fmt))
    if not inputs:
        raise AmorError("no motion given: pass FILES and/or --builtin deepmimic")
    return inputs


def import_clip(
    path: Path,
    name: str | None,
    licence: str,
    kin: CharacterKinematics,
    fmt: str | None,
    joint_map: Path | None,
) -> SourceMotion | CharacterMotion:
    """Import one file for ``kin``'s character (a skeleton motion, or a motion of the character
    itself)."""
    spec = kin.spec
    opts = ImportOptions(
        name=name,
        joint_map=joint_map,
        character=spec.name,
        joint_names=spec.joint_names(),
        root_body=spec.root_body,
        licence=licence,
    )
    return import_file(path, fmt, opts)


def process_motion(
    motion: SourceMotion | CharacterMotion,
    path: Path,
    kin: CharacterKinematics,
    max_joint_speed: float | None = None,
    tempo: float = 1.0,
) -> tuple[CharacterMotion, dict[str, np.ndarray]]:
    """Play an imported motion at ``tempo`` (:func:`~amorctl.motion.tempo.retime`), resample,
    retarget it (IK joints within ``max_joint_speed`` rad/s when given); returns the character
    motion and its frame arrays."""
    spec = kin.spec
    motion = retime(motion, tempo)
    hz = float(spec.control_hz)
    duration = float(motion.times[-1] - motion.times[0])
    if duration * hz < 1.0:  # resampled, it would be one frame: nothing to track
        raise AmorError(
            f"{path}: the clip lasts {duration:.3g} s, less than one control step at {hz:g} Hz "
            "(a frame rate far too high?); a motion needs at least 2 frames"
        )
    if isinstance(motion, CharacterMotion):
        if motion.character != spec.name:
            raise AmorError(f"{path}: holds motion for {motion.character!r}, not {spec.name!r}")
        char = finish_robot_clip(resample_character(motion, hz), kin)
    else:
        char = retarget(resample_source(motion, hz), kin, max_joint_speed)
    char = replace(char, source=source_label(path))
    if tempo != 1.0:
        char = replace(char, stats={**char.stats, "tempo": tempo})
    arrays = clip_arrays(char, kin, hz)
    for key, a in arrays.items():
        if not np.isfinite(a).all():
            frame = int(np.argwhere(~np.isfinite(a))[0][0])
            raise AmorError(f"{path}: processing produced a non-finite {key} at frame {frame}")
    return char, arrays


def process_clip(
    path: Path,
    name: str | None,
    licence: str,
    kin: CharacterKinematics,
    fmt: str | None,
    joint_map: Path | None,
    max_joint_speed: float | None = None,
) -> tuple[CharacterMotion, dict[str, np.ndarray]]:
    """Import, resample, retarget one file (:func:`import_clip`, then :func:`process_motion`)."""
    motion = import_clip(path, name, licence, kin, fmt, joint_map)
    return process_motion(motion, path, kin, max_joint_speed)


def joint_speed_bound(value: float | str | None, spec: CharacterSpec) -> float | None:
    """``--max-joint-speed``: None (the IK's default bound), a speed in rad/s (> 0), or ``"motor"``
    for the character's no-load speed; checked against the character before any work."""
    if value is None:
        return None
    if spec.retarget != "ik":
        raise AmorError(
            f"--max-joint-speed: character {spec.name!r} retargets by {spec.retarget!r}, which copies "
            "the source's joint angles; the bound applies to IK retargeting only"
        )
    if value == "motor":
        if spec.actuator.no_load_speed is None:
            raise AmorError(
                f"--max-joint-speed motor: character {spec.name!r} has no no-load speed in its "
                "actuator model; give a speed in rad/s"
            )
        return float(spec.actuator.no_load_speed)
    try:
        speed = float(value)
    except ValueError:
        raise AmorError(f"--max-joint-speed: {value!r} is neither a speed in rad/s nor 'motor'") from None
    if not (math.isfinite(speed) and speed > 0):
        raise AmorError(f"--max-joint-speed: {value!r} must be a positive speed in rad/s (or 'motor')")
    return speed


def preprocess(
    files: Sequence[Path],
    *,
    character: str,
    out: Path,
    builtin: str | None = None,
    fmt: str | None = None,
    joint_map: Path | None = None,
    vae: VaeConfig | None = VaeConfig(),  # noqa: B008 - frozen dataclass, safe as a default
    progress: Progress | None = None,
    licence: str | None = None,
    max_joint_speed: float | str | None = None,
    tempo: Tempo | None = None,
) -> PreprocessReport:
    """Build a motion dataset at ``out``; AmorError (and no file) on any bad input, and before any
    work when ``out``'s folder is not writable. ``max_joint_speed``: see :func:`joint_speed_bound`;
    ``tempo``: each clip's playback rate (:class:`~amorctl.motion.tempo.Tempo`)."""
    check_writable(Path(out).parent, "output folder", "make it writable or choose another --out")
    progress = progress or Progress()
    t0 = time.perf_counter()
    spec = get_registry().character(character)
    bound = joint_speed_bound(max_joint_speed, spec)
    kin = character_kinematics(spec)
    inputs = gather_inputs(files, builtin, fmt, licence)
    motions, per_clip = _process_clips(inputs, kin, joint_map, progress, bound, tempo or Tempo())
    t1 = time.perf_counter()

    lengths = np.array([a["frames"].shape[0] for a in per_clip], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    flat = {k: np.concatenate([a[k] for a in per_clip], axis=0) for k in per_clip[0]}
    vae_info: dict[str, Any] | None = None
    encoder_bytes = None
    z = np.zeros((flat["frames"].shape[0], 0), dtype=np.float32)
    if vae is not None:
        if builtin == "deepmimic" and not vae.holdout and not files:
            vae = replace(vae, holdout=DEEPMIMIC_HOLDOUT)
        z, encoder_bytes, vae_info = _vae_latents(flat["frames"], starts, lengths, motions, vae, progress)
    t2 = time.perf_counter()

    library = _library(kin, motions, starts, lengths, flat, z, vae_info)
    clip_stats = {m.name: {**m.stats, "duration_s": float(m.times[-1])} for m in motions}
    write_dataset(out, library, clip_stats=clip_stats, encoder=encoder_bytes)
    t3 = time.perf_counter()
    rows = [
        {
            "name": c.name,
            "source": c.source,
            "frames": c.num_frames,
            "duration_s": library.clip_duration(c),
            "source_fps": c.source_fps,
            "retarget_error_m": c.retarget_error,
            **_short_stats(clip_stats[c.name]),
        }
        for c in library.clips
    ]
    return PreprocessReport(
        out=Path(out),
        character=spec.name,
        fps=library.fps,
        clips=rows,
        num_frames=library.num_frames,
        vae=vae_info,
        timings={"clips": t1 - t0, "vae": t2 - t1, "write": t3 - t2, "total": t3 - t0},
    )


def _process_clips(
    inputs: list[tuple[str | None, Path, str, str | None]],
    kin: CharacterKinematics,
    joint_map: Path | None,
    progress: Progress,
    max_joint_speed: float | None = None,
    tempo: Tempo = Tempo(),  # noqa: B008 - frozen dataclass, safe as a default
) -> tuple[list[CharacterMotion], list[dict[str, np.ndarray]]]:
    """Import every input (clip names must be unique), resolve each clip's tempo against the
    names, then :func:`process_motion` each, in order."""
    imported: list[tuple[SourceMotion | CharacterMotion, Path]] = []
    for name, path, licence, clip_fmt in inputs:
        motion = import_clip(path, name, licence, kin, clip_fmt, joint_map)
        if any(m.name == motion.name for m, _ in imported):
            raise AmorError(f"{path}: a second clip named {motion.name!r} (rename the file)")
        imported.append((motion, path))
    rates = tempo.resolve([m.name for m, _ in imported])
    motions: list[CharacterMotion] = []
    per_clip: list[dict[str, np.ndarray]] = []
    for i, (motion, path) in enumerate(imported):
        char, arrays = process_motion(motion, path, kin, max_joint_speed, rates[motion.name])
        motions.append(char)
        per_clip.append(arrays)
        if progress.clip:
            progress.clip(i + 1, len(inputs), char.name)
    return motions, per_clip


def _vae_latents(
    frames: np.ndarray,
    starts: np.ndarray,
    lengths: np.ndarray,
    motions: list[CharacterMotion],
    vae: VaeConfig,
    progress: Progress,
) -> tuple[np.ndarray, bytes, dict[str, Any]]:
    """Train the VAE on frames [F, D] (clips at ``starts``/``lengths``); returns z [F, L], the
    encoder file's bytes and the dataset's ``vae`` metadata."""
    names = [m.name for m in motions]
    trained = train_vae(frames, starts, lengths, vae, progress=progress.vae_step, names=names)
    z = encode(trained.encoder, trained.mean, trained.std, frames, starts, lengths, vae.window)
    encoder_bytes = encoder_to_bytes(trained, frames.shape[1])
    vae_held = [names[k] for k in trained.heldout_clips]
    info = {
        **asdict(vae),
        "padding": "edge (clamp to the clip's first/last frame)",
        "heldout_clips": vae_held,
        "heldout_recon_mse": trained.heldout_error,
        "heldout_recon_mse_per_clip": dict(zip(vae_held, trained.heldout_per_clip, strict=True)),
        "untrained_heldout_recon_mse": trained.untrained_error,
        "train_recon_mse": trained.train_error,
        "error_units": "mean squared error per feature of standardised frames",
    }
    return z, encoder_bytes, info


def _library(
    kin: CharacterKinematics,
    motions: list[CharacterMotion],
    starts: np.ndarray,
    lengths: np.ndarray,
    flat: dict[str, np.ndarray],
    z: np.ndarray,
    vae_info: dict[str, Any] | None,
) -> MotionLibrary:
    """The in-memory dataset: every clip's arrays concatenated (``flat``), latents ``z`` [F, L]."""
    spec = kin.spec
    clips = tuple(
        ClipInfo(
            name=m.name,
            source=m.source,
            sha256=m.sha256,
            licence=m.licence,
            start=int(s),
            num_frames=int(n),
            source_fps=float(m.source_fps),
            retarget_error=float(m.retarget_error),
        )
        for m, s, n in zip(motions, starts, lengths, strict=True)
    )
    return MotionLibrary(
        character=spec.name,
        fps=float(spec.control_hz),
        joint_names=spec.joint_names(),
        end_effectors=tuple(spec.end_effectors),
        clips=clips,
        frames=flat["frames"],
        z=z,
        metadata={
            "frame_layout": frame_layout(spec.num_joints, len(spec.end_effectors)),
            "vae": vae_info,
            "keypoints": dict(spec.keypoints),
            "velocities": "forward finite differences at fps; last frame repeats the previous",
        },
        **{k: v for k, v in flat.items() if k != "frames"},
    )


def _short_stats(stats: dict[str, Any]) -> dict[str, Any]:
    keep = (
        "method",
        "floor_lift_max",
        "foot_sliding",
        "foot_sliding_source",
        "scale",
        "max_joint_speed",
        "tempo",
        "npz_layout",
        "penetration_before_lift_m",
        "lower_foot_hover_max",
        "fk_check_error_m",
        "body_names",
        "notes",
    )
    return {k: stats[k] for k in keep if k in stats}
