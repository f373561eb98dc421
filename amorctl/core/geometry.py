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


# --- additions for motion data (numpy only: used at preprocess time, never inside jitted code) ---


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions with a non-negative w (a canonical sign). q: [..., 4] -> [..., 4]."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_from_mat(m: np.ndarray) -> np.ndarray:
    """Quaternions (w, x, y, z) from rotation matrices. m: [..., 3, 3] -> [..., 4]."""
    from scipy.spatial.transform import Rotation

    m = np.asarray(m, dtype=np.float64)
    xyzw = Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat()
    return quat_normalize(xyzw[:, [3, 0, 1, 2]].reshape(*m.shape[:-2], 4))


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (axis * angle, angle in [0, π]). q: [..., 4] -> [..., 3]."""
    q = quat_normalize(q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-12), 2.0)
    return v * scale


def quat_from_rotvec(r: np.ndarray) -> np.ndarray:
    """Inverse of :func:`quat_to_rotvec`. r: [..., 3] -> [..., 4]."""
    r = np.asarray(r, dtype=np.float64)
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * angle
    sinc = np.where(angle > 1e-12, np.sin(half) / np.maximum(angle, 1e-12), 0.5)
    return np.concatenate([np.cos(half), r * sinc], axis=-1)


def quat_slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Shortest-path spherical interpolation. a, b: [..., 4], t: [...] in [0, 1] -> [..., 4]."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0.0, -b, b)
    delta = quat_mul(quat_conj(a), b)
    r = quat_to_rotvec(delta) * np.asarray(t, dtype=np.float64)[..., None]
    return quat_normalize(quat_mul(a, quat_from_rotvec(r)))


def mat_to_euler_xyz(m: np.ndarray) -> np.ndarray:
    """Intrinsic XYZ Euler angles (a, b, c) with m = Rx(a) Ry(b) Rz(c). m: [..., 3, 3] -> [..., 3]."""
    m = np.asarray(m, dtype=np.float64)
    b = np.arcsin(np.clip(m[..., 0, 2], -1.0, 1.0))
    a = np.arctan2(-m[..., 1, 2], m[..., 2, 2])
    c = np.arctan2(-m[..., 0, 1], m[..., 0, 0])
    return np.stack([a, b, c], axis=-1)
