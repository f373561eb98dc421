"""The tracking7 objective set: kernels against hand-computed values, scales, combination rule."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import FrameParts, TrackingInputs, frame_features, split_frame
from amorctl.plugins.objectives import tracking7_kernels as k
from amorctl.plugins.objectives.tracking7 import (
    ALIVE_BONUS,
    OBJECTIVES,
    PRIOR_SCALES,
    Tracking7,
    resolve_scales,
)
from amorctl.registry import get_registry

IDENTITY_6D = np.array([1.0, 0, 0, 0, 1, 0])
RZ90_6D = np.array([0.0, 1, 0, -1, 0, 0])  # columns (0,1,0), (-1,0,0)
RX180_6D = np.array([1.0, 0, 0, 0, -1, 0])


# --- kernels ----------------------------------------------------------------------------------


def test_joint_pos_error_exp() -> None:
    r = k.joint_pos_error_exp(np.array([[0.1, -0.2], [0.0, 0.0]]), np.zeros((2, 2)), 2.0)
    np.testing.assert_allclose(r, [math.exp(-2.0 * 0.05), 1.0])


def test_joint_pos_error_exp_empty_group_is_max() -> None:
    np.testing.assert_allclose(k.joint_pos_error_exp(np.zeros((3, 0)), np.zeros((3, 0)), 7.0), 1.0)


def test_root_height_error_exp() -> None:
    np.testing.assert_allclose(
        k.root_height_error_exp(np.array([0.8]), np.array([0.9]), 10.0), [math.exp(-0.1)]
    )


def test_body_pos_error_exp_sums_over_effectors() -> None:
    p = np.array([[[1.0, 0, 0], [0, 2.0, 0]]])
    np.testing.assert_allclose(k.body_pos_error_exp(p, np.zeros_like(p), 0.5), [math.exp(-0.5 * 5.0)])


def test_body_rot_error_exp_frobenius() -> None:
    sim = np.stack([RZ90_6D, RX180_6D])[None]  # [1, 2, 6]
    ref = np.stack([IDENTITY_6D, IDENTITY_6D])[None]
    # ||Rz90 - I||_F² = 6 - 2 tr(Rz90) = 4;  ||Rx180 - I||_F² = 6 - 2 (-1) = 8
    np.testing.assert_allclose(k.body_rot_error_exp(sim, ref, 0.25), [math.exp(-0.25 * 12.0)])


def test_body_rot_error_exp_accepts_unnormalized_6d() -> None:
    sim = (2.0 * IDENTITY_6D)[None, None]
    np.testing.assert_allclose(k.body_rot_error_exp(sim, IDENTITY_6D[None, None], 1.0), [1.0])


def test_body_vel_error_exp() -> None:
    v = np.array([[[0.0, 3.0, 4.0]]])
    np.testing.assert_allclose(k.body_vel_error_exp(v, np.zeros_like(v), 0.04), [math.exp(-1.0)])


def test_root_rot_error_exp() -> None:
    r = k.root_rot_error_exp(np.stack([RZ90_6D, IDENTITY_6D]), np.stack([IDENTITY_6D, IDENTITY_6D]), 1.0)
    np.testing.assert_allclose(r, [math.exp(-4.0), 1.0])


def test_root_velocity_kernels() -> None:
    v = np.array([[1.0, 2.0, 2.0]])
    np.testing.assert_allclose(k.root_lin_vel_error_exp(v, np.zeros_like(v), 2.0), [math.exp(-18.0)])
    np.testing.assert_allclose(k.root_ang_vel_error_exp(v, v, 2.0), [1.0])
    np.testing.assert_allclose(k.root_ang_vel_error_exp(v, 0 * v, 0.1), [math.exp(-0.9)])


def test_torque_l2_averages_substeps() -> None:
    tau = np.array([[[1.0, 2.0], [3.0, 0.0]]])  # [N=1, S=2, J=2]: 5 and 9 -> mean 7
    np.testing.assert_allclose(k.torque_l2(tau, 1e-4), [-7e-4])


def test_action_rate_and_acc_l2() -> None:
    a, a1, a2 = np.array([[1.0, 2.0]]), np.zeros((1, 2)), np.array([[1.0, 0.0]])
    np.testing.assert_allclose(k.action_rate_l2(a, a1, 1.5), [-1.5 * 5.0])
    # a - 2 a1 + a2 = (2, 2) -> 8
    np.testing.assert_allclose(k.action_acc_l2(a, a1, a2, 0.45), [-0.45 * 8.0])


def test_joint_acc_l2() -> None:
    np.testing.assert_allclose(k.joint_acc_l2(np.array([[3.0, 4.0]]), 2.5e-6), [-2.5e-6 * 25.0])


# --- the bound set ------------------------------------------------------------------------------


def _zero_error_inputs(n: int, j: int, e: int, seed: int = 0) -> TrackingInputs:
    rng = np.random.default_rng(seed)
    quat = rng.standard_normal((n, 4))
    ee_quat = rng.standard_normal((n, e, 4))
    frames = frame_features(
        rng.standard_normal((n, 3)), quat / np.linalg.norm(quat, axis=-1, keepdims=True),
        rng.standard_normal((n, 3)), rng.standard_normal((n, 3)), rng.standard_normal((n, j)),
        rng.standard_normal((n, j)), rng.standard_normal((n, e, 3)),
        ee_quat / np.linalg.norm(ee_quat, axis=-1, keepdims=True), rng.standard_normal((n, e, 3)),
    )  # fmt: skip
    parts = split_frame(frames, j, e)
    a = rng.standard_normal((n, j))
    return TrackingInputs(
        sim=parts,
        ref=split_frame(frames.copy(), j, e),
        torque=np.zeros((n, 5, j)),
        pd_target=a,
        pd_target_prev=a,
        pd_target_prev2=a,
        joint_acc=np.zeros((n, j)),
    )


@pytest.fixture(params=["humanoid36", "biped20", "stickman12"])
def character(request: pytest.FixtureRequest):
    registry = get_registry()
    if request.param not in registry.names("character"):
        pytest.skip(f"character {request.param} not installed")
    return registry.character(request.param)


def test_zero_error_gives_maximum_reward(character) -> None:
    obj = Tracking7(character)
    x = _zero_error_inputs(4, character.num_joints, len(character.end_effectors))
    r = obj(x, np.ones(4))
    c = obj.alive_bonus
    np.testing.assert_allclose(r, np.tile([1 + c] * 6 + [c], (4, 1)), atol=1e-12)
    np.testing.assert_allclose(r, np.tile(obj.high, (4, 1)), atol=1e-12)
    np.testing.assert_allclose(obj(x, np.zeros(4)), np.tile([1.0] * 6 + [0.0], (4, 1)), atol=1e-12)


def test_table1_scales_per_character() -> None:
    registry = get_registry()
    names = registry.names("character")
    if "humanoid36" in names:
        s = Tracking7(registry.character("humanoid36")).scales
        assert s["up"] == s["lo"] == s["feet"] == 1.0
        assert s["smooth_torque"] == s["smooth_action_rate"] == s["smooth_action_acc"] == 1.0e-5
        assert s["smooth_joint_acc"] == 1.0e-6
        assert s["vel_lin"] == s["vel_ang"] == 1.0
    if "biped20" in names:
        s = Tracking7(registry.character("biped20")).scales
        assert s["up"] == s["lo"] == s["feet"] == 7.0
        assert s["rbs_pos"] == s["rbs_rot"] == s["rbs_vel"] == s["root"] == 1.0
        assert s["vel_lin"] == s["vel_ang"] == 2.0
        assert s["smooth_torque"] == 1.0e-4
        assert s["smooth_action_rate"] == 1.5
        assert s["smooth_action_acc"] == 0.45
        assert s["smooth_joint_acc"] == 2.5e-6
    for name in names:
        ch = registry.character(name)
        overrides = dict(ch.objective_scales.get("tracking7", {}))
        expected = {**PRIOR_SCALES[ch.scale_profile], **overrides}
        if "up" in overrides:
            expected["up_height"] = overrides.get("up_height", overrides["up"])
        assert Tracking7(ch).scales == expected


def test_character_override_and_bad_keys(character) -> None:
    ch = dataclasses.replace(character, objective_scales={"tracking7": {"up": 3.0, "alive": 0.5}})
    s = resolve_scales(ch)
    assert s["up"] == 3.0 and s["up_height"] == 3.0 and s["alive"] == 0.5
    assert Tracking7(ch).alive_bonus == 0.5
    bad = dataclasses.replace(character, objective_scales={"tracking7": {"upper": 3.0}})
    with pytest.raises(AmorError, match="upper"):
        resolve_scales(bad)
    with pytest.raises(AmorError, match="scale_profile"):
        resolve_scales(dataclasses.replace(character, scale_profile="insect"))


def test_combination_rule_mean_of_exponentials_and_sum_of_penalties(character) -> None:
    obj = Tracking7(character)
    j, e = character.num_joints, len(character.end_effectors)
    x = _zero_error_inputs(1, j, e)
    up = np.asarray(character.group_indices("upper"))
    sim = x.sim
    jp = sim.joint_pos.copy()
    jp[0, up[0]] += 0.3  # upper joint error 0.09
    lin = sim.root_lin_vel + np.array([0.5, 0.0, 0.0])  # lin vel error 0.25
    epos = sim.ee_pos.copy()
    epos[0, 0, 2] += 0.2  # ee position error 0.04
    sim2 = dataclasses.replace(sim, joint_pos=jp, root_lin_vel=lin, ee_pos=epos, h=sim.h + 0.1)
    a = x.pd_target
    x2 = dataclasses.replace(
        x, sim=sim2, pd_target=a + 0.1, joint_acc=np.full((1, j), 2.0), torque=np.full((1, 5, j), 3.0)
    )
    s = obj.scales
    r = obj(x2, np.ones(1))[0] - obj.alive_bonus
    assert r[0] == pytest.approx(0.5 * (math.exp(-s["up"] * 0.09) + math.exp(-s["up_height"] * 0.01)))
    assert r[1] == pytest.approx(1.0) and r[2] == pytest.approx(1.0)
    assert r[3] == pytest.approx((math.exp(-s["rbs_pos"] * 0.04) + 2.0) / 3.0)
    assert r[4] == pytest.approx(1.0)
    assert r[5] == pytest.approx(0.5 * (math.exp(-s["vel_lin"] * 0.25) + 1.0))
    smooth = -(
        s["smooth_torque"] * 9.0 * j
        + s["smooth_action_rate"] * 0.01 * j
        + s["smooth_action_acc"] * 0.01 * j  # a+0.1 - 2a + a = 0.1
        + s["smooth_joint_acc"] * 4.0 * j
    )
    assert r[6] == pytest.approx(smooth)


def test_registered_set_order_and_bounds() -> None:
    spec = get_registry().objective_set("tracking7")
    assert spec.objectives == ("up", "lo", "feet", "rbs", "root", "vel", "smooth") == OBJECTIVES
    assert ALIVE_BONUS == 1.0


def test_kernels_run_under_jax() -> None:
    jnp = pytest.importorskip("jax.numpy")
    x = _zero_error_inputs(3, 6, 2)
    sim = FrameParts(**{f.name: jnp.asarray(getattr(x.sim, f.name)) for f in dataclasses.fields(FrameParts)})
    ref = FrameParts(**{f.name: jnp.asarray(getattr(x.ref, f.name)) for f in dataclasses.fields(FrameParts)})
    jx = TrackingInputs(
        sim=sim, ref=ref, torque=jnp.asarray(x.torque), pd_target=jnp.asarray(x.pd_target),
        pd_target_prev=jnp.asarray(x.pd_target), pd_target_prev2=jnp.asarray(x.pd_target),
        joint_acc=jnp.asarray(x.joint_acc),
    )  # fmt: skip
    registry = get_registry()
    ch = registry.character(registry.names("character")[0])
    ch = dataclasses.replace(ch, joints=ch.joints[:6], end_effectors=ch.end_effectors[:2])
    obj = Tracking7(ch)
    np.testing.assert_allclose(np.asarray(obj(jx, jnp.ones(3), xp=jnp)), obj(x, np.ones(3)), rtol=1e-5)


def test_rot6d_frobenius_sq_matches_matrix_form() -> None:
    from amorctl.core.geometry import rot6d_to_mat

    rng = np.random.default_rng(3)
    a, b = rng.standard_normal((40, 6)), rng.standard_normal((40, 6))
    expected = ((rot6d_to_mat(a) - rot6d_to_mat(b)) ** 2).sum(axis=(-1, -2))
    np.testing.assert_allclose(k.rot6d_frobenius_sq(a, b), expected, atol=1e-12)
    np.testing.assert_allclose(k.rot6d_frobenius_sq(a, a), 0.0, atol=1e-12)
