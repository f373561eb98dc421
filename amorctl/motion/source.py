"""The canonical source skeleton and the two motion records that flow through preprocessing.

Every importer returns either a :class:`SourceMotion` (a skeleton animation: mocap such as
DeepMimic JSON or BVH, still to be retargeted) or a :class:`CharacterMotion` (joint angles that
already belong to one character, such as a robot ``.npz``). Both live in MuJoCo's world frame
(z up, metres, radians, quaternions (w, x, y, z)).

The canonical source skeleton is the DeepMimic humanoid's: 13 joints named below, with the
DeepMimic rest pose (zero rotation everywhere = standing upright, arms down, facing +x). A BVH
file is mapped onto these names by a TOML joint map.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.geometry import quat_mul, quat_rotate

#: DeepMimic (y up) -> MuJoCo (z up): +90° about x, (x, y, z) -> (x, -z, y).
C_DM_TO_MJ = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: The same rotation as a quaternion (w, x, y, z).
C_DM_TO_MJ_QUAT = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0])

#: Global scale pybullet (and DeepMimic) apply to ``humanoid.urdf``.
DEEPMIMIC_SCALE = 0.25

#: Canonical joint names, parents first. Knees and elbows are 1-DoF in DeepMimic but stored as
#: quaternions like every other joint.
CANONICAL_JOINTS: tuple[str, ...] = (
    "root",
    "chest",
    "neck",
    "right_hip",
    "right_knee",
    "right_ankle",
    "right_shoulder",
    "right_elbow",
    "left_hip",
    "left_knee",
    "left_ankle",
    "left_shoulder",
    "left_elbow",
)
#: DeepMimic's hinge joints and their axis in the joint's own (DeepMimic, y-up) frame.
DEEPMIMIC_REVOLUTE: tuple[str, ...] = ("right_knee", "right_elbow", "left_knee", "left_elbow")
DEEPMIMIC_REVOLUTE_AXIS = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Skeleton:
    """A kinematic tree of ball joints.

    names [J]; parents [J] (-1 for the root, parents before children); offsets [J, 3] of each joint
    from its parent joint in the parent's frame (MuJoCo axes, metres); keypoints: KEYPOINTS name ->
    (joint name, offset [3] in that joint's frame).
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    keypoints: dict[str, tuple[str, tuple[float, float, float]]]

    def index(self, name: str) -> int:
        return self.names.index(name)


def _dm(v: tuple[float, float, float]) -> tuple[float, float, float]:
    """A DeepMimic URDF offset (y up, unscaled) in MuJoCo axes, scaled."""
    x, y, z = (DEEPMIMIC_SCALE * np.asarray(v)) @ C_DM_TO_MJ.T
    return (float(x), float(y), float(z))


def deepmimic_skeleton() -> Skeleton:
    """The DeepMimic humanoid (``pybullet_data/humanoid/humanoid.urdf`` at scale 0.25)."""
    urdf = {  # child: (parent, offset in the parent's DeepMimic frame, unscaled)
        "root": (None, (0.0, 0.0, 0.0)),
        "chest": ("root", (0.0, 0.944604, 0.0)),
        "neck": ("chest", (0.0, 0.895576, 0.0)),
        "right_hip": ("root", (0.0, 0.0, 0.339548)),
        "right_knee": ("right_hip", (0.0, -1.686184, 0.0)),
        "right_ankle": ("right_knee", (0.0, -1.639480, 0.0)),
        "right_shoulder": ("chest", (-0.0962, 0.974, 0.73244)),
        "right_elbow": ("right_shoulder", (0.0, -1.099152, 0.0)),
        "left_hip": ("root", (0.0, 0.0, -0.339548)),
        "left_knee": ("left_hip", (0.0, -1.686184, 0.0)),
        "left_ankle": ("left_knee", (0.0, -1.639480, 0.0)),
        "left_shoulder": ("chest", (-0.0962, 0.974, -0.73244)),
        "left_elbow": ("left_shoulder", (0.0, -1.099152, 0.0)),
    }
    names = CANONICAL_JOINTS
    parents = tuple(-1 if urdf[n][0] is None else names.index(urdf[n][0]) for n in names)
    offsets = np.array([_dm(urdf[n][1]) for n in names])
    keypoints = {
        "root": ("root", (0.0, 0.0, 0.0)),
        "head": ("neck", (0.0, 0.0, 0.0)),  # the neck joint: character key points are body origins
        "left_hand": ("left_elbow", _dm((0.0, -1.035788, 0.0))),  # the fixed wrist
        "right_hand": ("right_elbow", _dm((0.0, -1.035788, 0.0))),
        "left_foot": ("left_ankle", (0.0, 0.0, 0.0)),
        "right_foot": ("right_ankle", (0.0, 0.0, 0.0)),
    }
    return Skeleton(names=names, parents=parents, offsets=offsets, keypoints=keypoints)


@dataclass(frozen=True)
class SourceMotion:
    """A skeleton animation in MuJoCo axes, before retargeting.

    times [T] seconds from 0, strictly increasing; root_pos [T, 3]; local_quat [T, J, 4]: each
    joint's rotation relative to its parent (joint 0: the root's world orientation).
    """

    name: str
    source: str
    sha256: str
    licence: str
    skeleton: Skeleton
    times: np.ndarray
    root_pos: np.ndarray
    local_quat: np.ndarray
    source_fps: float
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class CharacterMotion:
    """Poses of one character: a free root plus its actuated joints, in the character's order.

    times [T] seconds; root_pos [T, 3]; root_quat [T, 4]; joint_pos [T, J] radians.
    """

    name: str
    source: str
    sha256: str
    licence: str
    character: str
    times: np.ndarray
    root_pos: np.ndarray
    root_quat: np.ndarray
    joint_pos: np.ndarray
    source_fps: float
    retarget_error: float = 0.0
    stats: dict = field(default_factory=dict)

    @classmethod
    def retargeted(
        cls,
        source: SourceMotion,
        character: str,
        root_pos: np.ndarray,
        root_quat: np.ndarray,
        joint_pos: np.ndarray,
        stats: dict,
    ) -> CharacterMotion:
        """Poses retargeted from ``source``, keeping its name, provenance, times and frame rate."""
        return cls(
            name=source.name,
            source=source.source,
            sha256=source.sha256,
            licence=source.licence,
            character=character,
            times=source.times,
            root_pos=root_pos,
            root_quat=root_quat,
            joint_pos=joint_pos,
            source_fps=source.source_fps,
            stats=stats,
        )


def forward_kinematics(
    skeleton: Skeleton, root_pos: np.ndarray, local_quat: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World positions and orientations of every joint.

    root_pos [T, 3], local_quat [T, J, 4] -> (pos [T, J, 3], quat [T, J, 4]).
    """
    num_joints = len(skeleton.names)
    pos = np.zeros((*local_quat.shape[:-1], 3))
    quat = np.zeros(local_quat.shape)
    for j in range(num_joints):
        p = skeleton.parents[j]
        if p < 0:
            pos[:, j] = root_pos
            quat[:, j] = local_quat[:, j]
        else:
            pos[:, j] = pos[:, p] + quat_rotate(
                quat[:, p], np.broadcast_to(skeleton.offsets[j], pos[:, p].shape)
            )
            quat[:, j] = quat_mul(quat[:, p], local_quat[:, j])
    return pos, quat


def keypoint_positions(motion: SourceMotion) -> dict[str, np.ndarray]:
    """World positions of the skeleton's key points: KEYPOINTS name -> [T, 3]."""
    pos, quat = forward_kinematics(motion.skeleton, motion.root_pos, motion.local_quat)
    out = {}
    for key, (joint, offset) in motion.skeleton.keypoints.items():
        j = motion.skeleton.index(joint)
        out[key] = pos[:, j] + quat_rotate(quat[:, j], np.broadcast_to(np.asarray(offset), pos[:, j].shape))
    return out


#: Largest magnitude any imported value may have (metres, radians, degrees, seconds): beyond it the
#: number is corrupt, and float32 frames or velocities computed from it would overflow.
MAX_ABS_VALUE = 1.0e6
#: Longest clip accepted, in seconds (resampling allocates duration * control rate frames).
MAX_CLIP_SECONDS = 3600.0


def implausible(values: np.ndarray) -> np.ndarray:
    """True where a value is NaN, inf or beyond :data:`MAX_ABS_VALUE`: the one plausibility bound
    every importer applies to every number it reads (positions, angles, channels, velocities)."""
    with np.errstate(invalid="ignore"):
        return ~(np.abs(np.asarray(values, dtype=np.float64)) <= MAX_ABS_VALUE)


def check_finite(path: str, what: str, values: np.ndarray, axis_frames: int = 0) -> None:
    """Raise AmorError naming the file and the first frame holding NaN, inf or a value beyond
    :data:`MAX_ABS_VALUE` (:func:`implausible`)."""
    values = np.asarray(values, dtype=np.float64)
    bad = implausible(values)
    if not bad.any():
        return
    index = tuple(int(i) for i in np.argwhere(bad)[0])
    frame = index[axis_frames]
    if not np.isfinite(values[index]):
        raise AmorError(f"{path}: non-finite value (NaN or inf) in {what} at frame {frame}")
    raise AmorError(
        f"{path}: value {values[index]:.4g} in {what} at frame {frame} is implausibly large "
        f"(|x| > {MAX_ABS_VALUE:g})"
    )


def check_times(path: str, times: np.ndarray) -> None:
    """Frame times must be finite and strictly increasing, with at least two frames, spanning at
    most :data:`MAX_CLIP_SECONDS`."""
    if times.size == 0:
        raise AmorError(f"{path}: the clip has zero frames")
    if times.size == 1:
        raise AmorError(f"{path}: the clip has only one frame; a motion needs at least 2")
    if not np.isfinite(times).all():
        check_finite(path, "frame times", times)
    if float(times[-1] - times[0]) > MAX_CLIP_SECONDS:
        raise AmorError(
            f"{path}: the clip lasts {float(times[-1] - times[0]):.4g} s, more than {MAX_CLIP_SECONDS:g} s "
            "(a frame time or frame rate that is far off?)"
        )
    steps = np.diff(times)
    if steps.size and (steps <= 0).any():
        frame = int(np.argmax(steps <= 0)) + 1
        raise AmorError(f"{path}: frame times do not increase at frame {frame} (missing or bad frame rate)")
