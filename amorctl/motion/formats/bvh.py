"""Biovision BVH files, mapped onto the canonical source skeleton by a TOML joint map.

The map (see ``docs/preprocess.md``)::

    [joints]            # canonical joint = BVH joint name; every canonical joint is required
    root = "Hips"
    chest = "Chest"
    ...
    [options]
    scale = 0.01        # BVH length unit -> metres (default 1.0)
    up = "y"            # the BVH file's up axis: "y" (the BVH convention, default) or "z"
    forward = "+x"      # the direction the rest pose faces, in BVH axes (CMU files: "+z")

BVH joints that the map does not name still take part in forward kinematics (their rotations are
folded into the mapped joints'). The rest pose (all channels zero) must be the canonical rest pose
(upright, arms down, facing +x after the up-axis change), as it is for files written from
DeepMimic clips. Rotation channels compose in the order listed: ``Zrotation Xrotation Yrotation``
means R = Rz Rx Ry; angles in degrees.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from amorctl.core.errors import AmorError
from amorctl.core.geometry import (
    quat_conj,
    quat_from_mat,
    quat_from_rotvec,
    quat_mul,
    quat_normalize,
    quat_rotate,
)
from amorctl.motion.formats.base import ImportOptions, MotionFormatSpec, file_sha256
from amorctl.motion.source import (
    C_DM_TO_MJ,
    CANONICAL_JOINTS,
    MAX_ABS_VALUE,
    Skeleton,
    SourceMotion,
    check_finite,
    check_times,
    deepmimic_skeleton,
    implausible,
)
from amorctl.registry import impl as hookimpl

_AXES = {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0]), "Z": np.array([0.0, 0.0, 1.0])}
_CHANNELS = {"Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation"}


@dataclass
class BvhJointDef:
    """One joint of a parsed BVH hierarchy."""

    name: str
    parent: int
    offset: np.ndarray
    channels: list[str]
    end_site: np.ndarray | None = None
    children: list[int] = field(default_factory=list)


@dataclass
class BvhFile:
    """A parsed BVH file: joints in file order, frame time and the motion table [T, channels]."""

    joints: list[BvhJointDef]
    frame_time: float
    motion: np.ndarray


class _Lines:
    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        self.lines = text.splitlines()
        self.i = 0

    def next_tokens(self) -> tuple[int, list[str]]:
        while self.i < len(self.lines):
            self.i += 1
            tokens = self.lines[self.i - 1].split()
            if tokens:
                return self.i, tokens
        raise AmorError(f"{self.path}: file ends early (line {self.i}): truncated BVH")

    def fail(self, line: int, what: str) -> AmorError:
        return AmorError(f"{self.path}: line {line}: {what}")


def parse_bvh(path: Path) -> BvhFile:
    """Parse a BVH file; AmorError naming the file and line on any syntax problem."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise AmorError(f"{path}: not a text file (cannot decode it as UTF-8)") from None
    lines = _Lines(path, text)
    line, tok = lines.next_tokens()
    if tok != ["HIERARCHY"]:
        raise lines.fail(line, "expected 'HIERARCHY' (not a BVH file)")
    line, tok = lines.next_tokens()
    if len(tok) != 2 or tok[0] != "ROOT":
        raise lines.fail(line, "expected 'ROOT <name>'")
    joints: list[BvhJointDef] = []
    try:
        _parse_joint(lines, tok[1], -1, joints)
    except RecursionError:
        raise AmorError(f"{path}: the joint hierarchy is nested too deeply") from None
    line, tok = lines.next_tokens()
    if tok != ["MOTION"]:
        raise lines.fail(line, "expected 'MOTION'")
    line, tok = lines.next_tokens()
    if len(tok) != 2 or tok[0] != "Frames:":
        raise lines.fail(line, "expected 'Frames: <count>'")
    try:
        count = int(tok[1])
    except ValueError:
        raise lines.fail(line, f"bad frame count {tok[1]!r}") from None
    if count <= 0:
        raise AmorError(f"{path}: line {line}: the clip has zero frames")
    line, tok = lines.next_tokens()
    if len(tok) != 3 or tok[:2] != ["Frame", "Time:"]:
        raise lines.fail(line, "expected 'Frame Time: <seconds>' (missing frame rate)")
    try:
        frame_time = float(tok[2])
    except ValueError:
        raise lines.fail(line, f"bad frame time {tok[2]!r}") from None
    if not np.isfinite(frame_time) or frame_time <= 0:
        raise lines.fail(line, f"frame time {tok[2]} is not a positive number (missing or bad frame rate)")
    width = sum(len(j.channels) for j in joints)
    rows = []
    for f in range(count):
        try:
            line, tok = lines.next_tokens()
        except AmorError:
            raise AmorError(
                f"{path}: file ends at frame {f} of {count} (line {lines.i}): truncated BVH"
            ) from None
        if len(tok) != width:
            raise lines.fail(line, f"frame {f} has {len(tok)} values, expected {width}")
        try:
            rows.append([float(t) for t in tok])
        except ValueError:
            raise lines.fail(line, f"frame {f} holds a value that is not a number") from None
    extra = sum(1 for rest in lines.lines[lines.i :] if rest.split())
    if extra:
        raise AmorError(
            f"{path}: line {line + 1}: the header says {count} frames ('Frames: {count}') but "
            f"{count + extra} rows follow"
        )
    motion = np.asarray(rows, dtype=np.float64).reshape(count, width)
    bad = implausible(motion)
    if bad.any():  # the first bad row; in its column no earlier row is bad
        f, c = (int(i) for i in np.argwhere(bad)[0])
        joint, channel = [(j.name, ch) for j in joints for ch in j.channels][c]
        check_finite(f"{path}: line {line - count + 1 + f}", f"joint {joint!r} {channel}", motion[:, c])
    return BvhFile(joints=joints, frame_time=frame_time, motion=motion)


