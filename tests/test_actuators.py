"""biped20's servo model against hand-computed values: saturation, torque–speed curve, latency."""

from __future__ import annotations

import numpy as np
import pytest

from amorctl.plugins.characters.biped20 import NO_LOAD_SPEED, SPEC, TORQUE_LIMIT
from amorctl.sim.actuators import CommandDelay, available_torque, servo_torque

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


def test_half_no_load_speed_gives_half_the_limit() -> None:
    half = NO_LOAD_SPEED / 2
    # PD asks 21.1 * 2 - 0.5 * 2.41 = 40.99 N·m: saturated at 5 * (1 - 1/2) = 2.5
    assert _tau(2.0, 0.0, half) == pytest.approx(2.5)
    assert _tau(-2.0, 0.0, -half) == pytest.approx(-2.5)
    # The curve depends on |qd|: braking against the motion is limited the same way.
    assert _tau(-2.0, 0.0, half) == pytest.approx(-2.5)


def test_no_torque_at_or_beyond_no_load_speed() -> None:
    assert _tau(2.0, 0.0, NO_LOAD_SPEED) == pytest.approx(0.0)
    assert _tau(2.0, 0.0, 2 * NO_LOAD_SPEED) == pytest.approx(0.0)


def test_without_no_load_speed_only_the_limit_applies() -> None:
    assert _tau(2.0, 0.0, 100.0, no_load=None) == pytest.approx(-5.0)  # 42.2 - 50 = -7.8 -> -5
    assert _tau(2.0, 0.0, 10.0, no_load=None) == pytest.approx(5.0)  # 42.2 - 5 = 37.2 -> 5


def test_vectorized_over_envs_with_per_joint_parameters() -> None:
    q_target = np.array([[1.0, 0.01, 1.0], [0.0, 0.0, 0.0]])
    q = np.zeros((2, 3))
    qd = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    kp = np.array([10.0, 100.0, 10.0])
    limit = np.array([2.0, 5.0, 4.0])
    no_load = np.array([4.0, 4.0, 2.0])
    tau = servo_torque(q_target, q, qd, kp, 0.0, limit, no_load)
    # joint 2: 10 N·m asked, available 4 * (1 - 1/2) = 2
    np.testing.assert_allclose(tau, [[2.0, 1.0, 2.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(available_torque(qd, limit, no_load), [[2.0, 5.0, 2.0], [2.0, 5.0, 4.0]])


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
