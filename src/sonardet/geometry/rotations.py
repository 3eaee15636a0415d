"""Rotations: quaternions (w, x, y, z), rotation matrices and yaw angles.

All functions take and return float64 numpy arrays. Quaternions are unit, scalar first, and
describe the rotation of a body's canonical frame into the scene frame (active rotation).
"""

from __future__ import annotations

import math

import numpy as np


def wrap_angle(angle_rad):
    """Wrap angles (rad) into [-pi, pi)."""
    a = np.asarray(angle_rad, dtype=np.float64)
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _unit_quat_floats(q) -> tuple[float, float, float, float]:
    """`quat_normalize` of one quaternion (4,) as Python floats: the same operations in the same order
    (squares summed left to right, one square root, four divisions, the sign of w), so the same bits,
    without numpy's per-call cost on four numbers (a detector converts thousands of poses a scene)."""
    w, x, y, z = (float(v) for v in q)
    n = math.sqrt(((w * w + x * x) + y * y) + z * z)
    if not (math.isfinite(w) and math.isfinite(x) and math.isfinite(y) and math.isfinite(z)) or not n >= 1e-12:
        raise ValueError(f"quaternion must be finite and non-zero, got {[w, x, y, z]}")
    w, x, y, z = w / n, x / n, y / n, z / n
    return (-w, -x, -y, -z) if w < 0 else (w, x, y, z)


def quat_normalize(q) -> np.ndarray:
    """Return q / |q| with the sign fixed so that w >= 0. Raises on a zero or non-finite quaternion."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape == (4,):
        return np.array(_unit_quat_floats(q))
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(q)) or np.any(n < 1e-12):
        raise ValueError(f"quaternion must be finite and non-zero, got {q.tolist()}")
    q = q / n
    return np.where(q[..., :1] < 0, -q, q)


def _matrix_rows(w, x, y, z) -> tuple:
    """The rows of the rotation matrix of the unit quaternion (w, x, y, z), for floats or arrays alike."""
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrix (..., 3, 3) of unit quaternion(s) q = (w, x, y, z)."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape == (4,):  # one quaternion: the same expressions on Python floats
        return np.array(_matrix_rows(*_unit_quat_floats(q)))
    rows = _matrix_rows(*np.moveaxis(quat_normalize(q), -1, 0))
    return np.stack([np.stack(r, -1) for r in rows], -2)


def matrix_to_quat(m) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a 3x3 rotation matrix (Shepperd's method, stable)."""
    m = np.asarray(m, dtype=np.float64)
    tr = np.trace(m)
    diag = np.diag(m)
    k = int(np.argmax([tr, *diag]))
    if k == 0:
        s = 2.0 * np.sqrt(max(1.0 + tr, 1e-300))
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        s = 2.0 * np.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 1e-300))
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 1e-300))
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 1e-300))
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    return quat_normalize(np.array(q))


def quat_from_yaw(yaw_rad: float) -> np.ndarray:
    """Quaternion of a rotation by yaw_rad about +z."""
    h = 0.5 * float(yaw_rad)
    return np.array([np.cos(h), 0.0, 0.0, np.sin(h)])


def quat_multiply(a, b) -> np.ndarray:
    """Hamilton product a * b (apply b first, then a)."""
    aw, ax, ay, az = np.asarray(a, dtype=np.float64)
    bw, bx, by, bz = np.asarray(b, dtype=np.float64)
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def yaw_of_matrix(m) -> float:
    """Heading (rad, [-pi, pi)) of the canonical +x axis after rotation m, projected onto the xy plane.

    If the rotated x axis is (nearly) vertical, the heading of the rotated y axis minus pi/2 is used,
    so the result is always defined.
    """
    m = np.asarray(m, dtype=np.float64)
    ex = m[:, 0]
    if np.hypot(ex[0], ex[1]) > 1e-6:
        return float(wrap_angle(np.arctan2(ex[1], ex[0])))
    ey = m[:, 1]
    return float(wrap_angle(np.arctan2(ey[1], ey[0]) - 0.5 * np.pi))


def random_quat(rng: np.random.Generator) -> np.ndarray:
    """Uniformly distributed random rotation (Shoemake's method)."""
    u1, u2, u3 = rng.random(3)
    a, b = np.sqrt(1 - u1), np.sqrt(u1)
    q = np.array(
        [b * np.cos(2 * np.pi * u3), a * np.sin(2 * np.pi * u2), a * np.cos(2 * np.pi * u2), b * np.sin(2 * np.pi * u3)]
    )
    return quat_normalize(q)


def transform_points(points, t, q) -> np.ndarray:
    """Apply the pose (translation t (3,), quaternion q (w,x,y,z)) to points (N,3): R p + t."""
    p = np.asarray(points, dtype=np.float64)
    return p @ quat_to_matrix(q).T + np.asarray(t, dtype=np.float64)