def _parse_joint(lines: _Lines, name: str, parent: int, joints: list[BvhJointDef]) -> None:
    line, tok = lines.next_tokens()
    if tok != ["{"]:
        raise lines.fail(line, f"expected '{{' after joint {name!r}")
    line, tok = lines.next_tokens()
    if len(tok) != 4 or tok[0] != "OFFSET":
        raise lines.fail(line, f"expected 'OFFSET x y z' for joint {name!r}")
    offset = _floats(lines, line, tok[1:])
    line, tok = lines.next_tokens()
    if len(tok) < 2 or tok[0] != "CHANNELS":
        raise lines.fail(line, f"expected 'CHANNELS n ...' for joint {name!r}")
    try:
        n = int(tok[1])
    except ValueError:
        raise lines.fail(line, f"bad channel count {tok[1]!r}") from None
    channels = tok[2:]
    if len(channels) != n or not set(channels) <= _CHANNELS:
        raise lines.fail(line, f"bad CHANNELS line for joint {name!r}")
    index = len(joints)
    joints.append(BvhJointDef(name=name, parent=parent, offset=offset, channels=channels))
    if parent >= 0:
        joints[parent].children.append(index)
    while True:
        line, tok = lines.next_tokens()
        if tok == ["}"]:
            return
        if len(tok) == 2 and tok[0] == "JOINT":
            _parse_joint(lines, tok[1], index, joints)
        elif tok[:2] == ["End", "Site"]:
            line, tok = lines.next_tokens()
            if tok != ["{"]:
                raise lines.fail(line, "expected '{' after 'End Site'")
            line, tok = lines.next_tokens()
            if len(tok) != 4 or tok[0] != "OFFSET":
                raise lines.fail(line, "expected 'OFFSET x y z' in 'End Site'")
            joints[index].end_site = _floats(lines, line, tok[1:])
            line, tok = lines.next_tokens()
            if tok != ["}"]:
                raise lines.fail(line, "expected '}' closing 'End Site'")
        else:
            raise lines.fail(line, f"unexpected {' '.join(tok)!r} in joint {name!r}")


def _floats(lines: _Lines, line: int, tok: list[str]) -> np.ndarray:
    try:
        vals = np.array([float(t) for t in tok])
    except ValueError:
        raise lines.fail(line, "expected numbers") from None
    if not np.isfinite(vals).all():
        raise lines.fail(line, "non-finite value (NaN or inf)")
    if implausible(vals).any():
        raise lines.fail(line, f"offset beyond {MAX_ABS_VALUE:g} (implausibly large)")
    return vals


