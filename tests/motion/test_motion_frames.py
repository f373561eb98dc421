"""Frame computation against hand-computed cases, and velocities consistent with positions."""

from __future__ import annotations

import numpy as np
import pytest

from amorctl.core.geometry import quat_mul, quat_normalize, quat_rotate, yaw_quat
from amorctl.motion.formats import ImportOptions, import_file
from amorctl.motion.frames import (
    angular_velocity,
    clip_arrays,
    forward_difference,
    frame_layout,
    frame_vectors,
    integrate,
    integrate_rotation,
)
from amorctl.motion.resample import resample_source
from amorctl.motion.retarget import retarget
from amorctl.motion.source import CharacterMotion


def _random_state(rng: np.random.Generator, t: int = 5, j: int = 4, e: int = 4) -> dict[str, np.ndarray]:
    return {
        "root_pos": rng.normal(size=(t, 3)),
        "root_quat": quat_normalize(rng.normal(size=(t, 4))),
        "root_lin_vel": rng.normal(size=(t, 3)),
        "root_ang_vel": rng.normal(size=(t, 3)),
        "joint_pos": rng.normal(size=(t, j)),
        "joint_vel": rng.normal(size=(t, j)),
        "ee_pos": rng.normal(size=(t, e, 3)),
        "ee_quat": quat_normalize(rng.normal(size=(t, e, 4))),
        "ee_lin_vel": rng.normal(size=(t, e, 3)),
    }


def test_rotating_the_world_90deg_about_vertical_leaves_frames_unchanged():
    s = _random_state(np.random.default_rng(0))
    r = yaw_quat(np.array(np.pi / 2))
    r1 = np.broadcast_to(r, (5, 4))
    r2 = np.broadcast_to(r, (5, 4, 4))
    rot = {
        "root_pos": quat_rotate(r1, s["root_pos"]),
        "root_quat": quat_mul(r1, s["root_quat"]),
        "root_lin_vel": quat_rotate(r1, s["root_lin_vel"]),
        "root_ang_vel": quat_rotate(r1, s["root_ang_vel"]),
        "joint_pos": s["joint_pos"],
        "joint_vel": s["joint_vel"],
        "ee_pos": quat_rotate(r2, s["ee_pos"]),
        "ee_quat": quat_mul(r2, s["ee_quat"]),
        "ee_lin_vel": quat_rotate(r2, s["ee_lin_vel"]),
    }
    # the height is the world z, unchanged by a yaw about the origin
    np.testing.assert_allclose(frame_vectors(**rot), frame_vectors(**s), atol=1e-12)


def test_hand_computed_frame():
    """Root yawed 90° (facing +y), 0.9 m high, moving +y at 1 m/s, spinning about z at 2 rad/s;
    one joint; one effector 0.3 m to the root's left (world -x) and 0.2 m down, moving with it."""
    yaw = yaw_quat(np.array([np.pi / 2]))
    state = {
        "root_pos": np.array([[5.0, 7.0, 0.9]]),
        "root_quat": yaw,
        "root_lin_vel": np.array([[0.0, 1.0, 0.0]]),
        "root_ang_vel": np.array([[0.0, 0.0, 2.0]]),
        "joint_pos": np.array([[0.25]]),
        "joint_vel": np.array([[-1.5]]),
        "ee_pos": np.array([[[5.0 - 0.3, 7.0, 0.7]]]),
        "ee_quat": yaw[:, None],
        "ee_lin_vel": np.array([[[0.0, 1.5, 0.0]]]),
    }
    m = frame_vectors(**state)[0]
    layout = frame_layout(1, 1)
    assert m.shape == (layout["ee_vel"][1],) == (1 + 6 + 6 + 2 + 9 + 3,)
    expect = np.concatenate(
        [
            [0.9],
            [1, 0, 0, 0, 1, 0],  # identity in the heading frame
            [1, 0, 0],
            [0, 0, 2],  # forward at 1 m/s, yaw rate 2 rad/s
            [0.25],
            [-1.5],
            [0, 0.3, -0.2],
            [1, 0, 0, 0, 1, 0],  # to the left (+y of the heading frame), 0.2 m below
            [0.5, 0, 0],  # 0.5 m/s faster than the root, forwards
        ]
    )
    np.testing.assert_allclose(m, expect, atol=1e-12)


def test_known_joint_and_root_velocity(kinematics):
    kin = kinematics("humanoid36")
    t = np.arange(30) / 50.0
    joint_pos = np.zeros((30, kin.spec.num_joints))
    joint_pos[:, 3] = 0.4 * t  # neck_x at 0.4 rad/s
    yaw = 0.8 * t  # turning at 0.8 rad/s about z
    motion = CharacterMotion(
        name="synthetic",
        source="-",
        sha256="",
        licence="",
        character="humanoid36",
        times=t,
        root_pos=np.stack([0.5 * t, np.zeros(30), np.full(30, 0.9)], axis=1),
        root_quat=yaw_quat(yaw),
        joint_pos=joint_pos,
        source_fps=50.0,
    )
    arrays = clip_arrays(motion, kin, 50.0)
    np.testing.assert_allclose(arrays["joint_vel"][:, 3], 0.4, atol=1e-9)
    np.testing.assert_allclose(arrays["root_ang_vel"], np.tile([0, 0, 0.8], (30, 1)), atol=1e-9)
    np.testing.assert_allclose(arrays["root_lin_vel"], np.tile([0.5, 0, 0], (30, 1)), atol=1e-9)
    layout = frame_layout(kin.spec.num_joints, 4)
    a, b = layout["joint_vel"]
    np.testing.assert_allclose(arrays["frames"][:, a + 3], 0.4, atol=1e-9)
    # heading-frame linear velocity: world +x seen from a root yawed by 0.8 t
    a, b = layout["root_lin_vel"]
    expect = np.stack([0.5 * np.cos(yaw), -0.5 * np.sin(yaw), np.zeros(30)], axis=1)
    np.testing.assert_allclose(arrays["frames"][:, a:b], expect, atol=1e-9)


@pytest.mark.parametrize("clip", ["walk", "backflip"])
def test_integrating_velocities_reproduces_positions(clip, clip_path, kinematics):
    kin = kinematics("humanoid36")
    char = retarget(resample_source(import_file(clip_path(clip), None, ImportOptions()), 50.0), kin)
    arr = clip_arrays(char, kin, 50.0)
    dt = 1 / 50
    np.testing.assert_allclose(
        integrate(arr["root_pos"][0], arr["root_lin_vel"], dt), arr["root_pos"], atol=1e-9
    )
    np.testing.assert_allclose(
        integrate(arr["joint_pos"][0], arr["joint_vel"], dt), arr["joint_pos"], atol=1e-9
    )
    np.testing.assert_allclose(integrate(arr["ee_pos"][0], arr["ee_lin_vel"], dt), arr["ee_pos"], atol=1e-9)
    q = integrate_rotation(arr["root_quat"][0], arr["root_ang_vel"], dt)
    dots = np.abs(np.sum(q * arr["root_quat"], axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)


def test_velocity_helpers_on_tiny_inputs():
    assert forward_difference(np.zeros((1, 3)), 0.02).shape == (1, 3)
    assert angular_velocity(np.array([[1.0, 0, 0, 0]]), 0.02).shape == (1, 3)
    np.testing.assert_allclose(
        forward_difference(np.array([[0.0], [1.0], [3.0]]), 0.5), [[2.0], [4.0], [4.0]]
    )
