"""Rotation math shared by motion frames, observations and rewards.

Pure functions over arrays with leading batch dimensions ``[...]``. Quaternions are (w, x, y, z),
MuJoCo's convention, unit norm. Each function takes an optional ``xp`` array namespace (numpy by
default) so that jax.numpy can run the same code.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def quat_conj(q: Any, xp: Any = np) -> Any:
    """Conjugate (= inverse for unit quaternions). q: [..., 4] -> [..., 4]."""
    return xp.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def quat_mul(a: Any, b: Any, xp: Any = np) -> Any:
    """Hamilton product a ⊗ b. a, b: [..., 4] -> [..., 4]."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return xp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_rotate(q: Any, v: Any, xp: Any = np) -> Any:
    """Rotate vectors v by q. q: [..., 4], v: [..., 3] -> [..., 3]."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * xp.cross(u, v)
    return v + w * t + xp.cross(u, t)


def quat_to_mat(q: Any, xp: Any = np) -> Any:
    """Rotation matrices from quaternions. q: [..., 4] -> [..., 3, 3]."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return xp.stack([xp.stack(r, axis=-1) for r in rows], axis=-2)


def mat_to_6d(m: Any, xp: Any = np) -> Any:
    """6D rotation representation (Zhou et al. 2019): the first two columns, stacked.

    m: [..., 3, 3] -> [..., 6] ordered (m00, m10, m20, m01, m11, m21).
    """
    return xp.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def rot6d_to_mat(d6: Any, xp: Any = np) -> Any:
    """Inverse of :func:`mat_to_6d` with Gram–Schmidt. d6: [..., 6] -> [..., 3, 3]."""
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = a1 / xp.linalg.norm(a1, axis=-1, keepdims=True)
    b2 = a2 - xp.sum(b1 * a2, axis=-1, keepdims=True) * b1
    b2 = b2 / xp.linalg.norm(b2, axis=-1, keepdims=True)
    b3 = xp.cross(b1, b2)
    return xp.stack([b1, b2, b3], axis=-1)


def quat_to_6d(q: Any, xp: Any = np) -> Any:
    """q: [..., 4] -> [..., 6]."""
    return mat_to_6d(quat_to_mat(q, xp), xp)


def heading_angle(q: Any, xp: Any = np) -> Any:
    """Yaw of the body's x axis projected on the ground plane (z up). q: [..., 4] -> [...]."""
    x_axis = quat_rotate(q, xp.zeros_like(q[..., 1:]) + xp.asarray([1.0, 0.0, 0.0]), xp)
    return xp.arctan2(x_axis[..., 1], x_axis[..., 0])


def yaw_quat(angle: Any, xp: Any = np) -> Any:
    """Rotation about +z by ``angle``. angle: [...] -> [..., 4]."""
    half = 0.5 * angle
    zero = xp.zeros_like(half)
    return xp.stack([xp.cos(half), zero, zero, xp.sin(half)], axis=-1)


def heading_quat_inv(q: Any, xp: Any = np) -> Any:
    """The rotation that maps world vectors into the heading frame of q. q: [..., 4] -> [..., 4]."""
    return yaw_quat(-heading_angle(q, xp), xp)
