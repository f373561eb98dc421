"""Robot .npz (mjlab / BeyondMimic layout): columns are mapped by name, mismatched names refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amorctl.core.errors import AmorError
from amorctl.motion.formats import ImportOptions, import_file
from amorctl.motion.preprocess import process_clip
from amorctl.motion.resample import resample_source
from amorctl.motion.retarget import retarget


@pytest.fixture(scope="module")
def biped_walk(clip_path, kinematics):
    kin = kinematics("biped20")
    return kin, retarget(resample_source(import_file(clip_path("walk"), None, ImportOptions()), 50.0), kin)


def write_npz(path: Path, kin, motion, order: np.ndarray, fps: float = 50.0, **override) -> Path:
    """Save ``motion`` with its joint columns permuted by ``order`` (names permuted alike)."""
    bodies = ["left_foot", kin.spec.root_body, "right_foot"]
    qpos = kin.qpos(motion.root_pos, motion.root_quat, motion.joint_pos)
    bpos, bquat = kin.body_poses(qpos, bodies)
    names = np.array(kin.spec.joint_names())
    arrays = {
        "fps": np.array([fps]),
        "joint_pos": motion.joint_pos[:, order],
        "joint_vel": np.gradient(motion.joint_pos[:, order], axis=0) * fps,
        "body_pos_w": bpos,
        "body_quat_w": bquat,
        "joint_names": names[order],
        "body_names": np.array(bodies),
    }
    arrays.update(override)
    np.savez(path, **{k: v for k, v in arrays.items() if v is not None})
    return path


def _opts(kin) -> ImportOptions:
    return ImportOptions(
        character=kin.spec.name, joint_names=kin.spec.joint_names(), root_body=kin.spec.root_body
    )


def test_columns_are_mapped_by_name(tmp_path, biped_walk):
    kin, motion = biped_walk
    order = np.random.default_rng(0).permutation(kin.spec.num_joints)
    path = write_npz(tmp_path / "walk.npz", kin, motion, order)
    back = import_file(path, None, _opts(kin))
    np.testing.assert_allclose(back.joint_pos, motion.joint_pos, atol=1e-12)
    np.testing.assert_allclose(back.root_pos, motion.root_pos, atol=1e-12)
    assert back.times.shape == motion.times.shape
    _char, arrays = process_clip(path, None, "test", kin, None, None)
    assert arrays["frames"].shape[0] == motion.times.shape[0]


def test_mismatched_names_are_refused_saying_which(tmp_path, biped_walk):
    kin, motion = biped_walk
    order = np.arange(kin.spec.num_joints)
    names = np.array(kin.spec.joint_names())
    names[3] = "l_wrist"
    path = write_npz(tmp_path / "bad.npz", kin, motion, order, joint_names=names)
    with pytest.raises(
        AmorError, match=r"bad\.npz.*missing character joints l_sho_roll.*unknown to the character l_wrist"
    ):
        import_file(path, None, _opts(kin))


def test_without_names_the_character_order_is_checked_by_kinematics(tmp_path, biped_walk):
    """Issue 16: no joint_names -> the character's order, verified by FK against body positions."""
    kin, motion = biped_walk
    order = np.arange(kin.spec.num_joints)
    path = write_npz(tmp_path / "nonames.npz", kin, motion, order, joint_names=None)
    back = import_file(path, None, _opts(kin))
    np.testing.assert_allclose(back.joint_pos, motion.joint_pos, atol=1e-12)
    assert back.stats["joint_names"] == "from the character"
    assert back.stats["fk_check_error_m"] < 1e-6
    swapped = order.copy()
    swapped[[10, 16]] = swapped[[16, 10]]  # left and right hip pitch exchanged
    path = write_npz(tmp_path / "swapped.npz", kin, motion, swapped, joint_names=None)
    with pytest.raises(
        AmorError, match=r"swapped\.npz: no joint_names.*error \d+\.\d+ m \(body '(left|right)_foot'"
    ):
        import_file(path, None, _opts(kin))


def test_root_body_must_exist(tmp_path, biped_walk):
    kin, motion = biped_walk
    order = np.arange(kin.spec.num_joints)
    path = write_npz(tmp_path / "noroot.npz", kin, motion, order, body_names=np.array(["a", "b", "c"]))
    with pytest.raises(AmorError, match="no body named 'torso'"):
        import_file(path, None, _opts(kin))
