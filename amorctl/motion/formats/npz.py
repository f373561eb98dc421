"""Robot motion ``.npz`` (mjlab / BeyondMimic and qpos-style layouts), mapped onto a character.

Arrays: ``fps`` (scalar or [1]) and ``joint_pos`` [T, C] are required. Optional: ``joint_names``
[N], ``joint_vel`` [T, C] (checked, then recomputed from positions after resampling),
``body_pos_w`` [T, B, 3], ``body_quat_w`` [T, B, 4] (w, x, y, z; world z up), ``body_names`` [B].

Layouts of ``joint_pos`` (detected from the column count, N = the joints named or the
character's joint count):

- ``C == N``: joint angles only; the root pose comes from the body named like the character's
  root body in ``body_pos_w``/``body_quat_w``;
- ``C == 7 + N`` ("7 root + N joints", MuJoCo ``qpos`` order): root position (3), root quaternion
  (w, x, y, z), then the joints; body arrays are then optional.

Joints are matched to the character by ``joint_names`` when the file has them. Without names,
the columns are taken to be the character's joints in its order; if the file has body positions,
the character's forward kinematics of every frame must then reproduce them (bodies matched by
name) within :data:`FK_TOLERANCE`, else the file is refused with the error in metres.
"""

from __future__ import annotations

import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.geometry import quat_normalize
from amorctl.motion.formats.base import ImportOptions, MotionFormatSpec, file_sha256
from amorctl.motion.source import CharacterMotion, check_finite, check_times
from amorctl.registry import hookimpl

REQUIRED = ("fps", "joint_pos")
#: Largest body-position error (m) accepted when joint order is inferred from the character.
FK_TOLERANCE = 0.02
ROOT_COLUMNS = 7


