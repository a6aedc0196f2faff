"""Euler angles and quaternions (mavsid.numerics.rotations) against scipy's Rotation."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mavsid.numerics.rotations import euler_to_quat, quat_to_euler


def test_quaternion_to_euler_matches_scipy() -> None:
    rng = np.random.default_rng(3)
    rot = Rotation.random(200, random_state=rng)
    xyzw = rot.as_quat()
    wxyz = np.column_stack([xyzw[:, 3], xyzw[:, :3]])
    ours = quat_to_euler(wxyz)
    ref = rot.as_euler("ZYX")[:, ::-1]  # scipy: yaw, pitch, roll (intrinsic ZYX)
    assert np.allclose(ours, ref, atol=1e-9)
    assert np.allclose(quat_to_euler(3.0 * wxyz), ref, atol=1e-9)  # not unit: normalised


def test_euler_to_quaternion_matches_scipy() -> None:
    rng = np.random.default_rng(3)
    euler = np.column_stack([rng.uniform(-np.pi, np.pi, 2000), rng.uniform(-1.5, 1.5, 2000),
                             rng.uniform(-np.pi, np.pi, 2000)])
    xyzw = Rotation.from_euler("ZYX", euler[:, ::-1]).as_quat()
    want = np.column_stack([xyzw[:, 3], xyzw[:, :3]])
    np.testing.assert_allclose(euler_to_quat(euler), want, atol=1e-15)
    euler[7, 1] = np.nan
    assert euler_to_quat(euler)[7].tolist() == [1.0, 0.0, 0.0, 0.0]
    np.testing.assert_allclose(quat_to_euler(euler_to_quat(euler[8:])), euler[8:], atol=1e-12)
