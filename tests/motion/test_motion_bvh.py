"""BVH round trip: real DeepMimic clips written by an independent library (bvhio), read back.

Tolerances (bvhio computes in float32 and writes 9 decimals): joint rotations within 1e-4 rad,
root positions within 1e-5 m.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amorctl.core.errors import AmorError
from amorctl.core.geometry import quat_conj, quat_mul, quat_to_rotvec
from amorctl.motion.formats import ImportOptions, import_file
from amorctl.motion.source import (
    C_DM_TO_MJ,
    C_DM_TO_MJ_QUAT,
    CANONICAL_JOINTS,
    SourceMotion,
    deepmimic_skeleton,
)

bvhio = pytest.importorskip("bvhio", reason="bvhio (test extra) writes the BVH files")
glm = pytest.importorskip("glm")

IDENTITY_MAP = "[joints]\n" + "".join(f'{j} = "{j}"\n' for j in CANONICAL_JOINTS)
#: BVH tip offsets (DeepMimic frame, metres) for joints without children.
END_SITES = {
    "neck": (0.0, 0.175, 0.0),
    "right_elbow": (0.0, -0.258947, 0.0),
    "left_elbow": (0.0, -0.258947, 0.0),
    "right_ankle": (0.045, -0.0225, 0.0),
    "left_ankle": (0.045, -0.0225, 0.0),
}


def _to_dm(q_mj: np.ndarray) -> np.ndarray:
    """Rotation in MuJoCo axes back to DeepMimic (y-up) axes: Cᵀ q C."""
    c = np.broadcast_to(C_DM_TO_MJ_QUAT, q_mj.shape)
    return quat_mul(quat_mul(quat_conj(c), q_mj), c)


def write_bvh(motion: SourceMotion, path: Path, frame_time: float) -> None:
    """Write ``motion`` (uniformly timed) as a y-up BVH with bvhio's own writer."""
    skel = motion.skeleton
    offsets = skel.offsets @ C_DM_TO_MJ  # rows: Cᵀ v
    root_dm = motion.root_pos @ C_DM_TO_MJ
    local_dm = _to_dm(motion.local_quat)
    joints = []
    for j, name in enumerate(skel.names):
        bj = bvhio.BvhJoint(name, glm.vec3(*offsets[j]))
        bj.Channels = (["Xposition", "Yposition", "Zposition"] if j == 0 else []) + [
            "Zrotation",
            "Xrotation",
            "Yrotation",
        ]
        if name in END_SITES:
            bj.EndSite = glm.vec3(*END_SITES[name])
        for t in range(motion.times.shape[0]):
            w, x, y, z = local_dm[t, j]
            pos = glm.vec3(*root_dm[t]) if j == 0 else glm.vec3(*offsets[j])
            bj.Keyframes.append(bvhio.Pose(position=pos, rotation=glm.quat(w, x, y, z)))
        joints.append(bj)
        if skel.parents[j] >= 0:
            joints[skel.parents[j]].Children.append(bj)
    container = bvhio.BvhContainer(joints[0], motion.times.shape[0], frame_time)
    bvhio.writeBvh(str(path), container, percision=9)


@pytest.fixture()
def joint_map(tmp_path: Path) -> Path:
    p = tmp_path / "deepmimic.toml"
    p.write_text(IDENTITY_MAP + '[options]\nscale = 1.0\nup = "y"\n')
    return p