def _read(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except ValueError as exc:
        raise AmorError(f"{path}: cannot read it as .npz without unpickling objects: {exc}") from None
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise AmorError(f"{path}: not a valid .npz file (truncated or garbage): {exc}") from None


def _names(arrays: dict[str, np.ndarray], key: str) -> list[str] | None:
    return [str(n) for n in np.asarray(arrays[key]).reshape(-1)] if key in arrays else None


def _layout(path: Path, cols: int, file_names: list[str] | None, wanted: list[str]) -> tuple[int, list[str]]:
    """(first joint column, joint names of the columns after it) from the column count."""
    n = len(file_names) if file_names is not None else len(wanted)
    if cols == n:
        return 0, file_names or list(wanted)
    if cols == ROOT_COLUMNS + n:
        return ROOT_COLUMNS, file_names or list(wanted)
    what = f"{len(file_names)} joint_names" if file_names is not None else f"the character's {n} joints"
    raise AmorError(
        f"{path}: joint_pos has {cols} columns; with {what} expected {n} (joints only) or "
        f"{ROOT_COLUMNS + n} (7 root + joints)"
    )


def _match(path: Path, names: list[str], wanted: list[str], character: str) -> list[int]:
    absent = [n for n in wanted if n not in names]
    unknown = [n for n in names if n not in wanted]
    if absent or unknown:
        parts = []
        if absent:
            parts.append(f"missing character joints {', '.join(absent)}")
        if unknown:
            parts.append(f"joints unknown to the character {', '.join(unknown)}")
        raise AmorError(f"{path}: joint names do not match character {character!r}: {'; '.join(parts)}")
    return [names.index(n) for n in wanted]


def verify_by_kinematics(
    path: Path,
    character: str,
    root_pos: np.ndarray,
    root_quat: np.ndarray,
    joint_pos: np.ndarray,
    body_names: list[str],
    body_pos: np.ndarray,
) -> float:
    """Max distance (m) between the character's FK and the file's body positions [T, B, 3].

    Raises:
        AmorError: no body name is shared, or the error exceeds :data:`FK_TOLERANCE`.
    """
    import mujoco

    from amorctl.motion.kinematics import character_kinematics
    from amorctl.registry import get_registry

    kin = character_kinematics(get_registry().character(character))
    bodies = kin.model
    shared = [b for b in body_names if mujoco.mj_name2id(bodies, mujoco.mjtObj.mjOBJ_BODY, b) > 0]
    if not shared:
        raise AmorError(
            f"{path}: no joint_names, and none of its body_names is a body of {character!r}: "
            "cannot check the joint order (add joint_names)"
        )
    pos, _ = kin.body_poses(kin.qpos(root_pos, root_quat, joint_pos), shared)
    cols = [body_names.index(b) for b in shared]
    err = np.linalg.norm(pos - body_pos[:, cols], axis=-1)  # [T, B]
    worst = float(err.max())
    if worst > FK_TOLERANCE:
        t, b = np.unravel_index(int(np.argmax(err)), err.shape)
        raise AmorError(
            f"{path}: no joint_names, and the columns in {character!r}'s joint order do not reproduce the "
            f"file's body positions: error {worst:.3f} m (body {shared[b]!r}, frame {int(t)}; "
            f"tolerance {FK_TOLERANCE} m): add joint_names"
        )
    return worst


def _fps(path: Path, arrays: dict[str, np.ndarray]) -> float:
    fps = np.asarray(arrays["fps"], dtype=np.float64).reshape(-1)
    if fps.size != 1 or not np.isfinite(fps[0]) or fps[0] <= 0:
        raise AmorError(f"{path}: 'fps' must be one positive number, got {arrays['fps']!r}")
    return float(fps[0])


def _body_poses(
    path: Path, arrays: dict[str, np.ndarray], num_frames: int
) -> tuple[list[str] | None, np.ndarray | None, np.ndarray | None]:
    """(body_names, body_pos_w [T, B, 3], body_quat_w [T, B, 4]), checked; the arrays are None
    unless the file has all three."""
    body_names = _names(arrays, "body_names")
    if not ("body_pos_w" in arrays and "body_quat_w" in arrays and body_names is not None):
        return body_names, None, None
    bpos = np.asarray(arrays["body_pos_w"], dtype=np.float64)
    bquat = np.asarray(arrays["body_quat_w"], dtype=np.float64)
    if bpos.shape != (num_frames, len(body_names), 3) or bquat.shape != (num_frames, len(body_names), 4):
        raise AmorError(
            f"{path}: body_pos_w {bpos.shape} / body_quat_w {bquat.shape} do not match "
            f"{num_frames} frames and {len(body_names)} body_names"
        )
    check_finite(str(path), "body_pos_w", bpos)
    check_finite(str(path), "body_quat_w", bquat)
    return body_names, bpos, bquat


def _root_pose(
    path: Path,
    options: ImportOptions,
    first: int,
    jpos: np.ndarray,
    body_names: list[str] | None,
    bpos: np.ndarray | None,
    bquat: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, str]:
    """The root's positions [T, 3] and unit quaternions [T, 4] (from 7 root columns of
    ``joint_pos`` [T, first + N], else the root body's poses) and the layout found."""
    if first == ROOT_COLUMNS:
        root_pos, root_quat, layout = jpos[:, :3].copy(), jpos[:, 3:7].copy(), "7 root + N joints"
    elif bpos is not None and bquat is not None and body_names and options.root_body in body_names:
        b = body_names.index(options.root_body)
        root_pos, root_quat, layout = bpos[:, b].copy(), bquat[:, b].copy(), "joints + body poses"
    else:
        raise AmorError(
            f"{path}: no root pose: joint_pos has no 7 root columns and there is no body named "
            f"{options.root_body!r} (the root of {options.character!r}) in body_names/body_pos_w"
        )
    norms = np.linalg.norm(root_quat, axis=-1)
    if (norms < 1e-6).any():
        raise AmorError(f"{path}: zero root quaternion at frame {int(np.argmax(norms < 1e-6))}")
    return root_pos, quat_normalize(root_quat), layout


def load_npz(path: Path, options: ImportOptions) -> CharacterMotion:
    """Read a robot motion file and map it onto ``options.character`` (see the module docstring)."""
    if options.character is None or not options.joint_names or options.root_body is None:
        raise AmorError(f"{path}: a robot .npz needs a target character (--character)")
    arrays = _read(path)
    missing = [k for k in REQUIRED if k not in arrays]
    if missing:
        what = "frame rate" if missing == ["fps"] else "arrays"
        raise AmorError(f"{path}: missing {what} {', '.join(missing)} (has: {', '.join(sorted(arrays))})")
    for key in (*REQUIRED, "joint_vel", "body_pos_w", "body_quat_w"):
        if key in arrays and arrays[key].dtype.kind not in "biuf":
            raise AmorError(f"{path}: {key!r} must hold numbers, not {arrays[key].dtype}")
    fps = _fps(path, arrays)
    jpos = np.asarray(arrays["joint_pos"], dtype=np.float64)
    if jpos.ndim != 2 or jpos.shape[0] == 0:
        raise AmorError(
            f"{path}: joint_pos must be [frames, joints] with at least one frame, got {jpos.shape}"
        )
    num_frames = jpos.shape[0]
    wanted = list(options.joint_names)
    file_names = _names(arrays, "joint_names")
    first, names = _layout(path, jpos.shape[1], file_names, wanted)
    cols = _match(path, names, wanted, options.character)
    if "joint_vel" in arrays and np.shape(arrays["joint_vel"]) != jpos.shape:
        raise AmorError(
            f"{path}: joint_vel {np.shape(arrays['joint_vel'])} does not match joint_pos {jpos.shape}"
        )
    body_names, bpos, bquat = _body_poses(path, arrays, num_frames)
    has_bodies = bpos is not None
    check_finite(str(path), "joint_pos", jpos)
    if "joint_vel" in arrays:
        check_finite(str(path), "joint_vel", np.asarray(arrays["joint_vel"], dtype=np.float64))
    times = np.arange(num_frames) / fps
    check_times(str(path), times)
    root_pos, root_quat, layout = _root_pose(path, options, first, jpos, body_names, bpos, bquat)
    joint_pos = jpos[:, first:][:, cols].copy()
    stats: dict = {
        "npz_layout": layout,
        "joint_names": "from the file" if file_names else "from the character",
    }
    if file_names is None and has_bodies:
        stats["fk_check_error_m"] = verify_by_kinematics(
            path, options.character, root_pos, root_quat, joint_pos, body_names, bpos
        )
    return CharacterMotion(
        name=options.name or path.stem,
        source=str(path),
        sha256=file_sha256(path),
        licence=options.licence,
        character=options.character,
        times=times,
        root_pos=root_pos,
        root_quat=root_quat,
        joint_pos=joint_pos,
        source_fps=fps,
        stats=stats,
    )


SPEC = MotionFormatSpec(
    name="npz", suffixes=(".npz",), load=load_npz, description="mjlab / BeyondMimic robot motion"
)


@hookimpl
def amorctl_register_motion_formats(register: Callable[[MotionFormatSpec], None]) -> None:
    """Register :data:`SPEC`."""
    register(SPEC)
