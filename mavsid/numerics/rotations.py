"""Attitude conversions between ZYX Euler angles and Hamilton quaternions, in closed form.

The angles are (roll, pitch, yaw) in rad, the quaternion ``q_z(yaw) q_y(pitch) q_x(roll)``
as ``(w, x, y, z)``: what :class:`scipy.spatial.transform.Rotation` gives (``from_euler("ZYX",
[yaw, pitch, roll])``; tests/test_rotations.py compares), several times faster on a log's
million rows.
"""

from __future__ import annotations

import numpy as np

__all__ = ["euler_to_quat", "quat_to_euler"]


def quat_to_euler(q: np.ndarray) -> np.ndarray:
    """Hamilton quaternions ``(n, 4)`` (w, x, y, z) -> ZYX Euler angles ``(n, 3)`` in rad;
    the quaternions need not be unit (a zero one gives NaN angles).

    Examples
    --------
    >>> a = 0.3
    >>> quat_to_euler(np.array([[np.cos(a / 2), np.sin(a / 2), 0, 0]])).round(6).tolist()
    [[0.3, 0.0, 0.0]]
    """
    q = np.asarray(q, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):  # a zero quaternion gives NaN angles
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.column_stack([roll, pitch, yaw])


def euler_to_quat(euler: np.ndarray) -> np.ndarray:
    """ZYX Euler angles ``(n, 3)`` (roll, pitch, yaw; rad) -> unit Hamilton quaternions
    ``(n, 4)`` (w, x, y, z); the identity where an angle is not finite.

    Examples
    --------
    >>> euler_to_quat(np.array([[0.0, 0.0, np.pi]])).round(12).tolist()
    [[0.0, 0.0, 0.0, 1.0]]
    >>> euler_to_quat(np.array([[np.nan, 0.0, 0.0]])).tolist()
    [[1.0, 0.0, 0.0, 0.0]]
    """
    euler = np.asarray(euler, dtype=float)
    ok = np.all(np.isfinite(euler), axis=1)
    half = np.where(ok[:, None], euler, 0.0) / 2.0
    cr, cp, cy = np.cos(half).T
    sr, sp, sy = np.sin(half).T
    return np.column_stack([cy * cp * cr + sy * sp * sr, cy * cp * sr - sy * sp * cr,
                            cy * sp * cr + sy * cp * sr, sy * cp * cr - cy * sp * sr])