@pytest.mark.parametrize("clip", ["walk", "backflip", "cartwheel"])
def test_bvh_round_trip(clip, clip_path, tmp_path, joint_map):
    src = import_file(clip_path(clip), None, ImportOptions(name=clip))
    dt = float(np.median(np.diff(src.times)))
    uniform = SourceMotion(**{**src.__dict__, "times": np.arange(src.times.shape[0]) * dt})
    bvh_path = tmp_path / f"{clip}.bvh"
    write_bvh(uniform, bvh_path, dt)
    back = import_file(bvh_path, None, ImportOptions(joint_map=joint_map))
    assert back.times.shape == src.times.shape
    assert back.source_fps == pytest.approx(1 / dt, rel=1e-6)
    np.testing.assert_allclose(back.root_pos, src.root_pos, atol=1e-5)
    angle = np.linalg.norm(quat_to_rotvec(quat_mul(quat_conj(src.local_quat), back.local_quat)), axis=-1)
    assert angle.max() < 1e-4
    np.testing.assert_allclose(back.skeleton.offsets, deepmimic_skeleton().offsets, atol=1e-6)
    np.testing.assert_allclose(
        back.skeleton.keypoints["left_hand"][1], deepmimic_skeleton().keypoints["left_hand"][1], atol=1e-6
    )


def test_bvh_in_centimetres_with_renamed_joints(clip_path, tmp_path):
    """A map with other joint names and a unit scale gives the same motion."""
    src = import_file(clip_path("walk"), None, ImportOptions())
    dt = float(np.median(np.diff(src.times)))
    renamed = {j: f"J_{j.title().replace('_', '')}" for j in CANONICAL_JOINTS}
    skel = src.skeleton
    scaled = SourceMotion(
        **{
            **src.__dict__,
            "times": np.arange(src.times.shape[0]) * dt,
            "root_pos": src.root_pos * 100.0,
            "skeleton": type(skel)(
                tuple(renamed[n] for n in skel.names), skel.parents, skel.offsets * 100.0, skel.keypoints
            ),
        }
    )
    path = tmp_path / "walk_cm.bvh"
    write_bvh(scaled, path, dt)
    mp = tmp_path / "cm.toml"
    mp.write_text(
        "[joints]\n" + "".join(f'{k} = "{v}"\n' for k, v in renamed.items()) + "[options]\nscale = 0.01\n"
    )
    back = import_file(path, None, ImportOptions(joint_map=mp))
    np.testing.assert_allclose(back.root_pos, src.root_pos, atol=1e-5)


def test_bvh_facing_plus_z_with_forward_option(clip_path, tmp_path):
    """A skeleton whose rest pose faces +z in BVH axes (as CMU's) reads back facing +x."""
    from amorctl.core.geometry import quat_from_rotvec, quat_rotate

    src = import_file(clip_path("walk"), None, ImportOptions())
    dt = float(np.median(np.diff(src.times)))
    # In MuJoCo axes, BVH +z is -y: turn the whole motion (and its rest pose) by -90° about z.
    turn = quat_from_rotvec(np.array([0.0, 0.0, -np.pi / 2]))
    n = src.local_quat.shape[:2]
    t = np.broadcast_to(turn, (*n, 4))
    local = quat_mul(quat_mul(t, src.local_quat), quat_conj(t))
    skel = src.skeleton
    turned = SourceMotion(
        **{
            **src.__dict__,
            "times": np.arange(src.times.shape[0]) * dt,
            "root_pos": quat_rotate(np.broadcast_to(turn, (n[0], 4)), src.root_pos),
            "local_quat": local,
            "skeleton": type(skel)(
                skel.names,
                skel.parents,
                quat_rotate(np.broadcast_to(turn, (n[1], 4)), skel.offsets),
                skel.keypoints,
            ),
        }
    )
    path = tmp_path / "walk_z.bvh"
    write_bvh(turned, path, dt)
    mp = tmp_path / "z.toml"
    mp.write_text(IDENTITY_MAP + '[options]\nforward = "+z"\n')
    back = import_file(path, None, ImportOptions(joint_map=mp))
    np.testing.assert_allclose(back.root_pos, src.root_pos, atol=1e-5)
    angle = np.linalg.norm(quat_to_rotvec(quat_mul(quat_conj(src.local_quat), back.local_quat)), axis=-1)
    assert angle.max() < 1e-4
    bad = tmp_path / "bad.toml"
    bad.write_text(IDENTITY_MAP + '[options]\nforward = "+y"\n')
    with pytest.raises(AmorError, match="forward must be"):
        import_file(path, None, ImportOptions(joint_map=bad))
