"""biped20's servo model against hand-computed values (saturation, DC motor torque–speed range,
latency), and the native servo (MuJoCo ``dcmotor`` + history delay) against the numpy reference."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from amorctl.plugins.characters.biped20 import NO_LOAD_SPEED, SPEC, TORQUE_LIMIT
from amorctl.sim.actuators import CommandDelay, servo_torque, torque_bounds
from amorctl.sim.batch_sim import BatchSim

KP, KD = 21.1, 0.5


def _tau(q_target: float, q: float, qd: float, no_load: float | None = NO_LOAD_SPEED) -> float:
    out = servo_torque(
        np.array([[q_target]]), np.array([[q]]), np.array([[qd]]), KP, KD, TORQUE_LIMIT, no_load
    )
    assert out.shape == (1, 1)
    return float(out[0, 0])


def test_biped20_spec_uses_these_parameters() -> None:
    assert SPEC.actuator.kind == "servo"
    assert SPEC.actuator.no_load_speed == pytest.approx(46 * 2 * np.pi / 60)  # 4.817 rad/s
    assert all(j.torque_limit == TORQUE_LIMIT == 5.0 for j in SPEC.joints)


def test_unsaturated_torque_is_plain_pd() -> None:
    # 21.1 * 0.1 - 0.5 * 0.2 = 2.01 N·m; available at 0.2 rad/s: 5 * (1 - 0.2 / 4.8171) = 4.792
    assert _tau(0.1, 0.0, 0.2) == pytest.approx(2.01)
    assert _tau(-0.1, 0.0, 0.0) == pytest.approx(-2.11)


def test_saturates_at_the_torque_limit_at_rest() -> None:
    assert _tau(1.0, 0.0, 0.0) == pytest.approx(5.0)  # PD asks 21.1
    assert _tau(-1.0, 0.0, 0.0) == pytest.approx(-5.0)


def test_driving_at_half_no_load_speed_gives_half_the_limit() -> None:
    half = NO_LOAD_SPEED / 2
    # PD asks 21.1 * 2 - 0.5 * 2.41 = 40.99 N·m: saturated at 5 * (1 - 1/2) = 2.5
    assert _tau(2.0, 0.0, half) == pytest.approx(2.5)
    assert _tau(-2.0, 0.0, -half) == pytest.approx(-2.5)


def test_braking_keeps_the_full_stall_torque() -> None:
    half = NO_LOAD_SPEED / 2
    # Against the motion the back-EMF adds to the drive voltage: the current limit (5 N·m) binds.
    assert _tau(-2.0, 0.0, half) == pytest.approx(-5.0)
    assert _tau(2.0, 0.0, -half) == pytest.approx(5.0)
    # A small braking request is plain PD: 21.1 * (-0.05) - 0.5 * 2.41 = -2.26 N·m
    assert _tau(-0.05, 0.0, half) == pytest.approx(-21.1 * 0.05 - 0.5 * half)


def test_no_driving_torque_at_the_no_load_speed_and_braking_beyond() -> None:
    assert _tau(2.0, 0.0, NO_LOAD_SPEED) == pytest.approx(0.0)
    # at 1.5x the no-load speed the back-EMF exceeds the supply: -5 * 0.5 = -2.5 N·m even when driving
    assert _tau(2.0, 0.0, 1.5 * NO_LOAD_SPEED) == pytest.approx(-2.5)
    assert _tau(2.0, 0.0, 3 * NO_LOAD_SPEED) == pytest.approx(-5.0)  # the current limit still holds


def test_without_no_load_speed_only_the_limit_applies() -> None:
    assert _tau(2.0, 0.0, 100.0, no_load=None) == pytest.approx(-5.0)  # 42.2 - 50 = -7.8 -> -5
    assert _tau(2.0, 0.0, 10.0, no_load=None) == pytest.approx(5.0)  # 42.2 - 5 = 37.2 -> 5


def test_vectorized_over_envs_with_per_joint_parameters() -> None:
    q_target = np.array([[1.0, 0.01, 1.0], [0.0, 0.0, -1.0]])
    q = np.zeros((2, 3))
    qd = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    kp = np.array([10.0, 100.0, 10.0])
    limit = np.array([2.0, 5.0, 4.0])
    no_load = np.array([4.0, 4.0, 2.0])
    tau = servo_torque(q_target, q, qd, kp, 0.0, limit, no_load)
    # joint 2 driving: 10 N·m asked, 4 * (1 - 1/2) = 2 available; braking: -10 asked, -4 available
    np.testing.assert_allclose(tau, [[2.0, 1.0, 2.0], [0.0, 0.0, -4.0]])
    low, high = torque_bounds(qd, limit, no_load)
    np.testing.assert_allclose(high, [[2.0, 5.0, 2.0], [2.0, 5.0, 2.0]])
    np.testing.assert_allclose(low, [[-2.0, -5.0, -4.0], [-2.0, -5.0, -4.0]])


def _pair(spec, n: int = 8) -> tuple[BatchSim, BatchSim, np.ndarray]:
    """Native and python-servo simulations of ``spec`` in the same standing state, and the pose."""
    sims = BatchSim(spec, n, nthread=1), BatchSim(spec, n, nthread=1, servo_model="python")
    pose = np.array([spec.standing_pose.get(j, 0.0) for j in spec.joint_names()])
    for sim in sims:
        sim.set_state(
            np.arange(n), np.tile([0.0, 0.0, spec.standing_height], (n, 1)), np.tile([1.0, 0, 0, 0], (n, 1)),
            np.zeros((n, 3)), np.zeros((n, 3)), np.tile(pose, (n, 1)), np.zeros((n, spec.num_joints)),
        )  # fmt: skip
    return sims[0], sims[1], pose


def test_native_servo_equals_the_reference_under_explicit_actuator_forces() -> None:
    """With MuJoCo's Euler integrator (actuator forces explicit, as the numpy reference applies
    them) the native dcmotor + history delay and the reference give the same trajectory to
    rounding, through saturation, the torque–speed limit, the delay and resets."""
    native, ref, pose = _pair(SPEC)
    assert native.model.actuator_gaintype[native.actuators[0]] == mujoco.mjtGain.mjGAIN_DCMOTOR
    assert native.model.actuator_delay[native.actuators[0]] == pytest.approx(2 / SPEC.physics_hz)
    for sim in (native, ref):
        sim.model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    rng = np.random.default_rng(0)
    saturated = 0.0
    for t in range(20):
        target = pose + 0.6 * rng.standard_normal((native.num_envs, SPEC.num_joints))
        a, b = native.step(target), ref.step(target)
        np.testing.assert_allclose(a.torque, b.torque, atol=1e-9)
        np.testing.assert_allclose(native.qpos, ref.qpos, atol=1e-9)
        saturated = max(saturated, float((np.abs(b.torque) > TORQUE_LIMIT - 1e-9).mean()))
        if t == 10:  # reset half the envs mid-way: pending commands become the pose in both
            ids = np.arange(0, native.num_envs, 2)
            joints = np.tile(pose, (len(ids), 1))
            args = (native.root_pos()[ids], native.root_quat()[ids], native.root_lin_vel()[ids],
                    native.root_ang_vel()[ids], joints, native.joint_vel()[ids])  # fmt: skip
            native.set_state(ids, *args)
            ref.set_state(ids, *args)
    assert saturated > 0.1  # the test went through the torque limits


def test_native_servo_differs_from_the_reference_only_by_the_implicit_back_emf() -> None:
    """Under the character's ``implicitfast`` integrator MuJoCo also integrates the back-EMF
    damping (``-K²/R`` while the voltage clamp binds) implicitly; without the torque–speed limit
    the two are identical, with it they differ by the integration scheme only (docs/environment.md)."""
    no_speed = dataclasses.replace(SPEC, actuator=dataclasses.replace(SPEC.actuator, no_load_speed=None))
    native, ref, pose = _pair(no_speed)
    rng = np.random.default_rng(1)
    for _ in range(5):
        target = pose + 0.6 * rng.standard_normal((native.num_envs, SPEC.num_joints))
        native.step(target), ref.step(target)
        np.testing.assert_allclose(native.qpos, ref.qpos, atol=1e-9)
    native, ref, pose = _pair(SPEC)
    target = pose + 0.2 * rng.standard_normal((native.num_envs, SPEC.num_joints))
    native.step(target), ref.step(target)
    assert np.abs(native.qpos - ref.qpos).max() < 1e-3  # rad, after one control step


def test_python_servo_snapshot_restores_into_the_native_servo() -> None:
    """Checkpoints written before the servo moved into MuJoCo resume: the delay ring becomes the
    state's history, so the next steps equal the reference's (Euler: to rounding)."""
    native, ref, pose = _pair(SPEC)
    for sim in (native, ref):
        sim.model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    rng = np.random.default_rng(2)
    for _ in range(3):
        ref.step(pose + 0.3 * rng.standard_normal((ref.num_envs, SPEC.num_joints)))
    ref.step(pose)  # leaves the head mid-ring with distinct pending commands
    native.restore(ref.snapshot())
    for _ in range(3):
        target = pose + 0.3 * rng.standard_normal((ref.num_envs, SPEC.num_joints))
        native.step(target), ref.step(target)
        np.testing.assert_allclose(native.qpos, ref.qpos, atol=1e-9)


def test_latency_shifts_commands_by_exactly_k_steps() -> None:
    k, n, j = 2, 3, 4
    delay = CommandDelay(k, n, j, initial=-1.0)
    commands = [np.full((n, j), float(t)) for t in range(8)]
    out = [delay.push(c) for c in commands]
    for t in range(8):
        expected = -1.0 if t < k else float(t - k)
        np.testing.assert_array_equal(out[t], np.full((n, j), expected))


def test_latency_of_the_biped_in_physics_steps() -> None:
    k = SPEC.actuator.latency_steps
    assert k == 2
    delay = CommandDelay(k, 1, SPEC.num_joints)
    seen = [delay.push(np.full((1, SPEC.num_joints), float(t)))[0, 0] for t in range(6)]
    assert seen == [0.0, 0.0, 0.0, 1.0, 2.0, 3.0]


def test_zero_latency_returns_the_command() -> None:
    delay = CommandDelay(0, 2, 2)
    cmd = np.array([[1.0, 2.0], [3.0, 4.0]])
    np.testing.assert_array_equal(delay.push(cmd), cmd)


def test_reset_clears_only_the_selected_envs() -> None:
    delay = CommandDelay(1, 2, 2, initial=0.0)
    delay.push(np.full((2, 2), 5.0))
    delay.reset(np.array([True, False]), value=np.array([7.0, 8.0]))
    out = delay.push(np.full((2, 2), 9.0))
    np.testing.assert_array_equal(out, [[7.0, 8.0], [5.0, 5.0]])
    np.testing.assert_array_equal(delay.push(np.zeros((2, 2))), np.full((2, 2), 9.0))


def test_negative_latency_is_rejected() -> None:
    with pytest.raises(ValueError, match="latency"):
        CommandDelay(-1, 1, 1)
