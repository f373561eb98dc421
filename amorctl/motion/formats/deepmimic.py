"""DeepMimic motion clips (JSON ``{"Loop": ..., "Frames": [[dt, 43 numbers], ...]}``).

Row layout: frame duration dt, root position (3), root quaternion (w, x, y, z), then chest (4),
neck (4), right hip (4), right knee (1), right ankle (4), right shoulder (4), right elbow (1),
left hip (4), left knee (1), left ankle (4), left shoulder (4), left elbow (1). Y is up. ``dt`` of
row i is the time from frame i to frame i+1 (the last row's dt is only used for looping).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.geometry import quat_from_rotvec, quat_mul, quat_normalize
from amorctl.motion.formats.base import ImportOptions, MotionFormatSpec, file_sha256
from amorctl.motion.source import (
    C_DM_TO_MJ,
    C_DM_TO_MJ_QUAT,
    CANONICAL_JOINTS,
    DEEPMIMIC_REVOLUTE,
    DEEPMIMIC_REVOLUTE_AXIS,
    SourceMotion,
    check_finite,
    check_times,
    deepmimic_skeleton,
)
from amorctl.registry import impl as hookimpl

#: Columns of one row after dt: joint -> number of values (4 = quaternion, 1 = hinge angle).
ROW_LAYOUT: tuple[tuple[str, int], ...] = (
    ("chest", 4),
    ("neck", 4),
    ("right_hip", 4),
    ("right_knee", 1),
    ("right_ankle", 4),
    ("right_shoulder", 4),
    ("right_elbow", 1),
    ("left_hip", 4),
    ("left_knee", 1),
    ("left_ankle", 4),
    ("left_shoulder", 4),
    ("left_elbow", 1),
)
ROW_WIDTH = 1 + 3 + 4 + sum(n for _, n in ROW_LAYOUT)  # 44
#: DeepMimic clips' licence as recorded in datasets.
DEEPMIMIC_LICENCE = "MIT (DeepMimic), via pybullet_data (zlib)"
#: Frame durations more than this factor away from the clip's median count as inconsistent.
MAX_DT_RATIO = 4.0


def conjugate_dm_quat(q_dm: np.ndarray) -> np.ndarray:
    """A DeepMimic (y-up) rotation expressed in MuJoCo axes: C q Cᵀ. q: [..., 4] -> [..., 4]."""
    c = np.broadcast_to(C_DM_TO_MJ_QUAT, q_dm.shape)
    c_inv = c * np.array([1.0, -1.0, -1.0, -1.0])
    return quat_mul(quat_mul(c, q_dm), c_inv)


def rows_to_source(rows: np.ndarray, path: str, name: str, sha256: str, licence: str) -> SourceMotion:
    """Convert DeepMimic rows [T, 44] into a SourceMotion in MuJoCo axes."""
    check_finite(path, "frame values", rows)
    dt = rows[:, 0]
    if len(rows) > 1:
        steps = dt[:-1]
        if (steps <= 0).any():
            frame = int(np.argmax(steps <= 0))
            raise AmorError(f"{path}: frame {frame} has duration {steps[frame]} (frame rate missing or bad)")
        med = float(np.median(steps))
        ratio = np.maximum(steps / med, med / steps)
        if (ratio > MAX_DT_RATIO).any():
            frame = int(np.argmax(ratio > MAX_DT_RATIO))
            raise AmorError(
                f"{path}: inconsistent frame rate: frame {frame} lasts {steps[frame]:.4g} s, "
                f"the clip's median is {med:.4g} s"
            )
    times = np.concatenate([[0.0], np.cumsum(dt[:-1])])
    check_times(path, times)
    root_pos = rows[:, 1:4] @ C_DM_TO_MJ.T
    local = np.zeros((len(rows), len(CANONICAL_JOINTS), 4))
    local[:, 0] = conjugate_dm_quat(_unit(rows[:, 4:8], path, "root"))
    col = 8
    for joint, width in ROW_LAYOUT:
        j = CANONICAL_JOINTS.index(joint)
        vals = rows[:, col : col + width]
        if width == 4:
            q_dm = _unit(vals, path, joint)
        else:
            assert joint in DEEPMIMIC_REVOLUTE
            q_dm = quat_from_rotvec(vals * DEEPMIMIC_REVOLUTE_AXIS)
        local[:, j] = conjugate_dm_quat(q_dm)
        col += width
    fps = 1.0 / float(np.median(dt[:-1])) if len(rows) > 1 else 0.0
    return SourceMotion(
        name=name,
        source=path,
        sha256=sha256,
        licence=licence,
        skeleton=deepmimic_skeleton(),
        times=times,
        root_pos=root_pos,
        local_quat=local,
        source_fps=fps,
    )


def _unit(q: np.ndarray, path: str, joint: str) -> np.ndarray:
    norms = np.linalg.norm(q, axis=-1)
    if (norms < 1e-6).any():
        frame = int(np.argmax(norms < 1e-6))
        raise AmorError(f"{path}: zero quaternion for joint {joint!r} at frame {frame}")
    return quat_normalize(q)


def load_deepmimic(path: Path, options: ImportOptions) -> SourceMotion:
    """Read a DeepMimic JSON clip; AmorError naming the file (and frame) on any defect."""
    text = _read_text(path)
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise AmorError(
            f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}): {exc.msg}"
        ) from None
    except RecursionError:
        raise AmorError(f"{path}: not a DeepMimic clip (JSON nested too deeply)") from None
    if not isinstance(doc, dict) or "Frames" not in doc:
        raise AmorError(f"{path}: not a DeepMimic clip (no 'Frames' list)")
    frames = doc["Frames"]
    if not isinstance(frames, list) or len(frames) == 0:
        raise AmorError(f"{path}: the clip has zero frames")
    for i, row in enumerate(frames):
        if not isinstance(row, list) or len(row) != ROW_WIDTH:
            got = len(row) if isinstance(row, list) else type(row).__name__
            raise AmorError(f"{path}: frame {i} has {got} values, expected {ROW_WIDTH}")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row):
            raise AmorError(f"{path}: frame {i} holds a value that is not a number")
    rows = np.asarray(frames, dtype=np.float64)
    name = options.name or path.stem.removeprefix("humanoid3d_")
    return rows_to_source(rows, str(path), name, file_sha256(path), options.licence)


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise AmorError(f"{path}: not a text file (cannot decode it as UTF-8)") from None
    except OSError as exc:
        raise AmorError(f"{path}: cannot read it: {exc.strerror}") from None


SPEC = MotionFormatSpec(
    name="deepmimic",
    suffixes=(".txt", ".json"),
    load=load_deepmimic,
    description="DeepMimic JSON clips (pybullet_data/data/motions)",
)


@hookimpl
def amorctl_register_motion_formats(register: Callable[[MotionFormatSpec], None]) -> None:
    """Register :data:`SPEC`."""
    register(SPEC)