@dataclass(frozen=True)
class JointMap:
    """A TOML joint map: canonical joint -> BVH joint name, plus unit scale and up axis."""

    joints: dict[str, str]
    scale: float = 1.0
    up: str = "y"
    forward: str = "+x"

    def to_mujoco(self) -> np.ndarray:
        """[3, 3] rotation from BVH axes to MuJoCo axes with the rest pose facing +x (z up)."""
        m = C_DM_TO_MJ if self.up == "y" else np.eye(3)
        f = m @ (float(self.forward[0] + "1") * np.eye(3)["xyz".index(self.forward[1])])
        yaw = -np.arctan2(f[1], f[0])
        c, s = np.cos(yaw), np.sin(yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ m


def load_joint_map(path: Path) -> JointMap:
    """Read and check a TOML joint map; AmorError naming the file on any problem."""
    try:
        doc = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise AmorError(f"{path}: joint map not found") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise AmorError(f"{path}: not valid TOML: {exc}") from None
    unknown = set(doc) - {"joints", "options"}
    if unknown:
        raise AmorError(f"{path}: unknown table {sorted(unknown)[0]!r} (expected [joints] and [options])")
    joints = doc.get("joints", {})
    if not isinstance(joints, dict) or not all(isinstance(v, str) for v in joints.values()):
        raise AmorError(f"{path}: [joints] must map canonical joint names to BVH joint names (strings)")
    bad = set(joints) - set(CANONICAL_JOINTS)
    if bad:
        raise AmorError(
            f"{path}: {sorted(bad)[0]!r} is not a source-skeleton joint; known: {', '.join(CANONICAL_JOINTS)}"
        )
    missing = [j for j in CANONICAL_JOINTS if j not in joints]
    if missing:
        raise AmorError(f"{path}: no BVH joint given for {', '.join(missing)} in [joints]")
    opts = doc.get("options", {})
    extra = set(opts) - {"scale", "up", "forward"}
    if extra:
        raise AmorError(
            f"{path}: unknown option {sorted(extra)[0]!r} in [options] (known: scale, up, forward)"
        )
    scale = opts.get("scale", 1.0)
    up = opts.get("up", "y")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0 < scale <= MAX_ABS_VALUE:
        raise AmorError(
            f"{path}: [options] scale = {scale!r} must be a positive number (at most {MAX_ABS_VALUE:g})"
        )
    if up not in ("y", "z"):
        raise AmorError(f'{path}: [options] up must be "y" or "z"')
    forward = opts.get("forward", "+x")
    if forward not in ("+x", "-x", "+y", "-y", "+z", "-z") or forward[1] == up:
        raise AmorError(f"{path}: [options] forward must be one of +x, -x, +y, -y, +z, -z, not the up axis")
    return JointMap(joints=dict(joints), scale=float(scale), up=up, forward=forward)


def bvh_local_transforms(bvh: BvhFile) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame local translations [T, N, 3] and rotations [T, N, 4] of every BVH joint."""
    num_frames = bvh.motion.shape[0]
    trans = np.zeros((num_frames, len(bvh.joints), 3))
    rots = np.zeros((num_frames, len(bvh.joints), 4))
    col = 0
    for j, joint in enumerate(bvh.joints):
        trans[:, j] = joint.offset
        q = np.zeros((num_frames, 4))
        q[:, 0] = 1.0
        for ch in joint.channels:
            vals = bvh.motion[:, col]
            col += 1
            axis = _AXES[ch[0]]
            if ch.endswith("position"):
                trans[:, j, "XYZ".index(ch[0])] = vals
            else:
                q = quat_mul(q, quat_from_rotvec(np.deg2rad(vals)[:, None] * axis))
        rots[:, j] = q
    return trans, rots


def bvh_to_source(
    bvh: BvhFile, jmap: JointMap, path: str, name: str, sha256: str, licence: str
) -> SourceMotion:
    """Forward kinematics on the whole BVH tree, then read off the canonical joints."""
    names = [j.name for j in bvh.joints]
    for canon, bname in jmap.joints.items():
        if bname not in names:
            raise AmorError(f"{path}: joint {bname!r} (mapped to {canon!r}) is not in the file's hierarchy")
    trans, rots = bvh_local_transforms(bvh)
    trans = trans * jmap.scale
    num_frames = trans.shape[0]
    gpos = np.zeros_like(trans)
    grot = np.zeros_like(rots)
    rest = np.zeros((len(names), 3))  # rest-pose positions (all rotations identity)
    for j, joint in enumerate(bvh.joints):
        if joint.parent < 0:
            gpos[:, j] = trans[:, j]
            grot[:, j] = rots[:, j]
            rest[j] = joint.offset * jmap.scale
        else:
            p = joint.parent
            gpos[:, j] = gpos[:, p] + quat_rotate(grot[:, p], trans[:, j])
            grot[:, j] = quat_mul(grot[:, p], rots[:, j])
            rest[j] = rest[p] + joint.offset * jmap.scale
    # BVH axes -> MuJoCo axes (z up, rest pose facing +x): rotations conjugated, vectors rotated.
    m = jmap.to_mujoco()
    mq = np.broadcast_to(quat_from_mat(m), grot.shape)
    grot = quat_mul(quat_mul(mq, grot), quat_conj(mq))
    gpos = gpos @ m.T
    rest = rest @ m.T
    idx = [names.index(jmap.joints[c]) for c in CANONICAL_JOINTS]
    parents = deepmimic_skeleton().parents
    offsets = np.zeros((len(CANONICAL_JOINTS), 3))
    local = np.zeros((num_frames, len(CANONICAL_JOINTS), 4))
    for k, b in enumerate(idx):
        p = parents[k]
        if p < 0:
            local[:, k] = grot[:, b]
        else:
            offsets[k] = rest[b] - rest[idx[p]]
            local[:, k] = quat_mul(quat_conj(grot[:, idx[p]]), grot[:, b])
    local = quat_normalize(local)
    skeleton = Skeleton(
        names=CANONICAL_JOINTS,
        parents=parents,
        offsets=offsets,
        keypoints=_keypoints(bvh, jmap, rest, names),
    )
    times = np.arange(num_frames) * bvh.frame_time
    check_times(path, times)
    root_pos = gpos[:, idx[0]]
    check_finite(path, "root position", root_pos)
    return SourceMotion(
        name=name,
        source=path,
        sha256=sha256,
        licence=licence,
        skeleton=skeleton,
        times=times,
        root_pos=root_pos,
        local_quat=local,
        source_fps=1.0 / bvh.frame_time,
    )


def _keypoints(
    bvh: BvhFile, jmap: JointMap, rest: np.ndarray, names: list[str]
) -> dict[str, tuple[str, tuple[float, float, float]]]:
    """Hands sit at the tip of the elbow bone (first child or End Site); others at joints."""

    def tip(canon: str) -> tuple[float, float, float]:
        joint = bvh.joints[names.index(jmap.joints[canon])]
        if joint.children:
            off = bvh.joints[joint.children[0]].offset
        elif joint.end_site is not None:
            off = joint.end_site
        else:
            off = np.zeros(3)
        off = jmap.to_mujoco() @ (off * jmap.scale)
        return (float(off[0]), float(off[1]), float(off[2]))

    return {
        "root": ("root", (0.0, 0.0, 0.0)),
        "head": ("neck", (0.0, 0.0, 0.0)),
        "left_hand": ("left_elbow", tip("left_elbow")),
        "right_hand": ("right_elbow", tip("right_elbow")),
        "left_foot": ("left_ankle", (0.0, 0.0, 0.0)),
        "right_foot": ("right_ankle", (0.0, 0.0, 0.0)),
    }


def load_bvh(path: Path, options: ImportOptions) -> SourceMotion:
    """Read a BVH file with the joint map given in ``options.joint_map``."""
    if options.joint_map is None:
        raise AmorError(f"{path}: a BVH file needs a joint map (--map MAP.toml)")
    jmap = load_joint_map(options.joint_map)
    bvh = parse_bvh(path)
    names = {j.name for j in bvh.joints}
    missing = [b for b in jmap.joints.values() if b not in names]
    if missing:
        raise AmorError(
            f"{path}: joint {missing[0]!r} named in {options.joint_map} is not in the file's hierarchy"
        )
    return bvh_to_source(bvh, jmap, str(path), options.name or path.stem, file_sha256(path), options.licence)


SPEC = MotionFormatSpec(name="bvh", suffixes=(".bvh",), load=load_bvh, description="Biovision BVH + TOML map")


@hookimpl
def amorctl_register_motion_formats(register: Callable[[MotionFormatSpec], None]) -> None:
    """Register :data:`SPEC`."""
    register(SPEC)
