"""Unit quaternions for the SGGX fibre basis ``M`` of eq. 3.6.

Convention: ``q = (w, x, y, z)`` (scalar first), arrays of shape ``(..., 4)``. The rotation matrix
``R = quat_to_matrix(q)`` has the fibre-frame axes as *columns*: ``R[..., :, 0]`` is the axis whose
projected standard deviation is ``sigma_x``, ``R[..., :, 2]`` the axis with ``sigma_z = 1``.
"""

from __future__ import annotations

import numpy as np


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Return ``q / |q|`` (identity where ``|q| == 0``)."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    out = np.where(n > 0, q / np.where(n > 0, n, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))
    return out


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix ``(..., 3, 3)`` of unit quaternions ``(..., 4)``."""
    q = quat_normalize(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty(q.shape[:-1] + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - w * z)
    r[..., 0, 2] = 2 * (x * z + w * y)
    r[..., 1, 0] = 2 * (x * y + w * z)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - w * x)
    r[..., 2, 0] = 2 * (x * z - w * y)
    r[..., 2, 1] = 2 * (y * z + w * x)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(..., 4)`` with ``w >= 0`` of rotation matrices ``(..., 3, 3)``.

    Uses the largest-diagonal branch per element, so it is stable for every rotation.
    """
    r = np.asarray(r, dtype=np.float64)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    tr = m00 + m11 + m22
    cand = np.stack([tr, m00, m11, m22], axis=-1)
    branch = np.argmax(cand, axis=-1)
    q = np.empty(r.shape[:-2] + (4,))
    with np.errstate(invalid="ignore", divide="ignore"):
        s0 = np.sqrt(np.maximum(1.0 + tr, 1e-300)) * 2
        q0 = np.stack([0.25 * s0, (r[..., 2, 1] - r[..., 1, 2]) / s0,
                       (r[..., 0, 2] - r[..., 2, 0]) / s0, (r[..., 1, 0] - r[..., 0, 1]) / s0], -1)
        s1 = np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 1e-300)) * 2
        q1 = np.stack([(r[..., 2, 1] - r[..., 1, 2]) / s1, 0.25 * s1,
                       (r[..., 0, 1] + r[..., 1, 0]) / s1, (r[..., 0, 2] + r[..., 2, 0]) / s1], -1)
        s2 = np.sqrt(np.maximum(1.0 + m11 - m00 - m22, 1e-300)) * 2
        q2 = np.stack([(r[..., 0, 2] - r[..., 2, 0]) / s2, (r[..., 0, 1] + r[..., 1, 0]) / s2,
                       0.25 * s2, (r[..., 1, 2] + r[..., 2, 1]) / s2], -1)
        s3 = np.sqrt(np.maximum(1.0 + m22 - m00 - m11, 1e-300)) * 2
        q3 = np.stack([(r[..., 1, 0] - r[..., 0, 1]) / s3, (r[..., 0, 2] + r[..., 2, 0]) / s3,
                       (r[..., 1, 2] + r[..., 2, 1]) / s3, 0.25 * s3], -1)
    b = branch[..., None]
    q = np.where(b == 0, q0, np.where(b == 1, q1, np.where(b == 2, q2, q3)))
    q = quat_normalize(q)
    return np.where(q[..., :1] < 0, -q, q)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (rotation ``b`` first, then ``a``)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def quat_from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Quaternion rotating by ``angle`` (radians) about ``axis`` (need not be unit; 0 -> identity)."""
    axis = np.asarray(axis, dtype=np.float64)
    angle = np.asarray(angle, dtype=np.float64)
    n = np.linalg.norm(axis, axis=-1, keepdims=True)
    u = np.where(n > 1e-300, axis / np.where(n > 1e-300, n, 1.0), 0.0)
    half = 0.5 * angle[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * u], axis=-1)


def quat_from_rotvec(r: np.ndarray) -> np.ndarray:
    """Quaternion of a rotation vector (axis * angle)."""
    r = np.asarray(r, dtype=np.float64)
    return quat_from_axis_angle(r, np.linalg.norm(r, axis=-1))


def quat_slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation from ``a`` (t=0) to ``b`` (t=1) along the shorter arc."""
    a = quat_normalize(a)
    b = quat_normalize(b)
    t = np.asarray(t, dtype=np.float64)[..., None]
    d = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(d < 0, -b, b)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    small = s < 1e-6
    safe = np.where(small, 1.0, s)
    wa = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    wb = np.where(small, t, np.sin(t * theta) / safe)
    return quat_normalize(wa * a + wb * b)


def quat_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle (radians) between two orientations (sign of the quaternions ignored)."""
    d = np.abs(np.sum(quat_normalize(a) * quat_normalize(b), axis=-1))
    return 2.0 * np.arccos(np.clip(d, 0.0, 1.0))
