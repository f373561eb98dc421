"""Retargeting: direct mapping onto humanoid36 is exact; IK onto biped20 keeps feet on/above the floor."""

from __future__ import annotations

import numpy as np
import pytest

from amorctl.motion.formats import ImportOptions, import_file
from amorctl.motion.resample import resample_source
from amorctl.motion.retarget import keypoint_errors, retarget, retarget_direct, smooth_lift
from amorctl.motion.source import CharacterMotion, keypoint_positions


def _source(clip_path, name):
    return resample_source(import_file(clip_path(name), None, ImportOptions(name=name)), 50.0)


def test_direct_mapping_reproduces_every_key_point(clip_path, kinematics):
    """Without the floor lift, humanoid36's bodies sit exactly on the DeepMimic skeleton's joints."""
    kin = kinematics("humanoid36")
    src = _source(clip_path, "cartwheel")
    out = retarget_direct(src, kin)
    unlifted = CharacterMotion(**{**out.__dict__, "root_pos": src.root_pos})
    err = keypoint_errors(unlifted, keypoint_positions(src), kin)
    assert err.max() < 1e-6
    assert out.stats["unmapped_joints"] == ["right_toe", "left_toe"]
    lo, hi = kin.joint_ranges[:, 0], kin.joint_ranges[:, 1]
    assert ((out.joint_pos >= lo - 1e-6) & (out.joint_pos <= hi + 1e-6)).mean() > 0.99


@pytest.mark.parametrize(
    ("character", "clip"), [("humanoid36", "run"), ("biped20", "walk"), ("biped20", "roll")]
)
def test_feet_stay_above_the_floor_within_1cm(character, clip, clip_path, kinematics):
    kin = kinematics(character)
    out = retarget(_source(clip_path, clip), kin)
    qpos = kin.qpos(out.root_pos, out.root_quat, out.joint_pos)
    feet, _ = kin.body_poses(qpos, [kin.spec.keypoints["left_foot"], kin.spec.keypoints["right_foot"]])
    assert kin.lowest_points(qpos).min() >= -0.01  # every collision geom, feet included
    assert np.isfinite(feet).all()


def test_biped20_ik_error_limits_and_sliding(clip_path, kinematics):
    kin = kinematics("biped20")
    out = retarget(_source(clip_path, "walk"), kin)
    assert out.stats["method"] == "ik"
    assert 0.2 < out.stats["scale"] < 0.4  # OP3 legs are about 0.3 of the DeepMimic humanoid's
    assert out.retarget_error < 0.03  # mean key-point error, m (measured 0.017)
    assert out.stats["keypoint_error_per_point"]["left_foot"] < 0.01
    lo, hi = kin.joint_ranges[:, 0], kin.joint_ranges[:, 1]
    assert ((out.joint_pos >= lo - 1e-6) & (out.joint_pos <= hi + 1e-6)).all()
    knees = [kin.spec.joint_names().index(n) for n in ("l_knee", "r_knee")]
    assert (out.joint_pos[:, knees[0]] > -0.1).all() and (
        out.joint_pos[:, knees[1]] < 0.1
    ).all()  # bend forward
    assert out.stats["foot_sliding"] < 0.03  # m/s over contact frames


def test_smooth_lift_covers_what_is_needed():
    needed = np.zeros(50)
    needed[20] = 0.05
    needed[30:33] = 0.02
    lift = smooth_lift(needed)
    assert (lift >= needed - 1e-15).all()
    assert np.abs(np.diff(lift)).max() < 0.05 / 2


def test_the_character_spec_chooses_the_method(clip_path, kinematics):
    """The method is ``CharacterSpec.retarget``, not the character's name: humanoid36 renamed
    keeps direct mapping; told to use IK it solves IK instead."""
    from dataclasses import replace

    from amorctl.core.errors import AmorError
    from amorctl.motion.kinematics import CharacterKinematics

    base = kinematics("humanoid36")
    assert base.spec.retarget == "direct" and kinematics("biped20").spec.retarget == "ik"
    src = _source(clip_path, "walk")
    src = replace(src, times=src.times[:10], root_pos=src.root_pos[:10], local_quat=src.local_quat[:10])

    def with_spec(**changes) -> CharacterKinematics:
        return replace(base, spec=replace(base.spec, **changes))

    renamed = retarget(src, with_spec(name="my_deepmimic_clone"))
    assert renamed.stats["method"] == "direct" and renamed.character == "my_deepmimic_clone"
    np.testing.assert_array_equal(renamed.joint_pos, retarget(src, base).joint_pos)
    assert retarget(src, with_spec(retarget="ik")).stats["method"] == "ik"
    with pytest.raises(AmorError, match=r"character 'humanoid36': unknown retargeting method 'fk'"):
        retarget(src, with_spec(retarget="fk"))


def test_a_joint_speed_bound_holds_and_costs_key_point_error(clip_path, kinematics):
    """``max_joint_speed`` (``preprocess --max-joint-speed``) keeps every retargeted joint within
    the bound; on a fast clip the key points then follow the source less closely."""
    kin = kinematics("biped20")
    src = _source(clip_path, "spin")
    free = retarget(src, kin)
    bound = 4.0
    slow = retarget(src, kin, max_joint_speed=bound)
    speed = np.abs(np.diff(slow.joint_pos, axis=0)) * 50.0
    assert np.abs(np.diff(free.joint_pos, axis=0)).max() * 50.0 > 2 * bound  # the clip needs it
    assert speed.max() < bound * 1.01 and slow.stats["max_joint_speed"] == bound
    assert slow.retarget_error > free.retarget_error


def test_the_joint_speed_option_is_checked_before_any_work(tmp_path):
    from dataclasses import replace

    from amorctl.core.errors import AmorError
    from amorctl.motion.preprocess import joint_speed_bound, preprocess
    from amorctl.registry import get_registry

    biped, human = (get_registry().character(n) for n in ("biped20", "humanoid36"))
    assert joint_speed_bound(None, biped) is None and joint_speed_bound("2.5", biped) == 2.5
    assert joint_speed_bound("motor", biped) == pytest.approx(46 * 2 * np.pi / 60)
    for value, message in (("0", "positive"), ("nan", "positive"), ("fast", "neither"), ("-1", "positive")):
        with pytest.raises(AmorError, match=message):
            joint_speed_bound(value, biped)
    with pytest.raises(AmorError, match="IK retargeting only"):
        joint_speed_bound("motor", human)
    no_curve = replace(biped, actuator=replace(biped.actuator, no_load_speed=None))
    with pytest.raises(AmorError, match="no no-load speed"):
        joint_speed_bound("motor", no_curve)
    out = tmp_path / "d.mcap"
    with pytest.raises(AmorError, match="--max-joint-speed"):
        preprocess([], character="humanoid36", out=out, builtin="deepmimic", vae=None, max_joint_speed="3")
    assert not out.exists()
