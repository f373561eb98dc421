"""Pure reward kernels of the ``tracking7`` objective set (Table 1 of the AMOR paper).

Every kernel is a pure function over explicit arrays, named ``<quantity>_<kernel>`` as in
ProtoMotions: ``*_error_exp`` kernels return the tracking reward ``exp(-scale * err)`` in (0, 1],
``*_l2`` kernels return the smoothness penalty ``-scale * err`` (<= 0). ``err`` is always a squared
L2 (or Frobenius) norm summed over every non-batch axis. Each kernel takes the array namespace
``xp`` (numpy by default; jax.numpy runs the same code), so the torch-cpu and jax-mjx backends
share them. N is the batch (number of envs), J joints, E end effectors, S physics substeps.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def sum_sq(x: Any, xp: Any = np) -> Any:
    """Squared L2 norm over every axis but the first. x: [N, ...] -> [N]."""
    return xp.sum(xp.reshape(x * x, (x.shape[0], -1)), axis=-1)


def rot6d_frobenius_sq(d6: Any, d6_hat: Any, xp: Any = np) -> Any:
    """||R(d6) - R(d̂6)||_F² for 6D rotations, R by Gram–Schmidt. d6, d6_hat: [..., 6] -> [...].

    Equals 6 - 2 tr(Rᵀ R̂). With columns b1, b2, b3 = b1 × b2 (and b̂ likewise) the trace is
    b1·b̂1 + b2·b̂2 + (b1·b̂1)(b2·b̂2) - (b1·b̂2)(b2·b̂1) (Binet–Cauchy), so no matrix is built.
    """

    def dot(a: Any, b: Any) -> Any:  # written out: faster than a reduction over 3 elements
        return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]

    def columns(d: Any) -> tuple[Any, Any]:
        a1, a2 = d[..., :3], d[..., 3:]
        b1 = a1 / xp.sqrt(dot(a1, a1))[..., None]
        b2 = a2 - dot(b1, a2)[..., None] * b1
        return b1, b2 / xp.sqrt(dot(b2, b2))[..., None]

    b1, b2 = columns(d6)
    c1, c2 = columns(d6_hat)
    d11, d22, d12, d21 = dot(b1, c1), dot(b2, c2), dot(b1, c2), dot(b2, c1)
    return xp.maximum(6.0 - 2.0 * (d11 + d22 + d11 * d22 - d12 * d21), 0.0)


# --- tracking terms: exp(-scale * squared error), each in (0, 1] -------------------------------


def joint_pos_error_exp(q: Any, q_hat: Any, scale: float, xp: Any = np) -> Any:
    """exp(-scale * ||q - q̂||²) over one joint group.

    Args:
        q: [N, G] simulated joint positions of the group, rad.
        q_hat: [N, G] reference joint positions, rad.
        scale: prior scale (1/rad²).
    Returns:
        [N] reward in (0, 1]; 1 when q == q̂ (and when G == 0).
    """
    return xp.exp(-scale * sum_sq(q - q_hat, xp))


def root_height_error_exp(h: Any, h_hat: Any, scale: float, xp: Any = np) -> Any:
    """exp(-scale * (h - ĥ)²) of the root height above the ground.

    Args:
        h: [N] simulated root height, m.
        h_hat: [N] reference root height, m.
        scale: prior scale (1/m²).
    Returns:
        [N] reward in (0, 1].
    """
    d = h - h_hat
    return xp.exp(-scale * d * d)


def body_pos_error_exp(p: Any, p_hat: Any, scale: float, xp: Any = np) -> Any:
    """exp(-scale * Σ_e ||p_e - p̂_e||²) of end-effector positions relative to the root.

    Args:
        p: [N, E, 3] simulated positions in the root's heading frame, m.
        p_hat: [N, E, 3] reference positions in the reference root's heading frame, m.
        scale: prior scale (1/m²).
    Returns:
        [N] reward in (0, 1].
    """
    return xp.exp(-scale * sum_sq(p - p_hat, xp))


def body_rot_error_exp(rot6d: Any, rot6d_hat: Any, scale: float, xp: Any = np) -> Any:
    """exp(-scale * Σ_e ||R(p_e) - R(p̂_e)||_F²) of end-effector orientations.

    The 6D representations are mapped to rotation matrices (Gram–Schmidt) before comparing, as
    in Table 1; ||R - R̂||_F² = 6 - 2 tr(Rᵀ R̂) ranges over [0, 8] per effector.

    Args:
        rot6d: [N, E, 6] simulated orientations in the heading frame (6D).
        rot6d_hat: [N, E, 6] reference orientations (6D).
        scale: prior scale.
    Returns:
        [N] reward in (0, 1].
    """
    return xp.exp(-scale * xp.sum(rot6d_frobenius_sq(rot6d, rot6d_hat, xp), axis=-1))


def body_vel_error_exp(v: Any, v_hat: Any, scale: float, xp: Any = np) -> Any:
    """exp(-scale * Σ_e ||ṗ_e - p̂̇_e||²) of end-effector linear velocities relative to the root.

    Args:
        v: [N, E, 3] simulated velocities in the heading frame, m/s.
        v_hat: [N, E, 3] reference velocities, m/s.
        scale: prior scale (s²/m²).
    Returns:
        [N] reward in (0, 1].
    """
    return xp.exp(-scale * sum_sq(v - v_hat, xp))


def root_rot_error_exp(rot6d: Any, rot6d_hat: Any, scale: float, xp: Any = np) -> Any:
    """exp(-scale * ||R(θ) - R(θ̂)||_F²) of the root orientation in its heading frame.

    Args:
        rot6d: [N, 6] simulated root orientation relative to its heading (6D).
        rot6d_hat: [N, 6] reference root orientation relative to its heading (6D).
        scale: prior scale.
    Returns:
        [N] reward in (0, 1].
    """
    return xp.exp(-scale * rot6d_frobenius_sq(rot6d, rot6d_hat, xp))


def root_lin_vel_error_exp(v: Any, v_hat: Any, scale: float, xp: Any = np) -> Any:
    """exp(-scale * ||v_lin - v̂_lin||²) of the root linear velocity in the heading frame.

    Args:
        v: [N, 3] simulated, m/s.
        v_hat: [N, 3] reference, m/s.
        scale: prior scale (s²/m²).
    Returns:
        [N] reward in (0, 1].
    """
    return xp.exp(-scale * sum_sq(v - v_hat, xp))


def root_ang_vel_error_exp(w: Any, w_hat: Any, scale: float, xp: Any = np) -> Any:
    """exp(-scale * ||v_ang - v̂_ang||²) of the root angular velocity in the heading frame.

    Args:
        w: [N, 3] simulated, rad/s.
        w_hat: [N, 3] reference, rad/s.
        scale: prior scale (s²/rad²).
    Returns:
        [N] reward in (0, 1].
    """
    return xp.exp(-scale * sum_sq(w - w_hat, xp))


# --- smoothness terms: -scale * squared norm, each <= 0 -----------------------------------------


def torque_l2(tau: Any, scale: float, xp: Any = np) -> Any:
    """-scale * ||τ||², averaged over the physics substeps of the control step.

    Args:
        tau: [N, S, J] joint torques of every physics substep, N·m.
        scale: prior scale (1/(N·m)²).
    Returns:
        [N] penalty <= 0.
    """
    return -scale * xp.mean(xp.sum(tau * tau, axis=-1), axis=-1)


def action_rate_l2(a: Any, a_prev: Any, scale: float, xp: Any = np) -> Any:
    """-scale * ||a_t - a_{t-1}||² of the PD targets.

    Args:
        a: [N, J] this step's PD targets, rad.
        a_prev: [N, J] the previous step's PD targets, rad.
        scale: prior scale (1/rad²).
    Returns:
        [N] penalty <= 0.
    """
    return -scale * sum_sq(a - a_prev, xp)


def action_acc_l2(a: Any, a_prev: Any, a_prev2: Any, scale: float, xp: Any = np) -> Any:
    """-scale * ||a_t - 2 a_{t-1} + a_{t-2}||² (second difference of the PD targets).

    Args:
        a: [N, J] PD targets at t, rad.
        a_prev: [N, J] at t-1.
        a_prev2: [N, J] at t-2.
        scale: prior scale (1/rad²).
    Returns:
        [N] penalty <= 0.
    """
    return -scale * sum_sq(a - 2.0 * a_prev + a_prev2, xp)


def joint_acc_l2(qdd: Any, scale: float, xp: Any = np) -> Any:
    """-scale * ||q̈||² of the actuated joints.

    Args:
        qdd: [N, J] joint accelerations, rad/s² (the env uses the control-step finite
            difference (q̇_{t+1} - q̇_t) / Δt, as legged_gym does).
        scale: prior scale (s⁴/rad²).
    Returns:
        [N] penalty <= 0.
    """
    return -scale * sum_sq(qdd, xp)
