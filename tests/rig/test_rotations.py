"""Rotation helpers against scipy."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from prt_torch.rig.rotations import axis_angle_matrix, matrix_to_quat, quat_to_matrix, rotation_part, slerp, trs_matrix


def test_quat_matrix_round_trip_vs_scipy() -> None:
    r = Rotation.random(50, random_state=0)
    q = r.as_quat()
    np.testing.assert_allclose(quat_to_matrix(q), r.as_matrix(), atol=1e-12)
    back = matrix_to_quat(r.as_matrix())
    assert np.all(back[:, 3] >= 0)
    np.testing.assert_allclose(np.abs((back * q).sum(1)), 1.0, atol=1e-12)


def test_axis_angle_vs_scipy() -> None:
    axis = np.array([0.3, -0.5, 0.8])
    ang = np.linspace(-3, 3, 7)
    ref = Rotation.from_rotvec(axis / np.linalg.norm(axis) * ang[:, None]).as_matrix()
    np.testing.assert_allclose(axis_angle_matrix(axis, ang), ref, atol=1e-12)


def test_slerp_vs_scipy() -> None:
    r = Rotation.random(2, random_state=3)
    t = np.linspace(0, 1, 11)
    ref = Slerp([0, 1], r)(t).as_quat()
    got = slerp(np.tile(r.as_quat()[0], (11, 1)), np.tile(r.as_quat()[1], (11, 1)), t)
    np.testing.assert_allclose(np.abs((got * ref).sum(1)), 1.0, atol=1e-10)
    # shortest arc: negating one end point gives the same rotations
    got2 = slerp(np.tile(r.as_quat()[0], (11, 1)), -np.tile(r.as_quat()[1], (11, 1)), t)
    np.testing.assert_allclose(quat_to_matrix(got2), quat_to_matrix(got), atol=1e-10)


def test_trs_and_rotation_part() -> None:
    q = Rotation.from_euler("xyz", [10, 20, 30], degrees=True)
    m = trs_matrix([1, 2, 3], q.as_quat(), [2, 3, 4])
    p = np.array([0.5, -1, 2])
    np.testing.assert_allclose(m[:3, :3] @ p + m[:3, 3], q.apply(p * [2, 3, 4]) + [1, 2, 3], atol=1e-12)
    np.testing.assert_allclose(rotation_part(m), q.as_matrix(), atol=1e-12)
