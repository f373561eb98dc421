"""Robot motion ``.npz`` in the mjlab / BeyondMimic layout, mapped onto a character by names.

Arrays: ``fps`` (scalar or [1]), ``joint_pos`` [T, N], ``joint_vel`` [T, N], ``body_pos_w``
[T, B, 3], ``body_quat_w`` [T, B, 4] (w, x, y, z; world z up), ``joint_names`` [N] and
``body_names`` [B] (strings). Names are required here: columns are matched to the character's
joints by name, never by position, and the root pose is read from the body named like the
character's root body. ``joint_vel`` is checked but velocities are recomputed from positions so
that they stay consistent with them after resampling.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.geometry import quat_normalize
from amorctl.motion.formats import Importer, ImportOptions, file_sha256, register_importer
from amorctl.motion.source import CharacterMotion, check_finite, check_times

REQUIRED = ("fps", "joint_pos", "body_pos_w", "body_quat_w")


def load_npz(path: Path, options: ImportOptions) -> CharacterMotion:
    """Read a robot motion file and map it onto ``options.character`` by joint and body names."""
    if options.character is None or not options.joint_names or options.root_body is None:
        raise AmorError(f"{path}: a robot .npz needs a target character (--character)")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except ValueError as exc:
        raise AmorError(f"{path}: cannot read it as .npz without unpickling objects: {exc}") from None
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise AmorError(f"{path}: not a valid .npz file (truncated or garbage): {exc}") from None
    missing = [k for k in REQUIRED if k not in arrays]
    if missing:
        what = "frame rate" if missing == ["fps"] else "arrays"
        raise AmorError(f"{path}: missing {what} {', '.join(missing)} (has: {', '.join(sorted(arrays))})")
    for key in ("joint_names", "body_names"):
        if key not in arrays:
            raise AmorError(
                f"{path}: no {key!r}: amorctl maps robot motion by names, never by array position"
            )
    fps_arr = np.asarray(arrays["fps"], dtype=np.float64).reshape(-1)
    if fps_arr.size != 1 or not np.isfinite(fps_arr[0]) or fps_arr[0] <= 0:
        raise AmorError(f"{path}: 'fps' must be one positive number, got {arrays['fps']!r}")
    fps = float(fps_arr[0])
    jpos = np.asarray(arrays["joint_pos"], dtype=np.float64)
    bpos = np.asarray(arrays["body_pos_w"], dtype=np.float64)
    bquat = np.asarray(arrays["body_quat_w"], dtype=np.float64)
    joint_names = [str(n) for n in np.asarray(arrays["joint_names"]).reshape(-1)]
    body_names = [str(n) for n in np.asarray(arrays["body_names"]).reshape(-1)]
    if jpos.ndim != 2 or jpos.shape[0] == 0:
        raise AmorError(
            f"{path}: joint_pos must be [frames, joints] with at least one frame, got {jpos.shape}"
        )
    num_frames = jpos.shape[0]
    if jpos.shape[1] != len(joint_names):
        raise AmorError(f"{path}: joint_pos has {jpos.shape[1]} columns but {len(joint_names)} joint_names")
    if bpos.shape != (num_frames, len(body_names), 3) or bquat.shape != (num_frames, len(body_names), 4):
        raise AmorError(
            f"{path}: body_pos_w {bpos.shape} / body_quat_w {bquat.shape} do not match "
            f"{num_frames} frames and {len(body_names)} body_names"
        )
    if "joint_vel" in arrays and np.shape(arrays["joint_vel"]) != jpos.shape:
        raise AmorError(
            f"{path}: joint_vel {np.shape(arrays['joint_vel'])} does not match joint_pos {jpos.shape}"
        )
    wanted = list(options.joint_names)
    absent = [n for n in wanted if n not in joint_names]
    unknown = [n for n in joint_names if n not in wanted]
    if absent or unknown:
        parts = []
        if absent:
            parts.append(f"missing character joints {', '.join(absent)}")
        if unknown:
            parts.append(f"joints unknown to the character {', '.join(unknown)}")
        raise AmorError(
            f"{path}: joint names do not match character {options.character!r}: {'; '.join(parts)}"
        )
    if options.root_body not in body_names:
        raise AmorError(
            f"{path}: no body named {options.root_body!r} (the root of {options.character!r}) in body_names"
        )
    check_finite(str(path), "joint_pos", jpos)
    check_finite(str(path), "body_pos_w", bpos)
    check_finite(str(path), "body_quat_w", bquat)
    if "joint_vel" in arrays:
        check_finite(str(path), "joint_vel", np.asarray(arrays["joint_vel"], dtype=np.float64))
    times = np.arange(num_frames) / fps
    check_times(str(path), times)
    b = body_names.index(options.root_body)
    root_quat = bquat[:, b]
    if (np.linalg.norm(root_quat, axis=-1) < 1e-6).any():
        frame = int(np.argmax(np.linalg.norm(root_quat, axis=-1) < 1e-6))
        raise AmorError(f"{path}: zero root quaternion at frame {frame}")
    cols = [joint_names.index(n) for n in wanted]
    return CharacterMotion(
        name=options.name or path.stem,
        source=str(path),
        sha256=file_sha256(path),
        licence=options.licence,
        character=options.character,
        times=times,
        root_pos=bpos[:, b].copy(),
        root_quat=quat_normalize(root_quat),
        joint_pos=jpos[:, cols].copy(),
        source_fps=fps,
    )


register_importer(
    Importer(name="npz", suffixes=(".npz",), load=load_npz, description="mjlab / BeyondMimic robot motion")
)
